import numpy as np
import pytest
from conftest import RESLIP_KINDS, robot, run_reslip

from vtm_pin import RK4, LockEvent, Problem, compute_energy_momentum, simulate
from vtm_pin.numerics.integrators import DOP853, SemiImplicitEuler

Q0 = np.full(3, np.pi / 6)  # [rad]
PAPER = [LockEvent(0.8, ("joint2",)), LockEvent(1.3, ("joint3",))]
OFF_GRID = [LockEvent(0.80037, ("joint2",)), LockEvent(1.30071, ("joint3",))]
INTEGRATORS = [RK4(1e-3), SemiImplicitEuler(1e-4), DOP853(1e-10, 1e-12)]


def run(integrator, events=PAPER, duration=2.0, v0=None, **kwargs):
    v0 = np.zeros(3) if v0 is None else v0
    return simulate(
        Problem(robot("planar_3r"), Q0, v0, duration, tuple(events)), integrator, **kwargs
    )


@pytest.fixture(scope="module")
def reference():
    """DOP853 at rtol 1e-13: ~1e-13 rad from the closed-form reference (test_simulation)."""
    return {id(e): run(DOP853(1e-13, 1e-15), e) for e in (PAPER, OFF_GRID)}


@pytest.mark.parametrize("integrator", INTEGRATORS, ids=lambda i: i.name)
def test_time_events_are_hit_exactly(integrator):
    result = run(integrator, OFF_GRID)
    for event in OFF_GRID:
        assert np.count_nonzero(result.t == event.t) == 2
    assert result.t[-1] == 2.0


@pytest.mark.parametrize(
    "integrator, tolerance",
    [(RK4(1e-3), 1e-9), (SemiImplicitEuler(1e-5), 1e-4), (DOP853(1e-10, 1e-12), 1e-9)],
    ids=["rk4", "euler", "dop853"],
)
def test_each_method_reaches_its_accuracy(reference, integrator, tolerance):
    # Tolerances: RK4 dt = 1e-3 measured 8e-11; Euler dt = 1e-5 measured ~1.5e-5 (first order);
    # DOP853 rtol = 1e-10 measured ~6e-12. Each bound leaves a >= 6x margin.
    for events in (PAPER, OFF_GRID):
        error = np.max(np.abs(run(integrator, events).q[-1] - reference[id(events)].q[-1]))
        assert error < tolerance


@pytest.mark.parametrize("events", [PAPER, OFF_GRID], ids=["on-grid", "off-grid"])
def test_semi_implicit_euler_converges_with_first_order(reference, events):
    dts = [4e-4, 2e-4, 1e-4]
    errors = [
        np.max(np.abs(run(SemiImplicitEuler(dt), events).q[-1] - reference[id(events)].q[-1]))
        for dt in dts
    ]
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all((orders > 0.8) & (orders < 1.2)), orders


def test_dop853_error_follows_its_tolerance(reference):
    errors = [
        np.max(np.abs(run(DOP853(rtol, rtol * 1e-2)).q[-1] - reference[id(PAPER)].q[-1]))
        for rtol in (1e-6, 1e-8, 1e-10)
    ]
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 1e-9


@pytest.mark.parametrize("integrator", [RK4(1e-4), DOP853(1e-10, 1e-12)], ids=lambda i: i.name)
def test_state_events_on_dense_output(integrator):
    """The brake state machine runs the same with RK4 re-stepping and DOP853 dense output."""
    result = run_reslip(integrator)
    assert [e.kind for e in result.brake_events][:8] == RESLIP_KINDS
    for event in result.brake_events:
        if event.kind in ("stick", "reverse"):
            assert abs(event.v) <= 1e-12


def test_state_event_times_agree_across_methods():
    times = [
        np.array([e.t for e in run_reslip(integrator, 2.0).brake_events])
        for integrator in (RK4(1e-4), DOP853(1e-11, 1e-13))
    ]
    # Measured 2e-12 s: both methods are accurate far beyond the 1e-10 s asked for.
    np.testing.assert_allclose(times[0], times[1], rtol=0, atol=1e-10)


def energy_drift(integrator, duration):
    r = robot("planar_3r")
    result = simulate(Problem(r, Q0, np.zeros(3), duration), integrator)
    total = compute_energy_momentum(r, result).total
    return result.t, np.abs(total - total[0])


