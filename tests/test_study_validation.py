"""A study file is validated whole before any case runs; input-reading faults give one line.

Each refused study goes through ``vtm-pin study STUDY --out DIR``: exit 1, one line on stderr
naming the study file, the key and what is allowed, and nothing on disk (neither DIR nor a
staging folder beside it).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

import vtm_pin.scene.scenario as scenario_module
from vtm_pin.cli import main
from vtm_pin.exceptions import ScenarioError
from vtm_pin.files.inputs import read_yaml
from vtm_pin.physics.robot import ROBOTS_DIR
from vtm_pin.scene.scenario import SCENARIOS_DIR
from vtm_pin.study.cases import STUDIES_DIR, find_study, load_study, resolve_case

ROOT = Path(__file__).resolve().parent.parent
#: The shipped base scenario of the test studies.
BASE = yaml.safe_load((SCENARIOS_DIR / "ur10_annex_b.yaml").read_text())
#: [s] A refused input is refused at once: a hang on a named pipe would take forever; the
#: bound leaves room for Python, Pinocchio and the UR10's model to load on a slow machine.
HANG_TIMEOUT = 60.0


def refused(tmp_path: Path, capsys: pytest.CaptureFixture[str], study: Path) -> str:
    """Run the study; check exit 1, one line, and nothing written. Returns the line."""
    runs = tmp_path / "runs"
    runs.mkdir()
    code = main(["study", str(study), "--out", str(runs / "out")])
    err = capsys.readouterr().err
    assert code == 1, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vtm-pin: error: "), err
    assert str(study) in lines[0]
    assert list(runs.iterdir()) == []  # no DIR, no staging folder beside it
    return lines[0]


def study_file(folder: Path, text: str, base: dict | None = None, extra: str = "") -> Path:
    """A study file ``text`` (its base: base.yaml, ``base`` plus the raw YAML ``extra``)."""
    if base is not None:
        (folder / "base.yaml").write_text(yaml.safe_dump(base, sort_keys=False) + extra)
    path = folder / "study.yaml"
    path.write_text(text)
    return path


def shipped(vary: str, more: str = "") -> str:
    """A study of the shipped UR10 Annex-B base."""
    return f"scenario: ur10_annex_b\n{more}vary: {vary}\n"


# -- values checked before anything runs ---------------------------------------------------


@pytest.mark.parametrize(
    ("text", "words"),
    [
        # a key path's value: set alone into the base, the scenario's own schema refuses it
        (shipped("{stop.t: [abc]}"), ["'vary.stop.t': 'abc' is refused", "'stop.t'", "number"]),
        # a joint name the robot does not have: refused with the robot's joints
        (
            shipped("{joint: [shoulder_lift]}"),
            ["'vary.joint': 'shoulder_lift' is refused", "'annex_b.joint'", "shoulder_lift_joint"],
        ),
        # a range's ends are checked too
        (
            shipped("{stop.t: {min: 0.0, max: 5000.0}}", "samples: 4\n"),
            ["'vary.stop.t': 5000.0 is refused", "must be <= 3600"],
        ),
        # a brake torque scaled out of range
        (shipped("{brake_scale: [1.0, 1.0e9]}"), ["'vary.brake_scale': 1000000000.0", "<= 1e+06"]),
        # a seed too large for a float was never compared with its maximum
        (
            shipped("{speed: [1.0]}", "samples: 2\nseed: " + "9" * 400 + "\n"),
            ["'seed'", "<= 4294967295"],
        ),
        # an integer too long for Python: its key and its line
        (shipped("{speed: [1.0]}", "samples: " + "7" * 5000 + "\n"), ["'samples'", "at line 2"]),
    ],
)
def test_a_bad_value_is_refused_before_anything_runs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, words: list[str]
) -> None:
    line = refused(tmp_path, capsys, study_file(tmp_path, text))
    for word in words:
        assert word in line


@pytest.mark.parametrize(
    ("change", "extra", "words"),
    [
        ({"duration": -1.0}, "", ["'scenario'", "base.yaml: 'duration': -1.0 must be > 0"]),
        ({"annex_b": {"joint": "wrist_9"}}, "", ["'scenario'", "'annex_b.joint'", "wrist_1_joint"]),
        ({"stop": None}, "", ["'stop'", "a study case needs a stop"]),
        # malformed keys that the fragments are merged into (an internal error before)
        ({}, "include: 5\n", ["'include'", "5 is not a list"]),
        ({}, "include: [1, 2]\n", ["'include[0]'", "1 is not a string"]),
        ({}, "include: [frag.yaml]\nbrakes: 5\n", ["'brakes'", "5 is not a mapping"]),
        ({}, "include: [frag.yaml]\ndrives: [1]\n", ["'drives'", "[1] is not a mapping"]),
        ({}, "brakes: 5\n", ["'brakes'", "5 is not a mapping"]),
        # a base that includes itself
        ({}, "include: [base.yaml]\n", ["'include[0]'", "base.yaml is this scenario", "cycle"]),
        # a key given twice in the base, and in a fragment it includes
        ({}, "duration: 2.0\n", ["'duration'", "given twice", "keep one"]),
        ({}, "include: [dup.yaml]\n", ["dup.yaml", "'brakes.elbow_joint'", "lines 2 and 3"]),
    ],
)
def test_a_bad_base_scenario_is_refused_before_anything_runs(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    change: dict,
    extra: str,
    words: list[str],
) -> None:
    (tmp_path / "frag.yaml").write_text("assumptions: [a fragment]\n")
    (tmp_path / "dup.yaml").write_text(
        "brakes:\n  elbow_joint: {sliding_torque: 1.0}\n  elbow_joint: {sliding_torque: 2.0}\n"
    )
    base = {k: v for k, v in {**BASE, **change}.items() if v is not None}
    path = study_file(tmp_path, "scenario: base.yaml\nvary: {speed: [1.0]}\n", base, extra)
    line = refused(tmp_path, capsys, path)
    for word in words:
        assert word in line


def test_a_base_path_too_long_is_refused_in_a_short_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for name in ("a" * 300 + ".yaml", "a/" * 2000 + "x.yaml"):
        path = study_file(tmp_path, f"scenario: {name}\nvary: {{speed: [1.0]}}\n")
        line = refused(tmp_path, capsys, path)
        assert "'scenario'" in line and "cannot read the file" in line
        assert len(line) < 600  # the path is cut to an excerpt
        (tmp_path / "runs").rmdir()


ELBOW_DELAY, ELBOW_SLIDE = "brakes.elbow_joint.delay", "brakes.elbow_joint.sliding_torque"


@pytest.mark.parametrize(
    ("vary", "axis", "other"),
    [
        ("{speed: [1.0], annex_b.speed: [0.5]}", "annex_b.speed", "speed"),
        ("{payload: [1.0], payload.mass: [0.5]}", "payload.mass", "payload"),
        ("{brakes.*.delay: [0.0], brakes.elbow_joint.delay: [0.1]}", ELBOW_DELAY, "brakes.*.delay"),
        ("{brake_scale: [1], brakes.elbow_joint.sliding_torque: [1]}", ELBOW_SLIDE, "brake_scale"),
        ("{failed_brake: [none], brakes.elbow_joint.delay: [0.1]}", ELBOW_DELAY, "failed_brake"),
        ("{annex_b: [1.0], joint: [elbow_joint]}", "joint", "annex_b"),
        ("{category: [0], stop.category: [1]}", "stop.category", "category"),
    ],
)
def test_two_axes_setting_one_key_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], vary: str, axis: str, other: str
) -> None:
    line = refused(tmp_path, capsys, study_file(tmp_path, shipped(vary)))
    assert f"'vary.{axis}'" in line and f"which axis {other} sets too" in line


def test_axes_setting_different_keys_are_accepted(tmp_path: Path) -> None:
    vary = "{speed: [1.0], annex_b.extension: [0.5], brakes.*.delay: [0.0]}"
    path = study_file(tmp_path, shipped(vary))
    assert list(load_study(path).axes) == ["speed", "annex_b.extension", "brakes.*.delay"]


def test_a_failed_brake_goes_with_axes_that_set_every_brake(tmp_path: Path) -> None:
    """failed_brake removes one brake; brake_scale and brakes.*.delay set the others."""
    vary = "{failed_brake: [none, elbow_joint], brake_scale: [0.8], brakes.*.delay: [0.05]}"
    study = load_study(study_file(tmp_path, shipped(vary)))
    raw = resolve_case(study.base, study.cases()[1].values)
    assert raw["brakes"]["elbow_joint"] is None
    others = [spec for spec in raw["brakes"].values() if spec is not None]
    assert others and all(spec["delay"] == 0.05 for spec in others)


def test_a_key_given_twice_in_a_study_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    text = "scenario: ur10_annex_b\nvary:\n  speed: [1.0]\n  payload: [0.0]\n  speed: [0.5]\n"
    line = refused(tmp_path, capsys, study_file(tmp_path, text))
    assert "'vary.speed': is given twice, at lines 3 and 5; keep one" in line


def test_one_build_per_distinct_value_not_per_case(monkeypatch: pytest.MonkeyPatch) -> None:
    """The shipped 10,000-case study is checked with 14 builds: its base, 3 joints, 2 ends
    of each range (speed, extension) and 6 payloads."""
    built = []
    real = scenario_module.build_scenario

    def counting(*args: object, **kwargs: object) -> object:
        built.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(scenario_module, "build_scenario", counting)
    study = load_study(find_study("ur10_envelope"))
    assert study.samples == 10_000 and len(built) == 1 + 3 + 2 + 6 + 2


# -- duplicate keys and long integers in any file read -------------------------------------


def shipped_yaml() -> list[Path]:
    folders = (SCENARIOS_DIR, STUDIES_DIR, ROBOTS_DIR, ROOT / "scenarios", ROOT / "studies")
    return sorted({p for folder in folders for p in folder.glob("*.yaml")})


def test_no_shipped_file_has_a_key_twice() -> None:
    files = shipped_yaml()
    assert len(files) >= 20  # scenarios, studies and robot data files
    for path in files:
        read_yaml(path, ScenarioError)  # raises on a key given twice


@pytest.mark.parametrize(
    ("text", "key", "words"),
    [
        ("a:\n  - {b: 1, b: 2}\n", "a[0].b", "lines 2 and 2"),
        ('a: 1\n"a": 2\n', "a", "lines 1 and 2"),  # the same key, quoted
        ("a: [1, " + "7" * 5000 + "]\n", "a[1]", "an integer of 5000 digits at line 1"),
        ("7" * 5000 + "\n", "", "an integer of 5000 digits at line 1"),
    ],
)
def test_yaml_faults_name_the_key_and_line(tmp_path: Path, text: str, key: str, words: str) -> None:
    path = tmp_path / "f.yaml"
    path.write_text(text)
    with pytest.raises(ScenarioError) as info:
        read_yaml(path, ScenarioError)
    assert info.value.key == key and words in info.value.problem


def test_merge_keys_and_aliases_are_not_keys_given_twice(tmp_path: Path) -> None:
    path = tmp_path / "f.yaml"
    path.write_text("a: &x {b: 1, c: 2}\nd:\n  <<: *x\n  b: 3\ne: *x\n")
    assert read_yaml(path, ScenarioError) == {
        "a": {"b": 1, "c": 2},
        "d": {"b": 3, "c": 2},
        "e": {"b": 1, "c": 2},
    }


# -- named pipes: one line, never a hang ----------------------------------------------------


def run_cli(args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    """The real command, bounded by HANG_TIMEOUT (a hang fails the test, not blocks it)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
    return subprocess.run(
        [sys.executable, "-m", "vtm_pin", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=HANG_TIMEOUT,
        check=False,
    )


@pytest.mark.parametrize("where", ["study", "base", "fragment"])
def test_a_named_pipe_in_a_study_is_refused_not_waited_for(tmp_path: Path, where: str) -> None:
    folder = tmp_path / "study"
    folder.mkdir()
    pipe = folder / "pipe.yaml"
    os.mkfifo(pipe)
    (folder / "base.yaml").write_text(yaml.safe_dump({**BASE, "include": ["pipe.yaml"]}))
    study = {"study": pipe, "base": folder / "s1.yaml", "fragment": folder / "s2.yaml"}[where]
    (folder / "s1.yaml").write_text("scenario: pipe.yaml\nvary: {speed: [1.0]}\n")
    (folder / "s2.yaml").write_text("scenario: base.yaml\nvary: {speed: [1.0]}\n")
    runs = tmp_path / "runs"
    runs.mkdir()
    # run from elsewhere: the base is found beside the study, not in the working folder
    done = run_cli(["study", str(study), "--out", str(runs / "out")], tmp_path)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 1 and len(lines) == 1, done.stderr
    assert "pipe.yaml" in lines[0] and "is a named pipe (FIFO), not a regular file" in lines[0]
    assert list(runs.iterdir()) == []


def test_a_named_pipe_among_listed_scenarios_is_listed_invalid(tmp_path: Path) -> None:
    (tmp_path / "ok.yaml").write_text((SCENARIOS_DIR / "pendulum3r.yaml").read_text())
    os.mkfifo(tmp_path / "pipe.yaml")
    done = run_cli(["list", "scenarios", "--dir", str(tmp_path)], tmp_path)
    assert done.returncode == 0, done.stderr
    rows = {line.split()[0]: line for line in done.stdout.splitlines()[1:]}
    assert set(rows) == {"ok", "pipe"}
    assert "INVALID: is a named pipe (FIFO), not a regular file" in rows["pipe"]


def test_a_folder_beside_the_study_does_not_hide_a_shipped_base(tmp_path: Path) -> None:
    (tmp_path / "ur10_annex_b").mkdir()  # a results folder named like the shipped scenario
    study = load_study(study_file(tmp_path, shipped("{speed: [1.0]}")))
    assert study.scenario == SCENARIOS_DIR / "ur10_annex_b.yaml"


def test_a_whole_number_written_as_a_float_is_taken(tmp_path: Path) -> None:
    """``samples: 3.0`` (YAML reads 3e0 as a float too) is 3 cases, not an internal error."""
    text = shipped("{speed: {min: 0.5, max: 1.0}}", more="samples: 3.0\n")
    study = load_study(study_file(tmp_path, text))
    assert study.samples == 3 and len(study.cases()) == 3
