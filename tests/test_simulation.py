import numpy as np
import pinocchio as pin
import planar_reference as ref
import pytest
import scipy.integrate
from conftest import robot

from vtm_pin import (
    RK4,
    LockEvent,
    Problem,
    ProblemError,
    SimulationError,
    compute_energy_momentum,
    simulate,
)
from vtm_pin.numerics.integrators import DOP853

Q0 = np.full(3, np.pi / 6)  # [rad], the paper's release pose
PAPER_EVENTS = [LockEvent(0.8, ("joint2",)), LockEvent(1.3, ("joint3",))]
OFF_GRID_EVENTS = [LockEvent(0.80037, ("joint2",)), LockEvent(1.30071, ("joint3",))]


def run(dt, events=PAPER_EVENTS, transition="kkt", duration=2.0):
    problem = Problem(robot("planar_3r"), Q0, np.zeros(3), duration, tuple(events))
    return simulate(problem, RK4(dt), transition=transition)


def closed_form_reference(events, rtol=1e-12):
    """The paper example with closed-form dynamics, DOP853 and a hand-written KKT jump."""
    q, v = Q0.copy(), np.zeros(3)
    locked: list[int] = []
    t = 0.0
    v_plus = []
    for t_end, lock in [*[(e.t, e.lock) for e in events], (2.0, ())]:
        free = [i for i in range(3) if i not in locked]
        q_lock = q.copy()

        def f(_t, y, free=free, q_lock=q_lock):
            qq, vv = q_lock.copy(), np.zeros(3)
            qq[free], vv[free] = y[: len(free)], y[len(free) :]
            M, b = ref.mass_matrix(qq), ref.bias(qq, vv)
            a = np.linalg.solve(M[np.ix_(free, free)], -b[free])
            return np.concatenate([vv[free], a])

        sol = scipy.integrate.solve_ivp(
            f, (t, t_end), np.concatenate([q[free], v[free]]), "DOP853", rtol=rtol, atol=rtol
        )
        q[free], v[free] = sol.y[: len(free), -1], sol.y[len(free) :, -1]
        t = t_end
        if not lock:
            break
        locked += [int(name[-1]) - 1 for name in lock]
        M = ref.mass_matrix(q)
        J = np.eye(3)[locked]
        K = np.block([[M, J.T], [J, np.zeros((len(locked), len(locked)))]])
        dv = np.linalg.solve(K, np.concatenate([np.zeros(3), -J @ v]))[:3]
        v = v + dv
        v[locked] = 0.0
        v_plus.append(v.copy())
    return v_plus, q, v


def test_paper_example_matches_independent_closed_form():
    """RK4 (dt = 1e-4) on Pinocchio vs DOP853 (rtol 1e-12) on a closed-form model.

    Measured agreement ~2e-13; tolerance 1e-10 leaves room for the reference's rtol of
    1e-12 amplified over 2 s of motion.
    """
    result = run(1e-4)
    v_plus, q_end, v_end = closed_form_reference(PAPER_EVENTS)
    np.testing.assert_allclose(result.events[0].v_plus, v_plus[0], rtol=0, atol=1e-10)
    np.testing.assert_allclose(result.events[1].v_plus, v_plus[1], rtol=0, atol=1e-10)
    np.testing.assert_allclose(result.q[-1], q_end, rtol=0, atol=1e-10)
    np.testing.assert_allclose(result.v[-1], v_end, rtol=0, atol=1e-10)
    # The digits quoted in the issue.
    np.testing.assert_allclose(result.events[0].v_plus, [-2.0245, 0.0, 1.3059], atol=5e-5)


def test_consistent_rules_give_the_same_motion_and_naive_does_not():
    runs = {rule: run(1e-3, transition=rule) for rule in ("kkt", "projected", "minimal", "naive")}
    for rule in ("projected", "minimal"):
        np.testing.assert_allclose(runs[rule].q, runs["kkt"].q, rtol=0, atol=1e-10)
        np.testing.assert_allclose(runs[rule].v, runs["kkt"].v, rtol=0, atol=1e-9)
    # The naive rule ends in a different pose: ~0.2 rad on joint 1 in the paper example.
    assert np.max(np.abs(runs["naive"].q[-1] - runs["kkt"].q[-1])) > 0.1