@pytest.mark.slow  # ~10-20 s: a long horizon per method
def test_long_horizon_energy_drift_per_method():
    """100 s without events: energy drift of each method, bounded by its order.

    Measured over 100 s (|E| ~ 3.1e3 J, swing energy ~1.7e3 J): RK4 dt = 1e-3 drifts
    2.3e-6 J; DOP853 rtol 1e-10 6e-7 J. The semi-implicit Euler step in velocity form is
    symplectic only for a constant mass matrix; with M(q) its energy drifts at O(dt): ~125 J
    at dt = 5e-4 and ~52 J at dt = 2.5e-4 after 100 s.
    """
    _, drift = energy_drift(RK4(1e-3), 100.0)
    assert drift[-1] < 1e-4
    _, drift = energy_drift(DOP853(1e-10, 1e-12), 100.0)
    assert drift.max() < 1e-4
    finals = [energy_drift(SemiImplicitEuler(dt), 100.0)[1][-1] for dt in (5e-4, 2.5e-4)]
    assert 1.5 < finals[0] / finals[1] < 3.0  # first order in dt


@pytest.mark.parametrize("integrator", [RK4(2.0), DOP853(1e-10, 1e-12)], ids=lambda i: i.name)
@pytest.mark.parametrize("direction", [-1, 1])
def test_event_from_exactly_zero_fires_when_the_function_comes_back(integrator, direction):
    """g = y0 with y0' = d (1 - 2t), y0(0) = 0: g leaves zero for the side before the
    crossing and returns through zero at t = 1 s, inside one step. It must fire there
    (a joint starting to slide from rest, stopped again by its rising friction)."""
    from vtm_pin.numerics.integrators import StateEvent

    d = -direction  # the side g leaves for first

    def f(t, y):
        return np.array([d * (1.0 - 2.0 * t)])

    event = StateEvent(lambda t, y: float(y[0]), direction)
    segment = integrator.integrate(f, 0.0, np.zeros(1), 2.0, [event])
    assert segment.event == 0
    # [s]: the root of t - t^2 on the method's own solution (exact for both: a quadratic).
    assert segment.t[-1] == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("t0", [0.0, 0.3, 1e3])
def test_event_from_exactly_zero_leaving_to_the_far_side_fires_at_once(t0):
    """No point on the before side: the handler's state disagrees with the motion at once,
    so the event is taken at once (the event tolerance, or a few ulps of t where that is
    larger), not after a whole step of wrong motion, and never at a zero-length step."""
    from vtm_pin.numerics.integrators import StateEvent

    event = StateEvent(lambda t, y: float(y[0]), -1)
    rk4 = RK4(0.5, event_tol=1e-14)
    segment = rk4.integrate(lambda t, y: np.array([-1.0]), t0, np.zeros(1), t0 + 2.0, [event])
    assert segment.event == 0
    assert t0 < segment.t[-1] <= t0 + max(1e-14, 8 * np.spacing(t0 + 0.5))


def van_der_pol(t, y):
    """mu = 1: a smooth limit cycle."""
    return np.array([y[1], (1.0 - y[0] ** 2) * y[1] - y[0]])


def kepler(t, y):
    """Planar two-body orbit, GM = 1 (eccentricity 0.5 from KEPLER_Y0: period 2 pi)."""
    r3 = np.linalg.norm(y[:2]) ** 3
    return np.array([y[2], y[3], -y[0] / r3, -y[1] / r3])


KEPLER_Y0 = np.array([0.5, 0.0, 0.0, np.sqrt(3.0)])  # perihelion of e = 0.5 [-]
#: Final states of our DOP853 and scipy's [-, relative]: the same method and controller, with
#: each stage's sum grouped differently ((1, h A) @ (y, K) against scipy's y + (A @ K) h), so
#: they agree to round-off amplified by the steps: measured <= 5.7e-11 for rtol 1e-6 and 1e-10
#: (2.4e-9 at rtol 1e-4), while at rtol 1e-6 each is ~5e-5 from the exact Kepler orbit.
SCIPY_AGREEMENT = 1e-9
#: Each accepted step against scipy's, relative [-]: h is the same formula of the error
#: estimate, but that estimate is a difference of stages, so at tight tolerances the stages'
#: round-off moves it: measured <= 1e-6 at rtol 1e-6, 3.5e-3 at rtol 1e-10 (van der Pol;
#: 1.7e-2 at 1e-12, where the estimate is mostly round-off). A wrong controller constant moves
#: every step by more (the safety factor 0.9 by 1 % per 0.009).
SCIPY_STEPS = 1e-2


