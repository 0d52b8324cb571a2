import numpy as np
import pytest
from conftest import SCENARIOS

from vtm_pin import load_scenario, run_scenario
from vtm_pin.outputs.stopping import compute_stopping_report


@pytest.fixture(scope="module")
def paper_locks():
    scenario = load_scenario(SCENARIOS / "rx160l_paper_locks.yaml")
    return scenario, {rule: run_scenario(scenario, rule) for rule in ("kkt", "naive")}


def test_paper_example_two_consistent_vs_naive(paper_locks):
    scenario, runs = paper_locks
    kkt, naive = runs["kkt"], runs["naive"]
    # Locks at 0.05, 0.1, 0.15 s (wrist locked at rest from t = 0).
    assert [e.t for e in kkt.events] == [0.0, 0.05, 0.1, 0.15]
    for event in kkt.events[1:]:
        tr = event.transition
        np.testing.assert_allclose(tr.p_free_plus, tr.p_free_minus, rtol=1e-10, atol=1e-9)
    jumps = [
        np.max(np.abs(e.transition.p_free_plus - e.transition.p_free_minus))
        for e in naive.events[1:3]
    ]
    assert min(jumps) > 1.0  # [N m s]: the naive rule breaks the free joints' momentum
    # The naive rule even creates energy at the joint-2 lock (negative loss).
    assert naive.events[2].transition.energy_loss < 0.0 < kkt.events[2].transition.energy_loss
    # Different final pose: ~0.02 rad at joint 3, 2 rad on the motor side (ratio 100).
    dq_motor = (naive.q[-1] - kkt.q[-1]) * scenario.robot.gear_ratio
    assert np.max(np.abs(dq_motor)) > 1.0


def test_stopping_report_of_prescribed_locks(paper_locks):
    scenario, runs = paper_locks
    report = compute_stopping_report(scenario.robot, runs["kkt"])
    stop_times = [j.stop_time for j in report.joints]
    np.testing.assert_array_equal(stop_times, [0.05, 0.1, 0.15, 0.0, 0.0, 0.0])
    assert report.all_stopped_time == 0.15
    q0 = runs["kkt"].q[0]
    for j, joint in enumerate(report.joints):
        assert joint.stop_angle == pytest.approx(runs["kkt"].q[-1, j] - q0[j])
        assert joint.stop_angle_motor == pytest.approx(
            joint.stop_angle * scenario.robot.gear_ratio[j]
        )
    # Lock impulses equal -Lambda summed per joint.
    first = runs["kkt"].events[1]
    assert report.joints[0].lock_impulse == pytest.approx(
        sum(
            -e.transition.Lambda[list(e.locked_before + e.lock).index("joint_1")]
            for e in runs["kkt"].events
            if "joint_1" in e.locked_before + e.lock
        )
    )
    assert first.lock == ("joint_1",)
    assert report.tcp_path_length >= report.tcp_distance > 0.0
    # Locking joint 1 at 0.05 s speeds joint 3 up from 1.968 to 2.130 rad/s.
    assert report.joints[2].peak_surge == pytest.approx(
        abs(first.v_plus[2]) - abs(first.v_minus[2])
    )
    assert report.joints[2].peak_surge > 0.1


def test_braked_stop_report_margins_and_surges():
    scenario = load_scenario(SCENARIOS / "rx160l_estop_cat0.yaml")
    result = run_scenario(scenario)
    report = compute_stopping_report(scenario.robot, result, scenario.brakes, scenario.tool_frame)
    for j in report.joints[:3]:
        assert 0.08 < j.stop_time < 0.5  # [s] realistic main-axis stops
        assert j.holding_margin > 0.0
        assert j.friction_impulse != 0.0
    for j in report.joints[3:]:
        assert j.stop_time == 0.08 and np.isinf(j.holding_margin)  # ideal wrist brakes
    assert np.all(result.v[-1] == 0.0)


def test_stop_time_is_when_the_speed_stays_below_the_rest_speed():
    """Category 1: the ramp ends the motion (0.3 s) before the brakes latch (0.38 s)."""
    scenario = load_scenario(SCENARIOS / "rx160l_estop_cat1.yaml")
    result = run_scenario(scenario)
    report = compute_stopping_report(scenario.robot, result, scenario.brakes, scenario.tool_frame)
    assert report.rest_speed == 1e-3 and not report.moving
    for j, joint in enumerate(report.joints):
        assert joint.stopped and joint.latch_time == pytest.approx(0.38, abs=1e-3)
        assert joint.stop_time < 0.3 < joint.latch_time
        # After the stopping time the speed stays below the rest speed [rad/s].
        after = result.t >= report.signal_time + joint.stop_time + 1e-9
        assert np.all(np.abs(result.v[after, j]) <= report.rest_speed)
    assert report.all_stopped_time == max(j.stop_time for j in report.joints)


def test_rest_speed_is_a_scenario_key():
    import yaml

    from vtm_pin.scene.scenario import build_scenario

    raw = yaml.safe_load((SCENARIOS / "rx160l_estop_cat0.yaml").read_text())
    times = []
    for rest_speed in (1e-4, 1e-3, 1e-1):
        raw["stop"]["rest_speed"] = rest_speed
        scenario = build_scenario(raw, base_dir=SCENARIOS)
        report = compute_stopping_report(scenario.robot, run_scenario(scenario), scenario.brakes)
        assert report.rest_speed == rest_speed
        times.append([j.stop_time for j in report.joints[:3]])
    # A higher rest speed is reached earlier; the sliding brakes decelerate at a finite
    # rate, so the three thresholds give three different times.
    assert np.all(np.diff(times, axis=0) < 0.0)


def test_a_joint_still_moving_is_said_in_words(tmp_path):
    """Stopped before the brakes act: no NaN in summary.json, no 'nan' in the text."""
    import json

    from vtm_pin.cli import main

    text = (SCENARIOS / "rx160l_estop_cat0.yaml").read_text()
    short = tmp_path / "short.yaml"
    short.write_text(text.replace("duration: 1.0", "duration: 0.1"))
    out = tmp_path / "out"
    assert main(["run", str(short), "--out", str(out), "--quiet"]) == 0
    stopping = json.loads((out / "summary.json").read_text())["stopping"]
    assert stopping["all_stopped"] is False and stopping["all_stopped_time"] is None
    assert stopping["still_moving"] == ["joint_1", "joint_2", "joint_3"]
    first = stopping["joints"][0]
    assert first["stopped"] is False and first["stop_time"] is None
    assert "rest_speed" in stopping["definition"]

    from vtm_pin.outputs.report import format_stopping

    scenario = load_scenario(short)
    report = compute_stopping_report(scenario.robot, run_scenario(scenario), scenario.brakes)
    printed = format_stopping("kkt", report)
    assert "nan" not in printed.lower()
    assert "joint_1, joint_2, joint_3 still moving at the end of the run (t = 0.1 s)" in printed