def test_events_are_hit_exactly_and_locked_joints_stay_put():
    result = run(1e-3, OFF_GRID_EVENTS)
    for event in OFF_GRID_EVENTS:
        hits = np.flatnonzero(result.t == event.t)
        assert hits.size == 2  # sample before and after the jump
    i2 = np.flatnonzero(result.t == OFF_GRID_EVENTS[0].t)[1]
    assert np.all(result.q[i2:, 1] == result.q[i2, 1])  # q2 is exactly constant once locked
    assert np.all(result.v[i2:, 1] == 0.0)
    assert not result.free[-1, 1] and result.free[-1, 0]


def test_energy_is_conserved_between_events_and_drops_by_the_recorded_loss():
    r = robot("planar_3r")
    result = run(1e-4)
    energy = compute_energy_momentum(r, result).total
    bounds = [0, *[np.flatnonzero(result.t == e.t)[0] for e in result.events], result.t.size - 1]
    starts = [0, *[np.flatnonzero(result.t == e.t)[1] for e in result.events]]
    for start, end in zip(starts, bounds[1:], strict=True):
        drift = np.max(np.abs(energy[start : end + 1] - energy[start]))
        # RK4 at dt = 1e-4: measured ~1e-11 J on |E| ~ 3e3 J; 1e-9 J leaves a 100x margin.
        assert drift < 1e-9
    for event in result.events:
        before, after = np.flatnonzero(result.t == event.t)
        assert energy[before] - energy[after] == pytest.approx(
            event.transition.energy_loss, rel=1e-12
        )


def test_energy_drift_falls_with_fourth_order():
    r = robot("planar_3r")
    drifts = []
    for dt in (2e-3, 1e-3):
        result = run(dt, events=[], duration=0.8)
        total = compute_energy_momentum(r, result).total
        drifts.append(np.max(np.abs(total - total[0])))
    assert 2**3.5 < drifts[0] / drifts[1] < 2**4.5


@pytest.mark.parametrize("events", [PAPER_EVENTS, OFF_GRID_EVENTS], ids=["on-grid", "off-grid"])
def test_rk4_converges_with_fourth_order(events):
    dts = [4e-3, 2e-3, 1e-3, 5e-4]
    reference = run(dts[-1] / 16, events)
    errors = [np.max(np.abs(run(dt, events).q[-1] - reference.q[-1])) for dt in dts]
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    # Classical RK4: order 4; asymptotic range reached from dt = 4e-3 on for this motion.
    assert np.all((orders > 3.6) & (orders < 4.4)), orders


def test_lock_at_next_grid_point_would_cost_order_dt():
    """Landing exactly on an off-grid event vs applying it at the next grid point."""
    exact = run(1e-3, OFF_GRID_EVENTS)
    late = run(1e-3, [LockEvent(0.801, ("joint2",)), LockEvent(1.301, ("joint3",))])
    fine = run(1e-3 / 8, OFF_GRID_EVENTS)
    rk4_error = np.max(np.abs(exact.q[-1] - fine.q[-1]))
    late_error = np.max(np.abs(late.q[-1] - fine.q[-1]))
    assert late_error > 1e-4  # O(dt): ~1e-3 rad
    assert late_error > 1e4 * rk4_error


def test_lock_at_time_zero_and_at_the_end():
    result = run(1e-3, [LockEvent(0.0, ("joint1",)), LockEvent(2.0, ("joint2",))])
    assert result.events[0].t == 0.0 and result.events[-1].t == 2.0
    assert np.all(result.q[:, 0] == Q0[0])


