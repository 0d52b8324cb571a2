"""A robot's drives and brakes belong to it (issue 23): robot data files, and figures that hold.

* The shipped robot data (``robots/ur10.yaml``, ``ur5.yaml``, ``panda.yaml``) hold the rated
  payload at full reach with the margin their rule states: static torque >= 2 x the gravity
  load of every joint, over the Annex-B full-reach poses of joints 1-3 with the wrists in
  2000 seeded random orientations, the payload a point mass 0.05 m out along the flange axis.
* Scenarios take the robot's brakes unless they give a joint's brake themselves (replaced
  whole) or ``null`` (no brake); no shipped scenario has a brake that cannot hold its load.
* The UR10 at 5 and 10 kg (``studies/ur10_rated_payload.yaml``): every brake holds, no flag,
  and the stopping angle grows with speed and with payload; with 40 kg the collapse is flagged
  in the table, the graph and the report.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import ROOT, SCENARIOS

import vtm_pin as vp
from vtm_pin.cli import main
from vtm_pin.outputs.flags import gravity_loads, static_torques
from vtm_pin.physics.payload import Payload, attach_payload
from vtm_pin.physics.robot import load_robot, robot_data
from vtm_pin.scene.annex_b import Conditions, compute_test_state
from vtm_pin.study.cases import find_study, load_study
from vtm_pin.study.report import plot_stopping_graphs
from vtm_pin.study.runner import run_study

#: Robot, joints tested at full reach, the guess their pose is sought near.
SHIPPED = {
    "ur10": (3, [0.0, -1.2, 1.4, -1.2, -1.57, 0.0]),
    "ur5": (3, [0.0, -1.2, 1.4, -1.2, -1.57, 0.0]),
    "panda": (4, [0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8, 0.0, 0.0]),
}
#: The rule's margin: static torque >= 2 x the load. The files round the torques up to 2-3
#: digits, so no slack is needed beyond round-off.
MARGIN = 2.0


def full_reach_loads(name: str) -> np.ndarray:
    """Largest gravity load per joint [N m] at full reach with the rated payload."""
    arm = load_robot(name)
    assert arm.rated_payload is not None
    payload = Payload(arm.rated_payload, (0.0, 0.0, 0.05), None, arm.tool_frame)
    loaded = attach_payload(arm, payload)
    tested, guess = SHIPPED[name]
    poses = []
    for joint in arm.joints[:tested]:
        conditions = Conditions(joint, 1.0, 1.0, None, "down")
        poses.append(compute_test_state(loaded, arm.tool_frame, conditions, np.array(guess)).q)
    rng = np.random.default_rng(0)
    wrists = [q.copy() for q in poses for _ in range(2000 // len(poses))]
    for q in wrists:
        q[3:7] = rng.uniform(-np.pi, np.pi, min(4, arm.nv - 3))
    return gravity_loads(loaded, np.array(poses + wrists)).max(axis=0)


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_brakes_hold_the_rated_payload_at_full_reach_with_their_margin(name):
    arm = load_robot(name)
    raw = {"robot": name, "duration": 1.0, "initial": {"q": [0.0] * arm.nv}, "stop": {}}
    scenario = vp.build_scenario(raw, source="test")
    static = static_torques(scenario.robot, scenario.brakes)
    loads = full_reach_loads(name)
    braked = np.isfinite(static)
    assert braked[:7].all() or name != "panda"  # the Panda's fingers have no brake
    assert np.all(static[braked] >= MARGIN * loads[braked] * (1.0 - 1e-12)), (static, loads)


def test_scenarios_take_the_robots_brakes_unless_they_give_their_own():
    data = robot_data("ur10")["brakes"]
    raw = yaml.safe_load((SCENARIOS / "ur10_annex_b.yaml").read_text())
    assert "brakes" not in raw  # the shipped scenario uses the robot's
    raw["brakes"] = {
        "elbow_joint": {"ideal": True},  # replaces the robot's elbow brake whole
        "wrist_3_joint": None,  # no brake at all
    }
    scenario = vp.build_scenario(raw, source="test", base_dir=SCENARIOS)
    brakes = {b.joint: b for b in scenario.brakes}
    assert set(brakes) == set(data) - {"wrist_3_joint"}
    assert brakes["elbow_joint"].ideal
    lift = brakes["shoulder_lift_joint"]
    assert lift.friction.sliding_torque == data["shoulder_lift_joint"]["sliding_torque"]
    assert lift.delay == data["shoulder_lift_joint"]["delay"]
    del raw["stop"]  # without a stop, no brakes: not even the robot's
    raw.pop("brakes")
    assert vp.build_scenario(raw, source="test", base_dir=SCENARIOS).brakes == ()


def test_a_robot_data_brake_on_an_unknown_joint_is_one_line(tmp_path):
    shutil_copy(ROOT / "robots" / "planar_3r.urdf", tmp_path / "arm.urdf")
    (tmp_path / "arm.yaml").write_text("brakes:\n  joint9: {sliding_torque: 1.0}\n")
    with pytest.raises(vp.VtmError, match=r"arm\.yaml: 'brakes\.joint9': unknown joint"):
        load_robot(tmp_path / "arm.urdf")


def shutil_copy(source: Path, target: Path) -> None:
    target.write_bytes(source.read_bytes())


def stop_scenarios() -> list[str]:
    names = []
    for path in sorted(SCENARIOS.glob("*.yaml")):
        raw = yaml.safe_load(path.read_text())
        if "stop" in raw:
            names.append(path.stem)
    return names


@pytest.mark.parametrize("name", stop_scenarios())
def test_no_shipped_scenario_has_a_brake_that_cannot_hold(name):
    with warnings.catch_warnings():  # other flags (a slipping joint) are not this test's
        warnings.simplefilter("ignore", vp.VtmWarning)
        output = vp.pipeline.run(name)
    assert output.figures is not None
    assert output.figures.holds, [f.message for f in output.figures.flags]


@pytest.fixture(scope="module")
def rated(tmp_path_factory):
    out = tmp_path_factory.mktemp("rated")
    return run_study(load_study(find_study("ur10_rated_payload")), out, workers=2)


def test_ur10_at_its_rated_payload_holds_and_stops_further_when_faster_or_heavier(rated):
    table = rated.table
    assert len(table) == 54 and (table["status"] == "ok").all()
    assert table["holds"].all() and (table["flags"] == "").all()
    for _, group in table.groupby(["joint", "extension", "payload"]):
        angles = group.sort_values("speed")["stop_angle"].to_numpy()
        assert np.all(np.diff(angles) > 0.0)
    for (joint, _, _), group in table.groupby(["joint", "extension", "speed"]):
        angles = group.sort_values("payload")["stop_angle"].to_numpy()
        if joint != "shoulder_pan_joint":  # joints moving down: gravity drives them on
            assert np.all(np.diff(angles) > 0.0)


def test_a_payload_the_brakes_cannot_hold_is_flagged_in_table_graph_and_report(tmp_path):
    study = tmp_path / "heavy.yaml"
    study.write_text(
        f"scenario: {SCENARIOS / 'ur10_annex_b.yaml'}\n"
        "vary: {joint: [elbow_joint], speed: [0.5], payload: [10.0, 40.0]}\n"
    )
    out = tmp_path / "out"
    with pytest.warns(vp.VtmWarning, match=r"1 of 2 cases are flagged \(1 brake_cannot_hold"):
        output = run_study(load_study(study), out, workers=1)
    table = output.table.set_index("payload")
    assert table.loc[10.0, "holds"] and table.loc[10.0, "flags"] == ""
    assert not table.loc[40.0, "holds"]
    assert "brake_cannot_hold" in table.loc[40.0, "flags"]
    assert "payload_above_rated" in table.loc[40.0, "flags"]
    assert table.loc[40.0, "tool_drop"] > 0.5  # [m]: the arm collapses
    figure = plot_stopping_graphs(output.table)["stopping_elbow_joint.png"]
    crosses = [
        c
        for ax in figure.axes
        for c in ax.collections
        if c.get_label() == "FLAGGED: brake cannot hold"
    ]
    assert len(crosses) == 2 and all(len(c.get_offsets()) == 1 for c in crosses)
    page = (out / "report.html").read_text()
    assert "1 of 2 cases are flagged" in page and "the arm collapses" in page
    summary = json.loads((out / "summary.json").read_text())
    assert summary["counts"]["cannot_hold"] == 1
    csv = pd.read_csv(out / "results.csv")
    assert list(csv["holds"]) == [True, False]


def test_a_payload_above_the_rated_one_warns_in_one_line(tmp_path, capsys):
    raw = yaml.safe_load((SCENARIOS / "ur10_annex_b.yaml").read_text())
    raw["payload"]["mass"] = 12.0
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(raw))
    assert main(["run", str(path), "--out", str(tmp_path / "o"), "--no-plots"]) == 0
    warning = [line for line in capsys.readouterr().err.splitlines() if "rated payload" in line]
    assert warning == [
        "vtm-pin: warning: the payload of 12 kg is above the rated payload of 10 kg (robot "
        "data of ur10)"
    ]
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert [f["kind"] for f in summary["flags"]] == ["payload_above_rated"]


def test_implausible_payloads_and_tool_speeds_are_flagged():
    """No rated payload in the RX160L's data: a payload heavier than the arm is implausible;
    a centre of mass further out than the arm is long too; a fall without brakes reaches a
    tool speed no drive could give."""
    raw = yaml.safe_load((SCENARIOS / "rx160l_estop_cat0.yaml").read_text())
    raw["payload"] = {"mass": 7000.0, "com": [0.0, 0.0, 100.0]}
    raw["brakes"] = dict.fromkeys(raw["brakes"])  # every brake fails
    raw["duration"] = 0.6
    with pytest.warns(vp.VtmWarning):
        output = vp.pipeline.run(vp.build_scenario(raw, source="test", base_dir=SCENARIOS))
    kinds = [flag.kind for flag in output.figures.flags]
    assert kinds.count("payload_implausible") == 2
    assert "brake_cannot_hold" in kinds and "tool_speed_implausible" in kinds
    speed = next(f for f in output.figures.flags if f.kind == "tool_speed_implausible")
    assert speed.value > speed.limit > 0.0
