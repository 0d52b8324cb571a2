import math

import numpy as np
import pinocchio as pin
import pytest
from conftest import RESLIP_BRAKE, RESLIP_KINDS, robot, run_reslip

from vtm_pin import RK4, LockEvent, Problem, compute_energy_momentum, compute_M, simulate
from vtm_pin.core.phase import Phase
from vtm_pin.core.topology import Topology
from vtm_pin.exceptions import BrakeError
from vtm_pin.physics.brakes import ROUNDOFF, Brake, BrakeMode
from vtm_pin.physics.friction import Coulomb, Stribeck
from vtm_pin.physics.stop import Stop

Q0 = np.array([0.0, 1.2, 0.0])  # [rad]
V0 = np.array([2.0, 0.0, 0.0])  # [rad/s]


def run_pendulum(brakes, duration=3.0, dt=1e-4, stop=None, events=(), event_tol=1e-14, v0=V0):
    r = robot("planar_3r")
    integrator = RK4(dt, event_tol=event_tol)
    stop = Stop(0.0) if stop is None else stop
    problem = Problem(r, Q0, v0, duration, tuple(events), tuple(brakes), stop)
    return simulate(problem, integrator)


V_MOVING = np.array([1.0, -2.0, 1.5])  # [rad/s], held by the drives until the stop signal


@pytest.mark.parametrize(
    "law, message",
    [
        (lambda: Coulomb(0.0), r"sliding torque 0.0 N m is not a finite number > 0"),
        (lambda: Coulomb(-5.0), r"sliding torque -5.0 N m is not a finite number > 0"),
        (lambda: Coulomb(math.inf), r"sliding torque inf N m is not a finite number > 0"),
        (
            lambda: Coulomb(5.0, 4.0),
            r"static torque 4.0 N m is not a finite number >= the sliding torque 5.0 N m",
        ),
        (lambda: Coulomb(5.0, ramp=-1.0), r"ramp -1.0 s is not a finite number >= 0"),
        (
            lambda: Stribeck(5.0, 6.0, stribeck_velocity=0.0),
            r"Stribeck velocity 0.0 rad/s is not a finite number > 0",
        ),
        (lambda: Brake("j", delay=-0.1), r"Brake on 'j': delay -0.1 s is not a finite number >= 0"),
    ],
)
def test_brake_rejects_bad_figures(law, message):
    with pytest.raises(BrakeError, match=message):
        law()


def test_category_one_needs_ramp_and_torque_limit():
    with pytest.raises(BrakeError, match="Category-1 stop needs a drive torque limit"):
        Stop(0.0, category=1, ramp_time=0.3)
    with pytest.raises(BrakeError, match="Category-1 stop needs a ramp time > 0 s, got None"):
        Stop(0.0, category=1, torque_limit=np.ones(3))
    with pytest.raises(BrakeError, match="Category-2 stop needs a ramp time > 0 s, got None"):
        Stop(0.0, category=2, torque_limit=np.ones(3))
    with pytest.raises(BrakeError, match="Stop category 3 is not 0, 1 or 2"):
        Stop(0.0, category=3)


def test_holding_torque_is_the_kkt_multiplier():
    """Phase.holding_torque = -lambda of [M J^T; J 0][a; lambda] = [tau - b; 0]."""
    r = robot("rx160l")
    rng = np.random.default_rng(5)
    data = r.model.createData()
    for _ in range(5):
        q = rng.uniform(-1, 1, 6)
        locked = sorted(rng.choice(6, size=3, replace=False).tolist())
        v = rng.uniform(-1, 1, 6)
        v[locked] = 0.0
        topology = Topology(r, locked, q)
        phase = Phase(r, topology)
        hold = phase.holding_torque(0.0, topology.split(q, v))
        M = compute_M(r.model, data, q)
        b = pin.nonLinearEffects(r.model, data, q, v)
        J = np.eye(6)[locked]
        K = np.block([[M, J.T], [J, np.zeros((3, 3))]])
        lam = np.linalg.solve(K, np.concatenate([-b, np.zeros(3)]))[6:]
        np.testing.assert_allclose(hold[locked], -lam, rtol=1e-9, atol=1e-9)
        assert np.all(hold[np.setdiff1d(np.arange(6), locked)] == 0.0)