def test_bad_arguments_raise_simulation_errors():
    with pytest.raises(SimulationError, match="Unknown transition 'magic'; allowed: kkt"):
        run(1e-3, transition="magic")
    with pytest.raises(ProblemError, match=r"'events\[0\].t': 3.0 s is outside \[0, duration"):
        run(1e-3, [LockEvent(3.0, ("joint1",))])
    with pytest.raises(ProblemError, match=r"'events\[1\].lock': joint 'joint1' locks again"):
        run(1e-3, [LockEvent(0.1, ("joint1",)), LockEvent(0.2, ("joint1",))])
    with pytest.raises(ProblemError, match=r"'duration': -1\.0 is not a finite number of s > 0"):
        run(1e-3, duration=-1.0)


@pytest.mark.parametrize("integrator", [RK4(1e-3), DOP853(1e-8, 1e-10)], ids=["rk4", "dop853"])
def test_progress_callback_sees_time_advance_and_changes_nothing(integrator):
    q0 = np.full(3, np.pi / 6)
    seen = []
    args = (Problem(robot("planar_3r"), q0, np.zeros(3), 2.0, tuple(PAPER_EVENTS)), integrator)
    plain = simulate(*args)
    watched = simulate(*args, progress=seen.append)
    np.testing.assert_array_equal(watched.q, plain.q)
    np.testing.assert_array_equal(watched.t, plain.t)
    assert len(seen) >= plain.rhs_evals and seen[-1] == 2.0
    assert max(seen) == 2.0 and min(seen) >= 0.0


@pytest.mark.parametrize("engine", ["scalar", "batched"])
def test_a_runs_phases_leave_no_reference_cycles(engine: str) -> None:
    """A braked stop's phases (their right-hand sides, their stick/slip events) are freed by
    reference counting, not left to the garbage collector: ~67 objects a study case were in
    cycles before, and their collections cost ~0.1 ms a case. Checked with the collector's
    DEBUG_SAVEALL: nothing of a phase is among what a full collection finds unreachable.
    (SciPy's ``brentq``, which locates the scalar engine's events, wraps its function in a
    closure that refers to itself: the event it located is left to the collector with it.)"""
    import gc

    from vtm_pin.core.batch import run_many
    from vtm_pin.scene.scenario import SCENARIOS_DIR, load_scenario

    scenario = load_scenario(SCENARIOS_DIR / "ur10_annex_b.yaml")
    problems = [scenario.problem] * 3
    gc.collect()
    gc.set_debug(gc.DEBUG_SAVEALL)
    try:
        integrators = [scenario.integrator] * 3
        outcome = run_many(problems, integrators, transition=scenario.transition, engine=engine)
        del outcome
        gc.collect()
        kinds = {type(o).__name__ for o in gc.garbage}
    finally:
        gc.set_debug(0)
        gc.garbage.clear()
    assert not kinds & {"Phase", "Topology", "BrakeStateEvent", "EventSpec", "method"}, kinds


@pytest.mark.parametrize("reduced", [True, False], ids=["scalar loop", "batched loop"])
def test_the_loops_momentum_is_m_v(reduced: bool) -> None:
    """The momentum M v a lock at rest keeps (its p_free) comes from RNEA: on the weightless
    model in the scalar engine's loop, on the full model less g(q) in the batched engine's
    (which builds no weightless model a case). Both are CRBA's M times v within 1e-12
    relative to |g| + |M v| (the second subtracts g(q), ~1e2 N m on the UR10, at ~1e-16)."""
    from vtm_pin.core.simulation import _Hybrid, momentum
    from vtm_pin.numerics.dynamics import compute_M
    from vtm_pin.scene.scenario import SCENARIOS_DIR, load_scenario

    problem = load_scenario(SCENARIOS_DIR / "ur10_annex_b.yaml").problem
    robot = problem.robot
    rng = np.random.default_rng(4)
    for _ in range(5):
        q, v = rng.uniform(-3.0, 3.0, robot.nv), rng.uniform(-2.0, 2.0, robot.nv)
        h = _Hybrid(robot, q, v, problem.brakes, problem.stop, "kkt", reduced=reduced)
        data = robot.model.createData()
        expected = compute_M(robot.model, data, q) @ v
        scale = (
            np.abs(expected).max()
            + np.abs(pin.computeGeneralizedGravity(robot.model, data, q)).max()
        )
        p = momentum(robot, h.data, h.q, h.v, reduced)
        np.testing.assert_allclose(p, expected, rtol=0, atol=1e-12 * scale)