@pytest.mark.parametrize(
    ("f", "y0", "t1"),
    [(van_der_pol, np.array([2.0, 0.0]), 10.0), (kepler, KEPLER_Y0, 4.0 * np.pi)],
    ids=["van_der_pol", "kepler"],
)
@pytest.mark.parametrize("rtol", [1e-6, 1e-10])
def test_dop853_takes_scipys_steps_and_reaches_its_final_state(f, y0, t1, rtol):
    from scipy.integrate import solve_ivp

    ours = DOP853(rtol, rtol * 1e-2).integrate(f, 0.0, y0, t1)
    theirs = solve_ivp(f, (0.0, t1), y0, method="DOP853", rtol=rtol, atol=rtol * 1e-2)
    assert theirs.success
    # the same step-size controller: the same accepted steps and right-hand-side evaluations
    assert ours.t.size == theirs.t.size and ours.rhs_evals == theirs.nfev
    np.testing.assert_allclose(np.diff(ours.t), np.diff(theirs.t), rtol=SCIPY_STEPS, atol=0.0)
    final = theirs.y[:, -1]
    difference = np.linalg.norm(ours.y[-1] - final)
    assert difference <= SCIPY_AGREEMENT * np.linalg.norm(final)
    if f is kepler:  # two full orbits: the two differ by far less than scipy's own error
        assert difference <= 1e-2 * np.linalg.norm(final - y0)


def test_dop853_tables_are_scipys_to_the_last_bit():
    """The tables are the project's own; this pins them to scipy's (private) transcription."""
    from scipy.integrate._ivp import dop853_coefficients as scipy_tables

    from vtm_pin.numerics.integrators import dop853_coefficients as tables

    for name in ("A", "B", "C", "D", "E3", "E5"):
        np.testing.assert_array_equal(getattr(tables, name), getattr(scipy_tables, name), name)
    for name in ("N_STAGES", "N_STAGES_EXTENDED", "INTERPOLATOR_POWER"):
        assert getattr(tables, name) == getattr(scipy_tables, name)


def test_dop853_nested_in_a_right_hand_side_keeps_its_own_stages():
    """An integration inside f (same thread, same state size) leaves the outer one exact.

    The stage buffers are reused per thread; a nested interval must get buffers of its own,
    so the outer result is bit for bit the one without nesting.
    """
    it = DOP853(rtol=1e-10, atol=1e-12)

    def f(t, y):
        return np.array([y[1], -y[0]])

    def f_nested(t, y):
        it.integrate(f, 0.0, np.array([0.3, 0.7]), 0.01)
        return f(t, y)

    plain = it.integrate(f, 0.0, np.array([1.0, 0.0]), 3.0)
    nested = it.integrate(f_nested, 0.0, np.array([1.0, 0.0]), 3.0)
    assert np.array_equal(plain.t, nested.t) and np.array_equal(plain.y, nested.y)


@pytest.mark.parametrize("output_dt", [None, 0.01])
def test_dop853_with_a_writing_right_hand_side_is_bit_for_bit_the_returning_one(output_dt):
    """A right-hand side with ``into`` (a phase's topology) writes the stages in place.

    The result must be the one of the same function called the plain way, with its dense
    output (``output_dt``) and a state event located on it.
    """
    from vtm_pin import Topology
    from vtm_pin.numerics.integrators import StateEvent

    topology = Topology(robot("planar_3r"), [1], Q0)
    y0 = topology.split(Q0, np.array([0.4, 0.0, -0.3]))
    event = StateEvent(lambda t, y: y[0] - 0.2)  # joint 1 swings through 0.2 rad
    it = DOP853(rtol=1e-9, atol=1e-11, output_dt=output_dt)
    writing = it.integrate(topology, 0.0, y0, 2.0, [event])
    plain = it.integrate(lambda t, y: topology.rhs(t, y), 0.0, y0, 2.0, [event])
    assert hasattr(topology, "into") and writing.event == plain.event == 0
    assert np.array_equal(writing.t, plain.t) and np.array_equal(writing.y, plain.y)
    assert writing.rhs_evals == plain.rhs_evals