def test_ideal_brake_is_the_paper_lock():
    ideal = run_pendulum([Brake("joint2")], duration=1.5, stop=Stop(0.8), v0=V_MOVING)
    locked = run_pendulum(
        [], duration=1.5, stop=Stop(0.8), events=[LockEvent(0.8, ("joint2",))], v0=V_MOVING
    )
    assert np.max(np.abs(ideal.events[0].v_plus - ideal.events[0].v_minus)) > 0.1
    np.testing.assert_allclose(ideal.events[0].v_plus, locked.events[0].v_plus, atol=1e-14)
    np.testing.assert_allclose(ideal.q[-1], locked.q[-1], atol=1e-13)


def brake_convergence(levels=(1e3, 1e4, 1e5, 1e6)):
    """Error at t = 1.0 s of a finite brake on joint 2 (engaged at 0.8 s) vs the ideal lock."""
    ideal = run_pendulum([Brake("joint2")], duration=1.0, stop=Stop(0.8), v0=V_MOVING)
    errors = []
    for torque in levels:
        finite = run_pendulum(
            [Brake("joint2", friction=Coulomb(torque, 1e7))],
            duration=1.0,
            stop=Stop(0.8),
            v0=V_MOVING,
        )
        errors.append(
            max(
                np.max(np.abs(finite.v[-1] - ideal.v[-1])),
                np.max(np.abs(finite.q[-1] - ideal.q[-1])),
            )
        )
    return np.array(errors)


def test_growing_brake_torque_converges_to_ideal_jump():
    errors = brake_convergence()
    # The sliding phase lasts ~p/tau, so the error falls like 1/tau: x10 per decade.
    ratios = errors[:-1] / errors[1:]
    assert np.all(ratios > 5.0), (errors, ratios)
    assert errors[-1] < 1e-4


def test_state_machine_sticks_reverses_and_slips():
    result = run_reslip(RK4(1e-4))
    assert [e.kind for e in result.brake_events][:8] == RESLIP_KINDS
    static = RESLIP_BRAKE.static(0.0, 1.0)  # [N m], gear ratio 1
    for event in result.brake_events:
        if event.kind in ("stick", "reverse"):
            assert abs(event.v) <= 1e-12  # [rad/s] located on the zero crossing
        if event.kind == "stick":
            assert abs(event.holding_torque) <= static
        if event.kind == "reverse":
            assert abs(event.holding_torque) > static
        if event.kind == "slip":
            # The slip event is the root of static + ROUNDOFF |hold| - |hold| (the stick
            # decision's own test; the only holding torque is this joint's): located to
            # round-off.
            limit = static + ROUNDOFF * abs(event.holding_torque)
            assert abs(abs(event.holding_torque) - limit) < 1e-8
    # While stuck, the required holding torque stays within the static limit (+ round-off).
    stuck = result.modes[:, 0] == BrakeMode.STUCK
    assert np.all(np.abs(result.holding[stuck, 0]) <= static * (1.0 + ROUNDOFF) + 1e-8)


def test_event_times_are_located_to_1e10_seconds():
    """Refining the root tolerance (1e-12 -> 1e-14 s) and the step (1e-4 -> 5e-5 s).

    Measured: 6e-12 s and 1.3e-13 s over four successive events (an early event's error
    carries into the later ones, so a 1e-10 s tolerance alone would not give 1e-10 s there).
    """
    times = {}
    for tol, dt in [(1e-12, 1e-4), (1e-14, 1e-4), (1e-14, 5e-5)]:
        result = run_pendulum([RESLIP_BRAKE], duration=2.0, dt=dt, event_tol=tol)
        times[(tol, dt)] = np.array([e.t for e in result.brake_events[1:5]])
    assert np.max(np.abs(times[(1e-12, 1e-4)] - times[(1e-14, 1e-4)])) <= 1e-10
    assert np.max(np.abs(times[(1e-14, 5e-5)] - times[(1e-14, 1e-4)])) <= 1e-10


