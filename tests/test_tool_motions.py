"""Stopping reports made together (issue 27): many runs' tool motions in one pass.

A study's runner makes the reports of up to ``runner.REPORT_CASES`` finished cases together:
their runs' joint placements and tool paths are one NumPy forward-kinematics pass, and their
arms' largest displacements one search (:func:`vtm_pin.outputs.stopping.tool_motions`),
instead of one of each per run, whose fixed overhead was most of its cost at a study case's
~80 samples.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import SCENARIOS
from hypothesis import given, settings
from hypothesis import strategies as st

from vtm_pin.core.batch import run_many
from vtm_pin.core.results import SimulationResult
from vtm_pin.outputs.stopping import (
    _rest_times,
    compute_stopping_report,
    rest_times,
    sample_figures,
    signal_row,
    tool_motion,
    tool_motions,
)
from vtm_pin.physics.arm_points import max_displacement, point_speeds, sample_arm_points
from vtm_pin.physics.kinematics import compute_tool_jacobian
from vtm_pin.physics.robot import RobotCache
from vtm_pin.scene.scenario import build_scenario, load_scenario
from vtm_pin.study import runner
from vtm_pin.study.cases import find_study, load_study, resolve_case
from vtm_pin.study.runner import CaseTask, run_cases

#: [m, -] A run's motion from the stacked pass against its own: the same products sample by
#: sample, so equal but for a BLAS kernel that blocks a longer stack otherwise (~1e-16 a
#: product; measured: equal to the bit on these runs).
ROUND_OFF = 1e-12


def envelope_cases(count: int) -> list[CaseTask]:
    study = load_study(find_study("ur10_envelope"))
    chosen = study.cases()[:count]
    return [
        CaseTask(study.base, str(study.scenario.parent), str(study.scenario), "t", c)
        for c in chosen
    ]


@pytest.fixture(scope="module")
def mixed_runs():
    """UR10 envelope cases (several payload classes: one kinematics, several models), one with
    another tool frame, and the UR5 and pendulum scenarios (other kinematics)."""
    robots = RobotCache()
    built = [
        build_scenario(
            resolve_case(t.base, t.case.values),
            source="t",
            base_dir=Path(t.base_dir),
            name="t",
            loader=robots,
        )
        for t in envelope_cases(8)
    ]
    built += [
        load_scenario(SCENARIOS / f"{name}.yaml") for name in ("ur5_estop_cat0", "pendulum3r")
    ]
    outcome = run_many([s.problem for s in built], [s.integrator for s in built])
    runs = [
        (s.robot, r, s.tool_frame)
        for s, r in zip(built, outcome.results, strict=True)
        if isinstance(r, SimulationResult)
    ]
    robot, result, _ = runs[1]
    elbow = next(f.name for f in robot.model.frames if f.parentJoint == 3)  # another joint's
    runs.insert(2, (robot, result, elbow))
    return built, runs


def test_many_runs_motions_are_each_runs_own(mixed_runs) -> None:
    _, runs = mixed_runs
    assert len({id(robot) for robot, _, _ in runs}) >= 4  # several models in one call
    together = tool_motions(runs)
    assert len(together) == len(runs)
    for (robot, result, frame), motion in zip(runs, together, strict=True):
        own = tool_motion(robot, result, frame)
        assert len(motion.path) == len(result.t) - signal_row(result)
        ours = (motion.path, motion.speed, *motion.placements)
        for a, b in zip(ours, (own.path, own.speed, *own.placements), strict=True):
            assert a.shape == b.shape
            np.testing.assert_allclose(a, b, rtol=0.0, atol=ROUND_OFF)
        q = result.q[signal_row(result) :]
        arm = max_displacement(robot, sample_arm_points(robot), q, swept=False)
        assert own.arm is None and motion.arm is not None
        assert motion.arm.distance == pytest.approx(arm.distance, rel=0.0, abs=ROUND_OFF)
        assert (motion.arm.index, motion.arm.sample) == (arm.index, arm.sample)
        # what the report reads at the signal, against Pinocchio's at q, v there
        fastest = np.max(
            point_speeds(robot, sample_arm_points(robot), q[0], result.v[len(result.v) - len(q)])
        )
        assert motion.arm_speed == pytest.approx(fastest, rel=0.0, abs=ROUND_OFF)
        jac = compute_tool_jacobian(robot, q[0], frame)
        np.testing.assert_allclose(motion.column_norms, np.linalg.norm(jac, axis=0), atol=ROUND_OFF)


def test_another_tool_frame_is_followed_apart(mixed_runs) -> None:
    _, runs = mixed_runs
    together = tool_motions(runs)
    assert runs[1][1] is runs[2][1] and runs[1][2] != runs[2][2]
    assert np.max(np.abs(together[1].path - together[2].path)) > 1e-3  # another point
    np.testing.assert_allclose(together[1].placements[1], together[2].placements[1], atol=0.0)


def test_a_report_refuses_a_motion_of_another_run(mixed_runs) -> None:
    built, runs = mixed_runs
    robot, result, frame = runs[0]
    other = tool_motion(*runs[-1])
    with pytest.raises(ValueError, match="samples"):
        compute_stopping_report(robot, result, built[0].brakes, frame, other)


def strip(records: list[dict]) -> list[dict]:
    return [
        {k: v for k, v in r.items() if k not in ("timing", "wall_time", "engine_split")}
        for r in records
    ]


def test_study_records_do_not_depend_on_how_many_reports_are_made_together(monkeypatch) -> None:
    tasks = envelope_cases(10)
    monkeypatch.setattr(runner, "REPORT_CASES", 1)
    alone = run_cases(tasks)
    monkeypatch.setattr(runner, "REPORT_CASES", 4)  # 4, 4 and the batch's last 2
    together = run_cases(tasks)
    assert all(r["status"] == "ok" for r in together)
    assert strip(together) == strip(alone)
    assert all(r["timing"]["report"] > 0.0 for r in together)


def test_a_failing_joint_pass_fails_no_case(monkeypatch) -> None:
    """Making the reports together is an optimisation: if it raises, each report makes its own."""
    tasks = envelope_cases(6)
    working = run_cases(tasks)

    def broken(runs):
        raise RuntimeError("boom")

    monkeypatch.setattr("vtm_pin.outputs.stopping.tool_motions", broken)
    alone = strip(run_cases(tasks))
    # each report then takes the arm's and the tool's speeds at the signal from Pinocchio's
    # kinematics there, not NumPy's: the same to round-off
    for a, b in zip(alone, strip(working), strict=True):
        assert a["status"] == b["status"] == "ok"
        assert {k: v for k, v in a.items() if k != "metrics"} == {
            k: v for k, v in b.items() if k != "metrics"
        }
        assert a["metrics"].keys() == b["metrics"].keys()
        for key, value in a["metrics"].items():
            other = b["metrics"][key]
            assert (value is None) == (other is None), key
            if value is not None:
                assert value == pytest.approx(other, rel=ROUND_OFF, abs=ROUND_OFF), key


def test_each_runs_sample_figures_are_its_own_to_the_bit(mixed_runs) -> None:
    """Figures formed over many runs' stacked samples are each run's own, computed alone."""
    _, runs = mixed_runs
    together = tool_motions(runs)
    for (_, result, _), motion in zip(runs, together, strict=True):
        assert motion.figures is not None
        alone = sample_figures([result], [signal_row(result)], motion.path, motion.speed)[0]
        np.testing.assert_array_equal(motion.figures.rest_times, alone.rest_times)
        for name in ("distance", "length", "peak_speed", "reach"):
            assert getattr(motion.figures, name) == getattr(alone, name), name
        # and what they are, by their definitions
        path = motion.path
        assert alone.distance == pytest.approx(np.linalg.norm(path[-1] - path[0]), abs=1e-15)
        assert alone.length == np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1))
        assert alone.peak_speed == np.max(motion.speed)
        assert alone.reach == np.max(np.linalg.norm(path - path[0], axis=1))


def rest_time_by_hand(t: list[float], speed: list[float], rest: float) -> float:
    """When |v| falls below ``rest`` for good, sample by sample (linear in between)."""
    above = [i for i, s in enumerate(speed) if abs(s) > rest]
    if not above:
        return t[0]
    a = above[-1]
    if a == len(t) - 1:
        return math.nan  # still moving at the end
    if t[a + 1] == t[a]:  # an event: the speed drops at its time
        return t[a]
    fraction = (abs(speed[a]) - rest) / (abs(speed[a]) - abs(speed[a + 1]))
    return t[a] + fraction * (t[a + 1] - t[a])


@settings(max_examples=200, deadline=None)
@given(
    runs=st.lists(
        st.tuples(
            st.lists(st.floats(-2.0, 2.0), min_size=1, max_size=12),  # joint 1's rates
            st.lists(st.booleans(), min_size=12, max_size=12),  # which steps are events
            st.floats(1e-4, 0.5),  # rest speed
        ),
        min_size=1,
        max_size=5,
    )
)
def test_rest_times_of_stacked_runs_follow_their_definition(runs) -> None:
    """Per run and joint: the time |v| falls below the rest speed for good, whatever stacks."""
    ts, vs, rests, counts = [], [], [], []
    for rates, events, rest in runs:
        steps = [0.0 if e else 0.01 for e in events[: len(rates) - 1]]
        ts.append(np.concatenate([[0.3], 0.3 + np.cumsum(steps)]))
        vs.append(np.column_stack([rates, np.zeros(len(rates)), np.array(rates[::-1]) / 3]))
        rests.append(rest)
        counts.append(len(rates))
    counts_a = np.array(counts)
    firsts = np.concatenate([[0], np.cumsum(counts_a)[:-1]]).astype(int)
    out = _rest_times(np.concatenate(ts), np.concatenate(vs), np.array(rests), firsts, counts_a)
    assert out.shape == (len(runs), 3)
    for r, (t, v, rest) in enumerate(zip(ts, vs, rests, strict=True)):
        np.testing.assert_array_equal(rest_times(t, v, rest), out[r])  # one run alone
        for j in range(3):
            expected = rest_time_by_hand(list(t), list(v[:, j]), rest)
            # the same formula, term by term: equal to the bit (NaN: still moving)
            np.testing.assert_array_equal(out[r, j], expected)
