"""Friction laws: Coulomb and Stribeck behind one interface, and Stribeck end to end."""

import json
import math

import numpy as np
import pytest
import yaml
from conftest import SCENARIOS, robot

from vtm_pin import Problem, simulate
from vtm_pin.numerics.integrators import DOP853
from vtm_pin.physics.brakes import Brake
from vtm_pin.physics.friction import Coulomb, IdealLock, Stribeck
from vtm_pin.physics.stop import Stop


def test_laws_share_the_interface_and_the_ramp():
    for law in (Coulomb(3.0, 4.0, ramp=0.2), Stribeck(3.0, 4.0, ramp=0.2, stribeck_velocity=1)):
        assert law.breakaway(0.1) == pytest.approx(2.0)  # half the normal force at half ramp
        assert law.breakaway(1.0) == 4.0
        assert law.sliding(0.1, 100.0) == pytest.approx(1.5)  # [N m] at speed: Coulomb's
    assert IdealLock().breakaway(0.0) == math.inf
    assert Brake("j").ideal and not Brake("j", friction=Coulomb(1.0)).ideal


def test_stribeck_falls_from_static_to_coulomb():
    law = Stribeck(3.0, 5.0, stribeck_velocity=0.5)
    assert law.kinetic(0.0) == 5.0  # [N m]: the static torque at rest
    assert law.kinetic(0.5) == pytest.approx(3.0 + 2.0 / math.e)
    speeds = np.linspace(0.0, 3.0, 31)
    torques = [law.kinetic(w) for w in speeds]
    assert np.all(np.diff(torques) <= 0.0)  # monotone drop
    # At 10 Stribeck velocities the drop is exp(-100) of 2 N m: Coulomb to round-off.
    assert law.kinetic(5.0) == pytest.approx(3.0, abs=1e-15)


def test_stribeck_holds_its_static_torque_past_rest():
    """Past rest (w < 0, a trial stage of a step that overshoots the rest) the law holds tau_s.

    It meets the drop at w = 0 with the drop's value and slope (0), and never falls back to
    tau_c there: a step that overshoots a peak narrower than itself sees the peak past rest.
    """
    law = Stribeck(3.0, 5.0, stribeck_velocity=0.5)
    for w in (-1e-300, -1e-6, -0.5, -1e3, -math.inf):
        assert law.kinetic(w) == 5.0  # [N m]
    slope = (law.kinetic(1e-7) - law.kinetic(0.0)) / 1e-7
    assert abs(slope) < 1e-5  # [N m s/rad]: 2 (2 w / w_s^2) exp(-...) at 1e-7 rad/s is 1.6e-6


def slide_to_rest(friction, v1=2.0):
    """Joint 1 of the pendulum braked from 2 rad/s; joints 2 and 3 ideal-locked at engagement.

    DOP853 at rtol 1e-11: the integration error (~1e-9 rad) is far below the differences
    between laws compared here.
    """
    brakes = [Brake("joint1", friction=friction), Brake("joint2"), Brake("joint3")]
    q0, v0 = np.zeros(3), np.array([v1, 0.0, 0.0])
    problem = Problem(robot("planar_3r"), q0, v0, 1.0, brakes=tuple(brakes), stop=Stop())
    return simulate(problem, DOP853(1e-11, 1e-13))


def test_stribeck_converges_to_coulomb_as_its_velocity_goes_to_zero():
    """Same sliding and static torques; w_s -> 0 leaves only the kinetic (Coulomb) torque."""
    coulomb = slide_to_rest(Coulomb(900.0, 1500.0))
    errors = []
    for w_s in (0.1, 0.01, 0.001, 0.0001):  # [rad/s]
        stribeck = slide_to_rest(Stribeck(900.0, 1500.0, stribeck_velocity=w_s))
        errors.append(np.max(np.abs(stribeck.q[-1] - coulomb.q[-1])))
    # The extra friction acts only while |v| < ~w_s, so the error falls like w_s: measured
    # 6.5e-3, 7.1e-4, 9.4e-5, 9.4e-6 rad (x10 per decade; 5x asserted).
    errors = np.array(errors)
    assert np.all(errors[1:] < errors[:-1] / 5.0), errors
    assert errors[-1] < 1e-4  # [rad], of the ~0.6 rad the joint travels


