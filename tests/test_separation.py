"""The whole stopping chain (issue 23): T_robot is not T; S and S_p by hand from a case's figures.

The hand calculation takes the case's T_robot and S_s from its stopping report and the tool's
speed at the signal from Pinocchio's frame velocity (not from vtm_pin's code), then applies
ISO 13855:2024 (S = K T + D_DS + Z) and ISO/TS 15066 (S_p = S_h + S_r + S_s + C + Z_d + Z_r)
as the standards write them. Tolerance 1e-12 relative: the same sums in another order.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pinocchio as pin
import pytest
import yaml
from conftest import SCENARIOS

import vtm_pin as vp
from vtm_pin.cli import main
from vtm_pin.physics.arm_points import sample_arm_points
from vtm_pin.standards.separation import Iso13855, Safeguard, Ssm

GUARD = {"detection_time": 0.03, "response_time": 0.012, "latency": 0.004}  # [s]
ISO13855 = {"approach_speed": 2.0, "intrusion_distance": 0.208, "supplement": 0.1}  # [m/s, m, m]
SSM = {"intrusion_distance": 0.208, "human_uncertainty": 0.1, "robot_uncertainty": 0.02}  # [m]


def scenario(**extra) -> dict:
    raw = yaml.safe_load((SCENARIOS / "ur10_annex_b.yaml").read_text())
    raw.update(extra)
    return raw


def test_separation_distances_by_hand_from_a_case():
    raw = scenario(safeguard=GUARD, separation={"iso13855": ISO13855, "iso_ts_15066": SSM})
    output = vp.pipeline.run(vp.build_scenario(raw, source="test", base_dir=SCENARIOS))
    report = output.stopping[output.rule]
    T_robot = report.all_stopped_time
    S_s = float(np.max(np.linalg.norm(report.tcp_path - report.tcp_path[0], axis=1)))
    robot, result = output.scenario.robot, output.result
    model, data = robot.model, robot.model.createData()
    pin.forwardKinematics(model, data, result.q[0], result.v[0])
    pin.updateFramePlacements(model, data)
    frame = model.getFrameId(output.scenario.tool_frame)
    v_r = np.linalg.norm(pin.getFrameVelocity(model, data, frame, pin.LOCAL_WORLD_ALIGNED).linear)
    T_r = 0.03 + 0.012 + 0.004
    T = T_r + T_robot
    S = 2.0 * T + 0.208 + 0.1
    # S_s of S_p is the arm's: the largest displacement of its sampled points, by hand
    points = sample_arm_points(robot)
    i0 = int(np.argmax(result.t >= report.signal_time))
    positions = []
    for q in result.q[i0:]:
        pin.forwardKinematics(model, data, q)
        positions.append(
            [data.oMi[int(j)].act(x) for j, x in zip(points.joints, points.points, strict=True)]
        )
    moved = np.linalg.norm(np.array(positions) - np.array(positions[0]), axis=2)
    S_arm = float(moved.max())
    assert S_arm >= S_s

    # v_r of S_p is the fastest arm point's speed at the signal, by central differences of the
    # points' positions along v (step 1e-6 s: truncation ~1e-12 m/s, round-off ~1e-9 m/s)
    def place(q):
        pin.forwardKinematics(model, data, q)
        return np.array(
            [data.oMi[int(j)].act(x) for j, x in zip(points.joints, points.points, strict=True)]
        )

    h = 1e-6
    q0, v0 = result.q[i0], result.v[i0]
    speeds = np.linalg.norm(place(q0 + h * v0) - place(q0 - h * v0), axis=1) / (2 * h)
    arm_v_r = float(speeds.max())
    assert arm_v_r >= v_r * (1 - 1e-8)
    S_p = 1.6 * (T_r + T_robot) + arm_v_r * T_r + S_arm + 0.208 + 0.1 + 0.02
    values = output.figures.metrics
    assert values["robot_stop_time"] == pytest.approx(T_robot, rel=1e-12)
    assert values["overall_stop_time"] == pytest.approx(T, rel=1e-12)
    assert values["iso13855_distance"] == pytest.approx(S, rel=1e-12)
    assert values["ssm_distance"] == pytest.approx(S_p, rel=1e-9)  # the differenced v_r
    assert values["arm_speed_at_signal"] == pytest.approx(arm_v_r, rel=1e-7)
    assert values["tcp_speed_at_signal"] == pytest.approx(v_r, rel=1e-12)
    assert values["tcp_max_displacement"] == pytest.approx(S_s, rel=1e-12)
    assert values["arm_max_displacement"] == pytest.approx(S_arm, rel=1e-12)
    chain = output.summary["stopping_chain"]
    assert chain["iso_ts_15066"]["terms"]["S_h"] == pytest.approx(1.6 * (T_r + T_robot))
    assert chain["iso13855"]["formula"] == "S = K T + D_DS + Z"
    # The robot's own stop is never passed off as T: T is longer by the reaction time.
    assert values["overall_stop_time"] - values["robot_stop_time"] == pytest.approx(T_r)


def test_without_a_safeguard_T_S_and_S_p_are_not_computed():
    output = vp.pipeline.run("ur10_annex_b")
    values = output.figures.metrics
    assert values["robot_stop_time"] > 0.0
    assert values["overall_stop_time"] is None
    assert values["iso13855_distance"] is None and values["ssm_distance"] is None
    assert "NOT ISO 13855's T" in output.summary["stopping_chain"]["definition"]


@pytest.mark.parametrize(
    ("extra", "key", "phrase"),
    [
        ({"separation": {"iso13855": ISO13855}}, "separation", "give safeguard"),
        (
            {"safeguard": GUARD, "separation": {"iso13855": {"approach_speed": 2.0}}},
            "separation.iso13855",
            "'intrusion_distance' is missing",
        ),
        ({"safeguard": {**GUARD, "latency": -0.1}}, "safeguard.latency", "must be >= 0 s"),
        (
            {"safeguard": GUARD, "separation": {"iso_ts_15066": {**SSM, "human_speed": 0.0}}},
            "separation.iso_ts_15066.human_speed",
            "must be > 0 m/s",
        ),
    ],
)
def test_bad_chain_inputs_get_one_line(tmp_path, capsys, extra, key, phrase):
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(scenario(**extra)))
    assert main(["run", str(path), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"'{key}'" in err[0] and phrase in err[0], err
    assert not (tmp_path / "out").exists()


def test_the_formulas_alone():
    guard = Safeguard(0.1, 0.05, 0.01)
    assert guard.reaction_time == pytest.approx(0.16)
    assert guard.overall(0.5) == pytest.approx(0.66)
    assert Iso13855(1.6, 0.85, 0.0).distance(0.66) == pytest.approx(1.6 * 0.66 + 0.85)
    terms = Ssm(0.1, 0.2, 0.3).terms(0.16, 0.5, 1.0, 0.4)
    assert terms["S_h"] == pytest.approx(1.6 * 0.66) and terms["S_r"] == pytest.approx(0.16)
    assert terms["S_p"] == pytest.approx(math.fsum([1.6 * 0.66, 0.16, 0.4, 0.1, 0.2, 0.3]))


def test_the_printed_chain_shows_each_formula_with_its_inputs(tmp_path, capsys):
    raw = scenario(safeguard=GUARD, separation={"iso13855": ISO13855, "iso_ts_15066": SSM})
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(raw))
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--no-plots"]) == 0
    out = capsys.readouterr().out
    assert "T = t_detection + t_response + t_latency + T_robot = 0.03 + 0.012 + 0.004 +" in out
    assert "S = K T + D_DS + Z = 2 x" in out and "S_p = S_h + S_r + S_s + C + Z_d + Z_r" in out
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert (
        summary["figures"]["values"]["ssm_distance"]
        > summary["figures"]["values"]["tcp_max_displacement"]
    )
