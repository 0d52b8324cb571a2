"""The wheel works: built from the project, installed into a fresh environment, run elsewhere.

A wheel is what ``pip install`` without ``-e`` installs: only what the build configuration
ships. Both variants build one from a copy of the project and run ``vtm-pin`` from a folder
outside it, checking that the package (and its robots and scenarios) comes from the wheel.

- The default variant installs the wheel alone (``--no-deps``) and lends the dependencies
  of this environment through a ``.pth`` file, leaving out this environment's editable
  ``vtm_pin``: 10-20 s.
- The slow variant installs the wheel with its dependencies as a user would (``pip install
  vtm_pin-*.whl``): 45 s with a warm pip cache, more without.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
import tomllib
from conftest import ROOT, SCENARIOS

#: What a wheel is built from: the build configuration and what it names.
SOURCES = ["pyproject.toml", "README.md", "vtm_pin", "robots", "scenarios", "studies", "programs"]
#: Longest time one step may take [s]: a wheel build, an install, a command.
STEP_TIMEOUT = 600


def build_wheel(tmp: Path) -> Path:
    """Build the project's wheel from a copy of its sources; the wheel's path."""
    source = tmp / "source"
    source.mkdir()
    for name in SOURCES:
        path = ROOT / name
        if path.is_dir():
            shutil.copytree(path, source / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(path, source / name)
    dist = tmp / "dist"
    pip = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(dist)]
    run_checked([*pip, str(source)], cwd=tmp)
    (wheel,) = dist.glob("vtm_pin-*.whl")
    return wheel


def make_venv(folder: Path, *, with_pip: bool) -> Path:
    """A fresh virtual environment; its Python."""
    options = [] if with_pip else ["--without-pip"]
    run_checked([sys.executable, "-m", "venv", *options, str(folder)], cwd=folder.parent)
    return folder / "bin" / "python"


def site_packages(python: Path) -> Path:
    """The site-packages folder of the environment of ``python``."""
    code = "import sysconfig; print(sysconfig.get_path('purelib'))"
    return Path(run_checked([str(python), "-c", code], cwd=python.parent).stdout.strip())


def lend_dependencies(python: Path) -> None:
    """Make this environment's packages importable from the fresh one, except vtm_pin.

    A ``.pth`` file adds this environment's site-packages to the fresh one's path, after the
    fresh one's own (so the wheel's vtm_pin comes first). The ``.pth`` files of this
    environment are not read from a folder added that way, so those the dependencies need
    (Pinocchio's ``cmeel.pth``) are copied, all but the editable install of vtm_pin.
    """
    ours = Path(sysconfig.get_path("purelib"))
    theirs = site_packages(python)
    (theirs / "00_lent_dependencies.pth").write_text(f"{ours}\n")
    for pth in ours.glob("*.pth"):
        if "vtm_pin" not in pth.name:
            shutil.copy2(pth, theirs / pth.name)


def run_checked(command: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    """Run a command outside the project; fail with its output if it fails."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env["MPLBACKEND"] = "Agg"
    done = subprocess.run(
        command, cwd=cwd, env=env, capture_output=True, text=True, timeout=STEP_TIMEOUT
    )
    assert done.returncode == 0, f"{command} exited {done.returncode}:\n{done.stdout}{done.stderr}"
    return done


def check_installed_wheel(python: Path, elsewhere: Path) -> None:
    """vtm_pin, its robots, scenarios and schemas come from the wheel; run, list and init work."""
    code = (
        "import vtm_pin, vtm_pin.physics.robot as r, vtm_pin.scene.scenario as s, "
        "vtm_pin.schemas as j; "
        "print(vtm_pin.__file__); print(r.ROBOTS_DIR); print(s.SCENARIOS_DIR); "
        "print(j.schema_file('scenario')); print(j.schema_file('study'))"
    )
    paths = run_checked([str(python), "-c", code], cwd=elsewhere).stdout.split()
    env_root = python.parent.parent.resolve()
    assert len(paths) == 5
    for path in paths:
        assert Path(path).resolve().is_relative_to(env_root), f"{path} is not from the wheel"
    for path in paths[3:]:  # the JSON Schemas are package data of the wheel
        assert Path(path).is_file(), f"{path} is not in the wheel"
    vtm_pin = python.parent / "vtm-pin"
    listed = run_checked([str(vtm_pin), "list", "scenarios", "--json"], cwd=elsewhere).stdout
    names = [entry["scenario"] for entry in json.loads(listed)]
    assert names == sorted(p.stem for p in SCENARIOS.glob("*.yaml"))
    run_checked([str(vtm_pin), "run", "pendulum3r", "--quiet"], cwd=elsewhere)
    out = elsewhere / "results" / "pendulum3r"
    files = {p.name for p in out.iterdir()}
    assert {"summary.json", "trajectory.csv", "poses.png", "momenta.png"} <= files
    summary = json.loads((out / "summary.json").read_text())
    assert summary["robot"] == "planar_3r" and len(summary["events"]) == 2
    assert Path(summary["urdf"]).resolve().is_relative_to(env_root)
    # a shipped scenario copied here (with the fragment it includes) runs from its copy
    run_checked(
        [str(vtm_pin), "init", "scenario", "ur5_cb3_annex_b", "--to", "mine"], cwd=elsewhere
    )
    run_checked(
        [str(vtm_pin), "run", "mine/ur5_cb3_annex_b.yaml", "--quiet", "--no-plots"], cwd=elsewhere
    )
    assert (elsewhere / "results" / "ur5_cb3_annex_b" / "summary.json").is_file()
    # the shipped program is package data of the wheel, and init copies it
    run_checked([str(vtm_pin), "init", "program", "ur10_pick_place", "--to", "p"], cwd=elsewhere)
    assert (elsewhere / "p" / "ur10_pick_place.csv").read_bytes() == (
        ROOT / "programs" / "ur10_pick_place.csv"
    ).read_bytes()
    code = "import vtm_pin.scene.program as p; print(p.PROGRAMS_DIR)"
    folder = Path(run_checked([str(python), "-c", code], cwd=elsewhere).stdout.strip())
    assert folder.resolve().is_relative_to(env_root) and (folder / "ur10_pick_place.csv").is_file()


def test_pyproject_lists_every_package():
    """The build configuration names its packages: a new subpackage must be listed there."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    found = {
        ".".join(path.parent.relative_to(ROOT).parts)
        for path in (ROOT / "vtm_pin").rglob("__init__.py")
    }
    data = {
        "vtm_pin.robots": "robots",
        "vtm_pin.scenarios": "scenarios",
        "vtm_pin.studies": "studies",
        "vtm_pin.programs": "programs",
    }
    assert set(config["packages"]) == found | set(data)
    assert config["package-dir"] == data


def test_wheel_runs_from_another_folder(tmp_path):
    wheel = build_wheel(tmp_path)
    python = make_venv(tmp_path / "venv", with_pip=False)
    pip = [sys.executable, "-m", "pip", "--python", str(python), "install", "--quiet"]
    run_checked([*pip, "--no-deps", str(wheel)], cwd=tmp_path)
    lend_dependencies(python)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    check_installed_wheel(python, elsewhere)


@pytest.mark.slow
def test_wheel_with_its_dependencies_runs_from_another_folder(tmp_path):
    wheel = build_wheel(tmp_path)
    python = make_venv(tmp_path / "venv", with_pip=True)
    run_checked([str(python), "-m", "pip", "install", "--quiet", str(wheel)], cwd=tmp_path)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    check_installed_wheel(python, elsewhere)