def first_rest(result):
    """Time [s] and joint-1 angle [rad] when joint 1 first reaches v = 0."""
    t = next(e.t for e in result.brake_events if e.joint == "joint1" and e.kind != "engage")
    return t, float(result.q_at([t])[0, 0])


def test_stribeck_brake_stops_sooner_and_only_dissipates():
    """A Stribeck brake brakes at least as hard as Coulomb with the same torques."""
    coulomb = slide_to_rest(Coulomb(900.0, 1500.0))
    stribeck = slide_to_rest(Stribeck(900.0, 1500.0, stribeck_velocity=1.0))
    (t_c, q_c), (t_s, q_s) = first_rest(coulomb), first_rest(stribeck)
    assert t_s < t_c and q_s < q_c  # measured 0.607 vs 0.635 s
    # Non-decreasing friction work, to DOP853 round-off of the ~1e3 J dissipated [J].
    assert np.min(np.diff(stribeck.brake_work)) >= -1e-9 * stribeck.brake_work[-1]


def test_stribeck_from_the_scenario_key_to_summary(tmp_path):
    from vtm_pin.cli import main

    raw = yaml.safe_load((SCENARIOS / "rx160l_estop_cat0.yaml").read_text())
    raw["brakes"]["joint_2"].update(friction="stribeck", stribeck_velocity=5.0)
    path = tmp_path / "stribeck.yaml"
    path.write_text(yaml.safe_dump(raw))
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out), "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    joint_2 = next(b for b in summary["brakes"] if b["joint"] == "joint_2")
    assert joint_2["friction"]["law"] == "stribeck"
    assert joint_2["friction"]["stribeck_velocity"] == 5.0
    assert summary["energy"]["brake_work"] > 0.0
    assert summary["stopping"]["all_stopped"] is True


@pytest.mark.parametrize(
    "brake, message",
    [
        ({"sliding_torque": 1.0, "stribeck_velocity": 1.0}, "goes with friction: stribeck"),
        ({"sliding_torque": 1.0, "friction": "stribeck"}, "goes with friction: stribeck"),
        ({"ideal": True, "friction": "coulomb"}, "drop friction"),
        (
            {"sliding_torque": 1.0, "friction": "stribeck", "stribeck_velocity": 0.0},
            "must be > 0",
        ),
    ],
)
def test_bad_friction_keys_are_refused(tmp_path, capsys, brake, message):
    from vtm_pin.cli import main

    raw = yaml.safe_load((SCENARIOS / "rx160l_estop_cat0.yaml").read_text())
    raw["brakes"]["joint_2"] = brake
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(raw))
    assert main(["run", str(path), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err.strip()
    assert "brakes.joint_2" in err and message in err and "\n" not in err
    assert not (tmp_path / "out").exists()


def test_stribeck_brake_never_holds_beyond_its_static_torque():
    """The re-slip pendulum with a Stribeck brake: at v = 0 its kinetic torque equals the
    breakaway torque, so a released joint's acceleration is zero to round-off. It once stuck
    at once and was then held up to 3973 N m against a 400 N m static torque. Tolerance: the
    stick/slip test's own round-off (ROUNDOFF of the holding torque) plus 1e-8 N m."""
    from conftest import Q0_RESLIP, V0_RESLIP

    from vtm_pin import RK4
    from vtm_pin.physics.brakes import ROUNDOFF, BrakeMode

    brake = Brake("joint1", friction=Stribeck(300.0, 400.0, stribeck_velocity=0.5))
    problem = Problem(robot("planar_3r"), Q0_RESLIP, V0_RESLIP, 3.0, brakes=(brake,), stop=Stop())
    result = simulate(problem, RK4(1e-4))
    kinds = [str(e.kind) for e in result.brake_events]
    assert "stick" in kinds and "slip" in kinds  # it sticks, and slips again at its limit
    stuck = (result.modes[:, 0] == BrakeMode.STUCK) & np.isfinite(result.holding[:, 0])
    assert np.all(np.abs(result.holding[stuck, 0]) <= 400.0 * (1.0 + ROUNDOFF) + 1e-8)