@pytest.mark.parametrize("engine", ["scalar", "batched"])
def test_locks_at_rest_are_recorded_when_first_read(engine: str, monkeypatch) -> None:
    """A brake that sticks at rest is kept by the hybrid loop as a pending lock; its record
    (whose transition needs the momentum M v) is made when the run's records are first read,
    once. It is the at-rest jump: v+ = v- to the bit, no impulse, no energy lost, the free
    momentum kept, and that momentum is CRBA's M v at the lock within 1e-12 of |M v| + |g|
    (RNEA's round-off). Pickled, the records are their tuple."""
    import pickle

    from vtm_pin.core import simulation
    from vtm_pin.core.batch import run_many
    from vtm_pin.core.results import LockKind, LockRecords
    from vtm_pin.numerics.dynamics import compute_M
    from vtm_pin.scene.scenario import SCENARIOS_DIR, load_scenario

    made = []
    record = simulation._RestLock.record
    monkeypatch.setattr(simulation._RestLock, "record", lambda self: made.append(1) or record(self))
    scenario = load_scenario(SCENARIOS_DIR / "ur10_annex_b.yaml")
    problems, integrators = [scenario.problem] * 2, [scenario.integrator] * 2
    outcome = run_many(problems, integrators, transition=scenario.transition, engine=engine)
    events = outcome.results[0].events
    assert isinstance(events, LockRecords)
    count = len(events)
    assert made == []  # neither the run nor len() made a record
    records = list(events)
    sticks = [e for e in records if e.kind is LockKind.STICK]
    assert len(records) == count and len(made) == len(sticks) >= 3
    assert list(events) == records and len(made) == len(sticks)  # made once
    robot = scenario.problem.robot
    data = robot.model.createData()
    for event in sticks:
        tr = event.transition
        np.testing.assert_array_equal(tr.v_plus, event.v_minus)
        assert tr.energy_loss == 0.0 and not tr.Lambda.any()
        np.testing.assert_array_equal(tr.p_free_minus, tr.p_free_plus)
        held = [robot.joints.index(name) for name in (*event.locked_before, *event.lock)]
        free = np.setdiff1d(np.arange(robot.nv), held)
        expected = (compute_M(robot.model, data, event.q) @ event.v_minus)[free]
        g = pin.computeGeneralizedGravity(robot.model, data, event.q)
        scale = np.abs(expected).max(initial=0.0) + np.abs(g).max()
        np.testing.assert_allclose(tr.p_free_minus, expected, rtol=0, atol=1e-12 * scale)
    copied = pickle.loads(pickle.dumps(events))
    assert isinstance(copied, LockRecords) and len(copied) == count
    for mine, theirs in zip(records, copied, strict=True):
        assert (mine.t, mine.kind, mine.lock) == (theirs.t, theirs.kind, theirs.lock)
        np.testing.assert_array_equal(mine.v_plus, theirs.v_plus)
        np.testing.assert_array_equal(mine.transition.p_free_minus, theirs.transition.p_free_minus)


def test_a_studys_records_read_no_lock_record(monkeypatch) -> None:
    """A study's case records need none of its runs' lock records: no lock at rest is
    recorded (4-6 % of a UR10 case's time, issue 27)."""
    from vtm_pin.core import simulation
    from vtm_pin.study.cases import find_study, load_study
    from vtm_pin.study.runner import CaseTask, run_cases

    made = []
    record = simulation._RestLock.record
    monkeypatch.setattr(simulation._RestLock, "record", lambda self: made.append(1) or record(self))
    study = load_study(find_study("ur10_envelope"))
    tasks = [
        CaseTask(study.base, str(study.scenario.parent), str(study.scenario), "s", case, "f")
        for case in study.cases()[:20]
    ]
    records = run_cases(tasks)
    assert all(r["status"] == "ok" for r in records), records[0]["status"]
    assert made == []
