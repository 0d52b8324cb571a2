"""Robots from ROS xacro descriptions, expanded by xacrodoc (the ``xacro`` extra), no ROS needed."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, UR_JOINTS

from vtm_pin.cli import main
from vtm_pin.physics.robot import load_robot

pytest.importorskip("xacrodoc")

DATA = ROOT / "tests" / "data" / "xacro"
#: The public UR descriptions (github.com/ros-industrial/universal_robot), where present: a
#: ur_description folder given by VTM_PIN_UR_DESCRIPTION, or a local mirror of the repository.
UR_MIRROR = Path("/work/.mirror/ros-industrial+universal_robot/repo")


@pytest.fixture
def arm(tmp_path: Path) -> Path:
    """The 2-link xacro arm, its robot data, its parts package and a scenario, in tmp_path."""
    shutil.copytree(DATA, tmp_path / "arm")
    return tmp_path / "arm"


def test_a_xacro_robot_runs_with_its_packages_and_data(arm, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # the scenario's folder is not this one: paths are its own
    assert main(["run", "arm/two_link_drop.yaml", "--no-plots", "--json", "--out", "o"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["robot"] == "two_link.urdf.xacro" and len(summary["events"]) == 1
    robot = load_robot(arm / "two_link.urdf.xacro", packages={"vtm_test_parts": str(arm / "parts")})
    assert robot.joints == ("link1_joint", "link2_joint") and robot.tool_frame == "tip"
    # the macro's links: 2 kg rods of 0.5 m, properties expanded; the drive of two_link.yaml
    assert [robot.model.inertias[j].mass for j in (1, 2)] == [2.0, 2.0]
    assert robot.model.inertias[1].lever[2] == pytest.approx(-0.25)
    assert robot.gear_ratio.tolist() == [50.0, 1.0]
    assert robot.model.armature[0] == pytest.approx(50.0**2 * 1e-4)


def test_a_package_not_given_is_one_line(arm, capsys):
    scenario = arm / "two_link_drop.yaml"
    scenario.write_text(scenario.read_text().replace("robot_packages", "# robot_packages"))
    assert main(["run", str(scenario), "--no-plots", "--out", str(arm / "o")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'robot'" in err and "two_link.urdf.xacro" in err
    assert "ROS package 'vtm_test_parts' not found" in err and "robot_packages" in err
    assert not (arm / "o").exists()


def test_without_the_extra_a_xacro_robot_says_what_to_install(arm, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "xacrodoc", None)  # import xacrodoc raises ImportError
    assert main(["run", str(arm / "two_link_drop.yaml"), "--no-plots"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "pip install 'vtm_pin[xacro]'" in err


def ur_description(tmp_path: Path) -> Path:
    """A ur_description folder (meshes left out), or skip the test."""
    given = os.environ.get("VTM_PIN_UR_DESCRIPTION")
    if given:
        return Path(given)
    if not UR_MIRROR.is_dir():
        pytest.skip("no ur_description: set VTM_PIN_UR_DESCRIPTION to its folder")
    archive = ["git", "-C", str(UR_MIRROR), "archive", "HEAD", "ur_description/urdf"]
    archive += ["ur_description/config", "ur_description/package.xml"]
    tar = subprocess.run(archive, capture_output=True, check=True, timeout=60).stdout
    subprocess.run(["tar", "-x", "-C", str(tmp_path)], input=tar, check=True, timeout=60)
    return tmp_path / "ur_description"


def test_the_published_ur5_xacro_loads_like_example_robot_data_ur5(tmp_path):
    """$(find ur_description) resolves to the package holding the file (its package.xml)."""
    robot = load_robot(ur_description(tmp_path) / "urdf" / "ur5.xacro")
    reference = load_robot("ur5")
    assert robot.joints == UR_JOINTS == reference.joints
    masses = [robot.model.inertias[j].mass for j in range(1, 7)]
    # the same arm, from two sources: link masses (UR's published 18.4 kg arm) within 1 %
    reference_masses = [reference.model.inertias[j].mass for j in range(1, 7)]
    assert np.allclose(masses, reference_masses, rtol=0.01), (masses, reference_masses)


def test_a_study_fingerprint_follows_the_files_a_xacro_robot_includes(arm):
    """A resumed study must not mix results of an old robot: an included macro counts too."""
    from vtm_pin.study.cases import load_study

    scenario = arm / "two_link_drop.yaml"
    scenario.write_text(
        scenario.read_text() + "stop: {t: 0.1}\nbrakes: {link1_joint: {ideal: true}}\n"
    )
    study = arm / "drop_study.yaml"
    study.write_text("scenario: two_link_drop.yaml\nvary:\n  duration: [0.3, 0.4]\n")
    before = load_study(study).fingerprint
    assert load_study(study).fingerprint == before  # the digest is stable
    part = arm / "parts" / "link.xacro"
    part.write_text(part.read_text().replace('izz="1e-4"', 'izz="2e-4"'))
    assert 'izz="2e-4"' in part.read_text()  # the included macro changed, not the robot file
    assert load_study(study).fingerprint != before
