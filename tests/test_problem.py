"""The validated simulation problem: checked once, variants reuse the robot."""

import numpy as np
import pytest
from conftest import robot

from vtm_pin import RK4, LockEvent, Problem, ProblemError, simulate
from vtm_pin.physics.brakes import Brake
from vtm_pin.physics.friction import Coulomb
from vtm_pin.physics.stop import Stop

Q0 = np.array([0.0, 1.2, 0.0])  # [rad]


def problem(**changes):
    base = {"robot": robot("planar_3r"), "q0": Q0, "v0": np.zeros(3), "duration": 1.0}
    return Problem(**{**base, **changes})


@pytest.mark.parametrize(
    "changes, key, message",
    [
        ({"q0": np.zeros(2)}, "initial.q", "has 2 values but the robot has 3 joints"),
        ({"v0": np.array([0.0, np.nan, 0.0])}, "initial.v", "values must be finite numbers"),
        ({"duration": 0.0}, "duration", "0.0 is not a finite number of s > 0"),
        ({"events": (LockEvent(2.0, ("joint1",)),)}, "events[0].t", "2.0 s is outside [0,"),
        ({"events": (LockEvent(0.5, ()),)}, "events[0]", "needs 'lock' or 'activate'"),
        ({"events": (LockEvent(0.5, ("elbow",)),)}, "events[0].lock", "unknown joint 'elbow'"),
        (
            {"events": (LockEvent(0.6, ("joint1",)), LockEvent(0.2, ("joint1",)))},
            "events[0].lock",  # the later lock is the one refused, in the file's numbering
            "joint 'joint1' locks again at t = 0.6 s",
        ),
        ({"brakes": (Brake("joint1"),)}, "brakes", "brakes act after a stop signal"),
        ({"brakes": (Brake("nope"),), "stop": Stop()}, "brakes.nope", "unknown joint 'nope'"),
        (
            {"brakes": (Brake("joint1"), Brake("joint1")), "stop": Stop()},
            "brakes.joint1",
            "a joint has one brake",
        ),
        ({"stop": Stop(2.0)}, "stop.t", "2.0 s is after the end (duration = 1.0 s)"),
        (
            {"stop": Stop(0.0, category=1, ramp_time=0.2, torque_limit=np.ones(2))},
            "stop.torque_limit",
            "needs one value per joint (3: joint1, joint2, joint3)",
        ),
    ],
)
def test_problems_are_refused_naming_the_key(changes, key, message):
    with pytest.raises(ProblemError) as info:
        problem(**changes)
    assert info.value.key == key
    assert message in info.value.problem and "\n" not in str(info.value)


def test_variants_reuse_the_robot_and_are_validated_again():
    base = problem(brakes=(Brake("joint1", friction=Coulomb(500.0, 700.0)),), stop=Stop())
    faster = base.replace(v0=np.array([1.0, 0.0, 0.0]))
    assert faster.robot is base.robot and faster.brakes == base.brakes
    assert faster.v0[0] == 1.0 and base.v0[0] == 0.0
    with pytest.raises(ProblemError, match=r"'stop\.t'"):
        base.replace(stop=Stop(5.0))
    # The problem's state is read-only: a run cannot change the problem it was given.
    with pytest.raises(ValueError, match="read-only"):
        base.q0[0] = 1.0
    result = simulate(faster, RK4(1e-3))
    assert result.t[-1] == 1.0 and np.all(faster.v0 == [1.0, 0.0, 0.0])


def test_the_naive_rule_is_refused_with_frame_constraints():
    from vtm_pin.core.holonomic import FrameConstraint

    loop = FrameConstraint("loop", "tip_l", "tip_r", "point", axes=("x", "z"))
    q = np.array([-0.4, 0.57978007700581935, 0.2, 0.16334925102132061])  # [rad], closed
    five = Problem(robot("planar_fivebar"), q, np.zeros(4), 0.1, constraints=(loop,))
    with pytest.raises(ProblemError, match="'transition': naive is defined for joint locks"):
        simulate(five, RK4(1e-3), transition="naive")