@pytest.mark.parametrize("name", ["rx160l_estop_cat0", "ur5_estop_cat0"])
def test_energy_balance_over_a_braked_stop(name):
    """(T + V) lost = brake friction work + energy lost at locks, to the integrator's accuracy."""
    from conftest import SCENARIOS

    from vtm_pin import load_scenario, run_scenario

    scenario = load_scenario(SCENARIOS / f"{name}.yaml")
    result = run_scenario(scenario)
    energy = compute_energy_momentum(scenario.robot, result).total
    locks = sum(e.transition.energy_loss for e in result.events)
    lost = energy[0] - energy[-1]
    assert result.brake_work[-1] > 1.0  # [J]: the brakes did real work
    # RK4 at dt = 1e-4 s: measured residual ~1e-12 J on ~100 J of work.
    assert abs(lost - (result.brake_work[-1] + locks)) <= 1e-9 * max(1.0, abs(lost))


def test_category_one_ramp_stops_within_torque_limits():
    r = robot("planar_3r")
    limit = np.array([3000.0, 2000.0, 1000.0])
    stop = Stop(0.0, category=1, ramp_time=0.5, torque_limit=limit)
    brakes = [Brake(j, delay=0.05, friction=Coulomb(2000.0, 3000.0)) for j in r.joints]
    q0, v0 = np.array([0.2, 0.3, 0.1]), np.array([1.0, -1.0, 0.5])
    result = simulate(Problem(r, q0, v0, 1.0, brakes=tuple(brakes), stop=stop), RK4(1e-4))
    at_ramp_end = np.flatnonzero(result.t == 0.5)[0]
    assert np.max(np.abs(result.v[at_ramp_end])) < 1e-3  # [rad/s]: the drives stopped it
    assert [e.kind for e in result.brake_events[:3]] == ["engage", "engage", "engage"]
    assert all(math.isclose(e.t, 0.55) for e in result.brake_events[:3])  # ramp end + delay
    # The arm is nearly still: every brake sticks within 1e-5 s of engaging.
    assert [e.kind for e in result.brake_events[3:]] == ["stick"] * 3
    assert all(0.55 <= e.t < 0.55 + 1e-5 for e in result.brake_events[3:])
    energy = compute_energy_momentum(r, result).total
    balance = energy[0] - energy[-1] - (result.brake_work[-1] - result.drive_work[-1])
    assert abs(balance) < 1e-6  # [J] of ~100 J moved by the drives


#: At q = (0, 1.2, 0) rad the pendulum's gravity load needs -611.24 N m at joint 1 to hold
#: it at rest with joints 2 and 3 free (the lock's multiplier, measured).
Q_LOADED = np.array([0.0, 1.2, 0.0])  # [rad]


def engage_at_rest(v1: float, static: float, **kwargs):
    """Joint 1 braked from t = 0 on, starting at rate ``v1``; joints 2 and 3 free at rest."""
    brake = Brake("joint1", friction=Coulomb(0.75 * static, static, **kwargs))
    v0 = np.array([v1, 0.0, 0.0])
    problem = Problem(robot("planar_3r"), Q_LOADED, v0, 0.3, brakes=(brake,), stop=Stop())
    return simulate(problem, RK4(1e-4))


@pytest.mark.parametrize("v1", [0.0, 1e-15, -1e-15, 2e-20, -9e-19])
def test_engaging_at_rest_sticks_when_the_brake_can_hold(v1):
    """Rates that are zero to round-off go through the stick/slip decision (no sliding)."""
    result = engage_at_rest(v1, static=1e5)  # [N m], far above any load of the swing
    first = result.brake_events[1]
    assert (first.kind, first.t) == ("stick", 0.0)
    assert first.holding_torque == pytest.approx(-611.24, abs=0.01)  # [N m]
    after = slice(1, None)  # sample 0 is the initial state, before the brake engages
    assert np.all(result.v[after, 0] == 0.0) and np.all(result.q[:, 0] == 0.0)
    assert result.brake_work[-1] == 0.0


