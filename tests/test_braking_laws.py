"""Braking laws that decelerate hardest at the start (issue 23): the viscous brake law and the
motors' short-circuit braking, against closed forms, and as properties over their inputs.

The closed forms are for the UR5 (CB3) base joint alone (its other joints held by ideal brakes
from the signal, the arm at rest there, so their locks need no jump): a rotation about the
vertical axis, so gravity does no work and the inertia J = M[0, 0] (armature included) is
constant. With gear ratio N and motor speed N w:

* viscous brake, J dw/dt = -N tau_c (1 + N w / w_v): w(t) = (w0 + a/b) exp(-b t) - a/b with
  a = N tau_c / J, b = N^2 tau_c / (J w_v), at rest at t_s = ln(1 + b w0 / a) / b, having
  turned (w0 - a t_s) / b;
* short-circuit braking, J dw/dt = -N T_pk 2 x / (1 + x^2), x = N w / w_pk, separable:
  t(x) = J w_pk / (2 N^2 T_pk) (ln(x0 / x) + (x0^2 - x^2) / 2).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import robot
from hypothesis import given, settings
from hypothesis import strategies as st

from vtm_pin import Drive, Problem, load_robot, simulate
from vtm_pin.exceptions import BrakeError
from vtm_pin.numerics.dynamics import compute_M
from vtm_pin.numerics.integrators import DOP853
from vtm_pin.physics.brakes import Brake
from vtm_pin.physics.drives import ShortCircuit, short_circuit
from vtm_pin.physics.friction import Coulomb, Viscous
from vtm_pin.physics.stop import Stop

_positive = st.floats(1e-6, 1e6, allow_nan=False, allow_infinity=False)
_speed = st.floats(-1e4, 1e4, allow_nan=False, allow_infinity=False)


@settings(max_examples=200, deadline=None, derandomize=True, database=None)
@given(tau_c=_positive, ratio=st.floats(1.0, 5.0), w_v=_positive, speed=_speed)
def test_viscous_law_never_adds_energy(tau_c, ratio, w_v, speed):
    """Its kinetic torque is >= tau_c > 0 at every speed and grows with it, and the brake's
    torque -sign(v) tau(|N v|) opposes the motion: its power is <= 0."""
    law = Viscous(tau_c, 1.2 * tau_c, viscous_velocity=w_v)
    kinetic = law.kinetic(abs(speed))
    assert kinetic >= tau_c > 0.0
    assert law.kinetic(abs(speed) * 2.0 + 1.0) >= kinetic
    assert law.kinetic(0.0) == tau_c  # at rest: Coulomb's, below the static torque
    brake = Brake("j", friction=law)
    torque = -math.copysign(1.0, speed) * brake.sliding(1.0, abs(speed), ratio)
    assert torque * speed <= 0.0
    # Past rest (slip speed below 0, as an integrator's trial state may see it) the law stays
    # Coulomb's: dissipative, even for a stiff brake far past rest.
    assert law.kinetic(-abs(speed) - 1.0) == tau_c


@settings(max_examples=200, deadline=None, derandomize=True, database=None)
@given(
    peak=st.floats(0.0, 1e4),
    w_pk=_positive,
    ratio=st.floats(1.0, 200.0),
    v=st.lists(_speed, min_size=1, max_size=6),
)
def test_short_circuit_never_adds_energy(peak, w_pk, ratio, v):
    """tau(v) v <= 0 for every joint rate; the torque is odd in v and never above N T_pk."""
    n = len(v)
    law = ShortCircuit(np.full(n, peak), np.full(n, w_pk), np.full(n, ratio))
    v = np.array(v)
    tau = law.joint_torque(v)
    assert np.all(tau * v <= 0.0)
    assert np.array_equal(law.joint_torque(-v), -tau)
    assert np.all(np.abs(tau) <= ratio * peak * (1.0 + 1e-12))


def test_short_circuit_curve_peaks_at_its_speed():
    """T(w) = T_pk 2 x / (1 + x^2): slope 2 T_pk / w_pk at rest, T_pk at w_pk, T_pk/5 at 10 w_pk
    (the torque-speed curve of a shorted PMSM), joint side x N."""
    law = ShortCircuit(np.array([0.5]), np.array([200.0]), np.array([100.0]))
    joint = lambda w_motor: -law.joint_torque(np.array([w_motor / 100.0]))[0]  # noqa: E731
    assert joint(200.0) == pytest.approx(100.0 * 0.5)
    assert joint(2000.0) == pytest.approx(100.0 * 0.5 * 20.0 / 101.0)
    assert joint(1e-3) / 1e-3 == pytest.approx(100.0 * 2.0 * 0.5 / 200.0, rel=1e-6)
    speeds = np.linspace(0.0, 2000.0, 201)
    curve = [joint(w) for w in speeds]
    assert int(np.argmax(curve)) == 20  # the peak at 200 rad/s motor side


@pytest.mark.parametrize(
    ("torque", "speed", "ratio"),
    [
        ([-1.0], [1.0], [1.0]),
        ([1.0], [0.0], [1.0]),
        ([1.0], [1.0], [0.0]),
        ([1.0, 2.0], [1.0], [1.0]),
    ],
)
def test_short_circuit_refuses_meaningless_figures(torque, speed, ratio):
    with pytest.raises(BrakeError):
        ShortCircuit(np.array(torque), np.array(speed), np.array(ratio))


@pytest.mark.parametrize("w_v", [0.0, -1.0, math.inf, math.nan])
def test_viscous_law_refuses_meaningless_figures(w_v):
    with pytest.raises(BrakeError, match="viscous velocity"):
        Viscous(1.0, viscous_velocity=w_v)


#: The UR5 (CB3) at UR's zero (arm horizontal), its base turning alone at 3 rad/s.
W0 = 3.0  # [rad/s]
#: Integration: DOP853 at rtol 1e-11 on the smooth phase; the event locates rest to 1e-14 s.
TIGHT = DOP853(rtol=1e-11, atol=1e-13)


def _base_stop(base_brake: Brake | None, arm=None) -> tuple:
    arm = arm or robot("ur5_cb3")
    others = tuple(Brake(j) for j in arm.joints[1:])  # ideal, lock at once (at rest: no jump)
    brakes = others if base_brake is None else (base_brake, *others)
    q0 = np.zeros(arm.nv)
    v0 = np.zeros(arm.nv)
    v0[0] = W0
    problem = Problem(arm, q0, v0, 1.5, brakes=brakes, stop=Stop())
    J = compute_M(arm.model, arm.model.createData(), q0)[0, 0]
    return simulate(problem, TIGHT), J, float(arm.gear_ratio[0])


def test_viscous_brake_stops_as_the_closed_form():
    """Stop time and angle within 1e-8 relative (the integration is good to ~1e-11; the
    stopping angle is read at the located rest event)."""
    tau_c, w_v = 0.8, 150.0  # [N m], [rad/s] motor side
    result, J, N = _base_stop(
        Brake("shoulder_pan_joint", friction=Viscous(tau_c, 1.0, viscous_velocity=w_v))
    )
    a, b = N * tau_c / J, N**2 * tau_c / (J * w_v)
    t_stop = math.log(1.0 + b * W0 / a) / b
    angle = (W0 - a * t_stop) / b
    stick = [
        e for e in result.brake_events if e.joint == "shoulder_pan_joint" and e.kind == "stick"
    ]
    assert stick and stick[0].t == pytest.approx(t_stop, rel=1e-8)
    assert result.q[-1, 0] == pytest.approx(angle, rel=1e-8)
    # Hardest at the start: the deceleration at W0 is 1 + N W0 / w_v times that at rest.
    assert (a + b * W0) / a == pytest.approx(1.0 + N * W0 / w_v)


def test_short_circuit_braking_decays_as_the_closed_form():
    """No brake on the base, its motor shorted from the signal: t(x) at every sample within
    1e-8 s (DOP853 at rtol 1e-11 over 1.5 s)."""
    peak, w_pk = 0.4, 150.0  # [N m], [rad/s] motor side
    drives = {
        j: Drive(101.0, 1e-4 if i < 3 else 3e-5) for i, j in enumerate(robot("ur5_cb3").joints)
    }
    drives["shoulder_pan_joint"] = Drive(101.0, 1e-4, peak, w_pk)
    arm = load_robot("ur5_cb3", drives=drives)
    result, J, N = _base_stop(None, arm)
    x = N * result.v[:, 0] / w_pk
    x0 = N * W0 / w_pk
    t = J * w_pk / (2 * N**2 * peak) * (np.log(x0 / x) + (x0**2 - x**2) / 2.0)
    assert np.max(np.abs(t - result.t)) <= 1e-8
    assert result.short_circuit_work[-1] == pytest.approx(
        0.5 * J * (W0**2 - result.v[-1, 0] ** 2), rel=1e-8
    )
    assert np.all(np.diff(result.short_circuit_work) >= 0.0)


def test_short_circuit_acts_from_the_signal_and_after_a_category_one_ramp():
    """Category 0: from the signal. Category 1: a joint's motor is shorted when its drive drops
    out (its brake engages); before that the ramp's computed torque holds it, no short-circuit
    work is done."""
    arm = robot("ur5_cb3")
    drives = {j: Drive(101.0, 1e-4, 0.3, 200.0) for j in arm.joints}
    arm = load_robot("ur5_cb3", drives=drives)
    assert short_circuit(arm) is not None
    v0 = np.zeros(arm.nv)
    v0[0] = 1.0
    brakes = tuple(Brake(j, delay=0.05, friction=Coulomb(1.0, 1.2)) for j in arm.joints)
    cat0 = simulate(Problem(arm, np.zeros(arm.nv), v0, 1.0, brakes=brakes, stop=Stop(0.1)), TIGHT)
    before = cat0.t <= 0.1
    assert np.all(cat0.short_circuit_work[before] == 0.0)
    assert cat0.short_circuit_work[-1] > 0.0
    # The brake signal at 0.15 s (time_limit) cuts the 0.2 s ramp short: the brakes engage at
    # 0.2 s on a moving base, whose drive then drops out and whose motor is shorted.
    stop = Stop(
        0.1, category=1, ramp_time=0.2, time_limit=0.05, torque_limit=np.full(arm.nv, 150.0)
    )
    cat1 = simulate(Problem(arm, np.zeros(arm.nv), v0, 1.0, brakes=brakes, stop=stop), TIGHT)
    ramping = cat1.t <= 0.2
    assert np.all(cat1.short_circuit_work[ramping] == 0.0)
    assert cat1.short_circuit_work[-1] > 0.0