@pytest.mark.parametrize("v1", [0.0, 1e-15, -1e-15, 2e-20])
def test_engaging_at_rest_starts_sliding_with_the_load_when_it_cannot_hold(v1):
    """Too weak to hold: the joint starts sliding in the direction of the load, never the
    other way, and the friction opposes the motion it starts (work >= 0, never decreasing)."""
    result = engage_at_rest(v1, static=100.0)  # [N m] < 611 N m needed
    start = result.brake_events[1]
    assert start.kind == "start" and abs(start.holding_torque) > 100.0
    direction = -np.sign(start.holding_torque)  # the load drives against the holding torque
    moving = np.abs(result.v[:, 0]) > 1e-9  # [rad/s] REST_RATE: not the initial round-off
    assert np.all(np.sign(result.v[moving, 0])[:50] == direction)
    assert result.brake_work[-1] > 0.0
    # Work is integrated with the state: non-decreasing up to RK4 round-off (1e-12 J).
    assert np.min(np.diff(result.brake_work)) >= -1e-12


def test_a_lock_that_reverses_a_sliding_joint_reverses_its_friction():
    """Locking joint 2 at 0.01 s flips joint 3 from -1.97 to +1.11 rad/s: its brake must now
    push the other way, so that it keeps removing energy."""
    r = robot("planar_3r")
    brake = Brake("joint3", friction=Coulomb(1.0))
    v0 = np.array([0.0, 3.0, -2.0])  # [rad/s]
    events = (LockEvent(0.01, ("joint2",)),)
    problem = Problem(r, np.zeros(3), v0, 0.3, events, brakes=(brake,), stop=Stop())
    result = simulate(problem, RK4(1e-4))
    event = result.events[0]
    assert event.v_minus[2] < -1.0 and event.v_plus[2] > 1.0
    reverse = result.brake_events[1]
    assert (reverse.kind, reverse.t) == ("reverse", 0.01)
    after = (result.t > 0.01) & (np.abs(result.v[:, 2]) > 0.0)
    assert np.all(result.modes[after, 2] == BrakeMode.FORWARD)
    assert np.min(np.diff(result.brake_work)) >= -1e-12  # [J] RK4 round-off


def test_category_one_resting_joints_stay_at_rest_when_the_brakes_engage():
    """Section 1 of the trustworthy-stops issue on the pendulum: joint 1 ramps down, joints 2
    and 3 are at rest (2e-20 rad/s after the ramp) when the brakes engage; they must stick."""
    r = robot("planar_3r")
    limit = np.array([3000.0, 2000.0, 1000.0])  # [N m]
    stop = Stop(0.0, category=1, ramp_time=0.3, torque_limit=limit)
    # Joint 1 needs 1364 N m to hold after the others stick: every brake can hold.
    brakes = [Brake(j, delay=0.05, friction=Coulomb(2000.0, 2500.0)) for j in r.joints]
    q0, v0 = np.array([0.0, 0.3, 0.1]), np.array([1.0, 0.0, 0.0])
    result = simulate(Problem(r, q0, v0, 0.6, brakes=tuple(brakes), stop=stop), RK4(1e-4))
    after = result.t > 0.35  # the sample at 0.35 s itself is the state before engagement
    assert np.all(result.v[after][:, 1:] == 0.0)
    assert result.brake_work[-1] >= 0.0 and np.min(np.diff(result.brake_work)) >= -1e-12
    assert np.all(result.v[-1] == 0.0)


@pytest.mark.parametrize(
    "mode, sliding, sign",
    [
        (BrakeMode.FREE, False, 0.0),
        (BrakeMode.FORWARD, True, 1.0),
        (BrakeMode.BACKWARD, True, -1.0),
        (BrakeMode.STUCK, False, 0.0),
        (BrakeMode.LOCKED, False, 0.0),
    ],
)
def test_a_mode_says_whether_it_slides_and_which_way(mode, sliding, sign):
    assert mode.sliding is sliding and mode.sign == sign
