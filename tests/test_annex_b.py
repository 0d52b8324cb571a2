"""ISO 10218-1 Annex-B test conditions (vtm_pin.scene.annex_b) on UR5, UR10, Panda and RX160L.

The checks that R is right do not reuse the module's code: they pose the arms with Pinocchio's
forward kinematics and a 1-D root search of their own.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin
import pytest
from conftest import robot
from scipy.optimize import brentq

from vtm_pin.exceptions import ConditionsError
from vtm_pin.scene import annex_b
from vtm_pin.scene.annex_b import (
    DIRECTIONS,
    Conditions,
    compute_test_state,
    describe_conditions,
    extension_pose,
    horizontal_reach,
    max_reach,
)

#: Guess poses [rad]: UR arms in a usual working pose, the Panda's ready pose (fingers half
#: open [m]), the RX160L at zero (straight up).
GUESSES = {
    "ur5": [0.0, -1.2, 1.4, -1.2, -1.57, 0.0],
    "ur10": [0.0, -1.2, 1.4, -1.2, -1.57, 0.0],
    "panda": [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785, 0.02, 0.02],
    "rx160l": [0.0] * 6,
}
ROBOTS = list(GUESSES)
EXTENSIONS = (0.33, 0.66, 1.0)
#: Published reach [m] to the tool flange (Universal Robots datasheets).
PUBLISHED_REACH = {"ur5": 0.85, "ur10": 1.30}
#: Shoulder and elbow (pitch joints) of each arm; the Panda's third joint is an arm roll.
SHOULDER_ELBOW = {"ur5": (1, 2), "ur10": (1, 2), "panda": (1, 3), "rx160l": (1, 2)}

#: [-] r/R must equal e to this: the pose solve meets r = e R to 1e-9 m (at e = 1 the pose is
#: a maximizer found to ~1e-9 m), i.e. ~1e-9 of a ~1 m reach; 1e-6 leaves a wide margin.
EXTENSION_TOL = 1.0e-6
#: [m] Height of the tool above the shoulder plane: the module polishes it to round-off and
#: refuses poses off it by more than 1e-9 m.
PLANE_TOL = 1.0e-9
#: [m] A sampled pose may exceed R by this: the samples sit in the plane to brentq's 1e-14 rad
#: and R is SLSQP's optimum to ~1e-12 m; 1e-8 m is far below any real gain in reach.
SAMPLE_TOL = 1.0e-8
#: [-] Random poses in the plane come within this fraction of R (150 samples reach 0.96 to
#: 0.999 R: sampling a 5-6 D space finds the stretched arm only roughly): the check that R
#: is not an overestimate.
SAMPLE_COVERAGE = 0.9
#: Bounds of R / published reach for the UR arms: a sanity bound, not a match. UR measure the
#: reach to the flange with the wrist in its usual orientation; posed at shoulder height the
#: wrist links (UR5 ~0.13 m, UR10 ~0.15 m) may point outwards too and add up to ~12 %.
PUBLISHED_LOW, PUBLISHED_HIGH = 0.97, 1.15


def guess(name: str) -> np.ndarray:
    return np.array(GUESSES[name])


def tool_state(name: str, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Tool-frame origin [m], its world-aligned linear Jacobian and the shoulder height [m]."""
    r = robot(name)
    model, data = r.model, r.model.createData()
    fid = model.getFrameId(r.tool_frame)
    J = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL_WORLD_ALIGNED)[:3]
    # The second joint is revolute in all four arms: its origin does not move with it.
    return data.oMf[fid].translation.copy(), J, float(data.oMi[2].translation[2])


@pytest.mark.parametrize("name", ROBOTS)
def test_joint_1_is_a_vertical_axis_through_the_origin(name):
    # The independent checks below measure r as the horizontal distance from the world z axis.
    r = robot(name)
    data = r.model.createData()
    pin.forwardKinematics(r.model, data, pin.neutral(r.model))
    assert r.model.joints[1].shortname() == "JointModelRZ"
    np.testing.assert_allclose(data.oMi[1].rotation[:, 2], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(data.oMi[1].translation[:2], [0, 0], atol=1e-12)


@pytest.mark.parametrize("name", ROBOTS)
@pytest.mark.parametrize("e", EXTENSIONS)
def test_extension_pose_has_the_requested_reach_in_the_shoulder_plane(name, e):
    r = robot(name)
    q = extension_pose(r, r.tool_frame, e, guess(name))
    R = max_reach(r, r.tool_frame, guess(name))
    p, _, shoulder = tool_state(name, q)
    assert np.hypot(p[0], p[1]) / R == pytest.approx(e, abs=EXTENSION_TOL)
    assert horizontal_reach(r, r.tool_frame, q) / R == pytest.approx(e, abs=EXTENSION_TOL)
    assert abs(p[2] - shoulder) <= PLANE_TOL
    assert np.all(q >= r.model.lowerPositionLimit)
    assert np.all(q <= r.model.upperPositionLimit)
    # Joint 1 and the joints that cannot move the tool (the Panda's fingers) keep the guess.
    assert q[0] == guess(name)[0]
    if name == "panda":
        np.testing.assert_array_equal(q[7:], guess(name)[7:])


def test_the_pose_is_the_nearest_one_locally():
    # First-order optimality of min |q - g|^2 on {r = e R, plane}: q - g is a combination of the
    # two constraint gradients (no bound is active at this pose).
    r, e, g = robot("ur5"), 0.66, guess("ur5")
    q = extension_pose(r, r.tool_frame, e, g)
    p, J, _ = tool_state("ur5", q)
    radial = np.array([p[0], p[1], 0.0]) / np.hypot(p[0], p[1])
    free = slice(1, 6)
    A = np.vstack([radial @ J[:, free], J[2, free]]).T  # gradients of r and of the height
    d = (q - g)[free]
    residual = d - A @ np.linalg.lstsq(A, d, rcond=None)[0]
    # [rad] The pose is Newton's KKT point (stationarity to KKT_TOL = 1e-11 rad); 1e-9 leaves
    # room for the round-off of this independent Jacobian and projection. (SLSQP, its fallback,
    # minimizes |q - g|^2 / 2 to ftol 1e-10 only: its gradient is met to ~1e-5.)
    assert np.linalg.norm(residual) < 1e-9 * max(1.0, np.linalg.norm(d))


def sampled_reaches(name: str, n: int, seed: int) -> np.ndarray:
    """Horizontal reaches [m] of random poses put in the shoulder plane by moving joint 2.

    Independent of the module: each random pose (within the limits) is scanned over joint 2's
    range and every crossing of the shoulder plane is solved with brentq.
    """
    r = robot(name)
    model, data = r.model, r.model.createData()
    fid = model.getFrameId(r.tool_frame)
    lo, hi = model.lowerPositionLimit, model.upperPositionLimit
    rng = np.random.default_rng(seed)
    q = np.clip(guess(name), lo, hi)

    def height(a: float, qi: np.ndarray) -> float:
        qi[1] = a
        pin.framesForwardKinematics(model, data, qi)
        return float(data.oMf[fid].translation[2] - data.oMi[2].translation[2])

    reaches = []
    grid = np.linspace(lo[1], hi[1], 73)
    for _ in range(n):
        qi = q.copy()
        qi[1:6] = rng.uniform(lo[1:6], hi[1:6])
        h = np.array([height(a, qi) for a in grid])
        for k in np.flatnonzero(np.sign(h[:-1]) * np.sign(h[1:]) < 0):
            a = brentq(height, grid[k], grid[k + 1], args=(qi,), xtol=1e-14)
            height(a, qi)
            p = data.oMf[fid].translation
            reaches.append(np.hypot(p[0], p[1]))
    return np.array(reaches)


@pytest.mark.parametrize("name", ROBOTS)
def test_max_reach_bounds_random_poses_in_the_plane(name):
    r = robot(name)
    R = max_reach(r, r.tool_frame, guess(name))
    reaches = sampled_reaches(name, 150, seed=1)
    assert len(reaches) > 50
    assert reaches.max() <= R + SAMPLE_TOL
    assert reaches.max() >= SAMPLE_COVERAGE * R


@pytest.mark.parametrize("name", ROBOTS)
def test_max_reach_is_below_the_sum_of_the_link_lengths(name):
    # Triangle inequality: the tool is at most the sum of the joint-to-joint distances beyond
    # joint 2 (and the tool frame's offset) from joint 2's origin, which is r2 from the axis
    # (all joints revolute: a joint's origin does not move with it).
    r = robot(name)
    model, data = r.model, r.model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    frame = model.frames[model.getFrameId(r.tool_frame)]
    chain = [j for j in model.supports[frame.parentJoint] if j > 2]
    links = sum(np.linalg.norm(model.jointPlacements[j].translation) for j in chain)
    offset = np.linalg.norm(frame.placement.translation)  # from the frame's parent joint
    r2 = np.hypot(*data.oMi[2].translation[:2])
    # [m] 1e-12: round-off of the sums.
    assert max_reach(r, r.tool_frame, guess(name)) <= r2 + links + offset + 1e-12


@pytest.mark.parametrize("name", list(PUBLISHED_REACH))
def test_max_reach_of_ur_arms_is_near_the_published_reach(name):
    r = robot(name)
    ratio = max_reach(r, r.tool_frame, guess(name)) / PUBLISHED_REACH[name]
    assert PUBLISHED_LOW <= ratio <= PUBLISHED_HIGH


def test_max_reach_of_the_rx160l_is_its_straight_arm():
    # Joint-2 offset 0.15 + arm 0.825 + forearm 0.925 + flange 0.11 m = 2.01 m, Staubli's
    # published reach. [m] 1e-9: R is SLSQP's optimum of r^2/2 to ftol 1e-12 (~1e-12 m).
    r = robot("rx160l")
    assert max_reach(r, r.tool_frame, guess("rx160l")) == pytest.approx(2.01, abs=1e-9)


@pytest.mark.parametrize("name", ROBOTS)
@pytest.mark.parametrize("direction", ["down", "up"])
def test_down_moves_the_tool_along_gravity_and_up_against_it(name, direction):
    r = robot(name)
    for joint in (r.joints[i] for i in SHOULDER_ELBOW[name]):
        for e in (0.33, 1.0):
            state = compute_test_state(
                r, r.tool_frame, Conditions(joint, extension=e, direction=direction), guess(name)
            )
            _, J, _ = tool_state(name, state.q)
            vz = (J @ state.v)[2]  # [m/s] gravity is -z in all four models
            assert state.vertical
            assert (vz < 0) if direction == "down" else (vz > 0)


@pytest.mark.parametrize("name", ROBOTS)
def test_a_vertical_axis_joint_1_is_not_vertical_and_turns_positive(name):
    r = robot(name)
    for direction in ("down", "up", "positive"):
        state = compute_test_state(
            r, r.tool_frame, Conditions(r.joints[0], direction=direction), guess(name)
        )
        assert not state.vertical
        assert state.speed > 0
    state = compute_test_state(
        r, r.tool_frame, Conditions(r.joints[0], direction="negative"), guess(name)
    )
    assert not state.vertical and state.speed < 0


@pytest.mark.parametrize("name", ROBOTS)
def test_speed_is_the_fraction_of_the_limit_and_only_the_tested_joint_moves(name):
    r = robot(name)
    i = 2
    for fraction in (0.1, 0.5, 1.0):
        state = compute_test_state(
            r, r.tool_frame, Conditions(r.joints[i], speed=fraction), guess(name)
        )
        # rel 1e-15: one rounded product.
        assert abs(state.speed) == pytest.approx(fraction * r.model.velocityLimit[i], rel=1e-15)
        assert state.v[i] == state.speed and state.joint_index == i
        assert np.count_nonzero(state.v) == 1
    state = compute_test_state(
        r, r.tool_frame, Conditions(r.joints[i], speed=0.5, max_speed=2.0), guess(name)
    )
    assert abs(state.speed) == 1.0
    assert np.count_nonzero(state.v) == 1


def test_positive_and_negative_set_the_sign_directly():
    r = robot("ur5")
    for direction, sign in (("positive", 1.0), ("negative", -1.0)):
        state = compute_test_state(
            r, r.tool_frame, Conditions("elbow_joint", direction=direction), guess("ur5")
        )
        assert state.speed == sign * r.model.velocityLimit[2] and state.vertical


def test_a_prismatic_joint_is_tested_in_m_per_s():
    # The Panda's finger moves no part of the chain to the TCP: not vertical, positive.
    r = robot("panda")
    state = compute_test_state(
        r, r.tool_frame, Conditions("panda_finger_joint1", speed=0.5), guess("panda")
    )
    assert state.unit == "m/s" and not state.vertical
    # URDF limit 0.2 m/s; rel 1e-15: one rounded product.
    assert state.speed == pytest.approx(0.5 * 0.2, rel=1e-15)
    lines = describe_conditions(Conditions("panda_finger_joint1", speed=0.5), state, "x")
    assert "m/s" in lines[1] and "rad/s" not in " ".join(lines)


def test_describe_conditions_states_the_convention_speed_extension_and_direction():
    r = robot("ur10")
    conditions = Conditions("shoulder_lift_joint", speed=0.5, extension=0.66)
    state = compute_test_state(r, r.tool_frame, conditions, guess("ur10"))
    lines = describe_conditions(conditions, state, r.tool_frame)
    text = "\n".join(lines)
    assert len(lines) == 4 and "Annex-B" in lines[0] and "at rest" in lines[0]
    assert "URDF velocity limit" in lines[1] and "2.16 rad/s" in lines[1] and "1.08" in lines[1]
    assert "e = 0.66" in lines[2] and f"{state.max_reach:.4g} m" in lines[2]
    assert "along gravity" in lines[3] and "tool0" in text
    override = Conditions("shoulder_lift_joint", speed=0.5, max_speed=1.5)
    state = compute_test_state(r, r.tool_frame, override, guess("ur10"))
    assert "annex_b.max_speed" in describe_conditions(override, state, r.tool_frame)[1]


def test_a_payload_reuses_the_cached_max_reach():
    r, g = robot("ur5"), guess("ur5")
    R = max_reach(r, r.tool_frame, g)
    before = set(annex_b._REACH_CACHE)
    heavy = pin.Model(r.model)
    heavy.inertias[6] = pin.Inertia.FromSphere(5.0, 0.05)  # [kg], [m]: a payload on the wrist
    assert max_reach(dataclasses.replace(r, model=heavy), r.tool_frame, g) == R
    assert set(annex_b._REACH_CACHE) == before
    # A change of kinematics (a tighter elbow limit) is a new entry, and a smaller reach.
    bent = pin.Model(r.model)
    lower, upper = bent.lowerPositionLimit.copy(), bent.upperPositionLimit.copy()
    lower[2], upper[2] = 0.5, 3.0  # [rad]: the elbow cannot straighten
    bent.lowerPositionLimit, bent.upperPositionLimit = lower, upper
    assert max_reach(dataclasses.replace(r, model=bent), r.tool_frame, g) < R
    assert len(set(annex_b._REACH_CACHE) - before) == 1


@pytest.mark.parametrize(
    ("kwargs", "key"),
    [
        ({"speed": 0.0}, "speed"),
        ({"speed": 1.5}, "speed"),
        ({"speed": float("nan")}, "speed"),
        ({"speed": True}, "speed"),
        ({"extension": 0.0}, "extension"),
        ({"extension": -0.5}, "extension"),
        ({"max_speed": 0.0}, "max_speed"),
        ({"max_speed": float("inf")}, "max_speed"),
        ({"direction": "sideways"}, "direction"),
        ({"joint": ""}, "joint"),
    ],
)
def test_bad_conditions_name_their_key(kwargs, key):
    with pytest.raises(ConditionsError) as info:
        Conditions(**{"joint": "elbow_joint", **kwargs})
    assert info.value.key == key
    assert "\n" not in str(info.value)


def test_all_directions_are_accepted():
    for direction in DIRECTIONS:
        assert Conditions("j", direction=direction).direction == direction


def test_an_unknown_joint_lists_the_joints():
    r = robot("ur5")
    with pytest.raises(ConditionsError, match="shoulder_pan_joint, shoulder_lift_joint") as info:
        compute_test_state(r, r.tool_frame, Conditions("elbow"), guess("ur5"))
    assert info.value.key == "joint"


def test_a_joint_without_velocity_limit_needs_max_speed():
    r = robot("ur5")
    model = pin.Model(r.model)
    limits = model.velocityLimit.copy()
    limits[2] = 0.0
    model.velocityLimit = limits
    unlimited = dataclasses.replace(r, model=model)
    with pytest.raises(ConditionsError, match=r"set annex_b.max_speed \[rad/s\]") as info:
        compute_test_state(unlimited, r.tool_frame, Conditions("elbow_joint"), guess("ur5"))
    assert info.value.key == "max_speed" and "elbow_joint" in str(info.value)
    state = compute_test_state(
        unlimited, r.tool_frame, Conditions("elbow_joint", max_speed=2.0), guess("ur5")
    )
    assert abs(state.speed) == 2.0


def test_an_unreachable_extension_is_refused():
    # A frame that only joint 1 moves (here: none) cannot be posed.
    r = robot("ur5")
    with pytest.raises(ConditionsError) as info:
        extension_pose(r, "base_link", 0.5, guess("ur5"))
    assert info.value.key == "extension"
    with pytest.raises(ConditionsError) as info:
        extension_pose(r, "no_such_frame", 0.5, guess("ur5"))
    assert info.value.key == "extension"
    # The RX160L's elbow (+-150 deg) cannot fold the tool within 0.2 m of its axis at shoulder
    # height: e = 0.05 (0.10 m) cannot be posed.
    with pytest.raises(ConditionsError, match="cannot be posed") as info:
        extension_pose(robot("rx160l"), "tool0", 0.05, guess("rx160l"))
    assert info.value.key == "extension"


@pytest.mark.slow
@pytest.mark.parametrize("name", ROBOTS)
def test_sweep_of_extensions_and_guesses(name):
    r = robot(name)
    lo, hi = r.model.lowerPositionLimit, r.model.upperPositionLimit
    rng = np.random.default_rng(7)
    for _ in range(10):
        g = np.clip(guess(name) + rng.normal(0.0, 0.3, r.nv), lo, hi)
        R = max_reach(r, r.tool_frame, g)
        for e in np.linspace(0.2, 1.0, 9):  # the RX160L folds to e = 0.101 at the least
            q = extension_pose(r, r.tool_frame, e, g)
            p, _, shoulder = tool_state(name, q)
            assert np.hypot(p[0], p[1]) / R == pytest.approx(e, abs=EXTENSION_TOL)
            assert abs(p[2] - shoulder) <= PLANE_TOL


@pytest.mark.parametrize("name", ROBOTS)
def test_the_test_states_reach_and_column_are_the_evaluators_to_the_bit(name):
    """compute_test_state reads r(q) and the tested joint's column without a whole evaluator."""
    r = robot(name)
    chain = annex_b._robot_chain(r, r.tool_frame)
    lo, hi = r.model.lowerPositionLimit, r.model.upperPositionLimit
    rng = np.random.default_rng(5)
    for _ in range(20):
        q = rng.uniform(np.maximum(lo, -3.0), np.minimum(hi, 3.0))
        ev = annex_b._Evaluator(r.model, chain, q)
        for i in range(r.nv):
            reach, column = annex_b._reach_and_column(r.model, chain, q, r.model.createData(), i)
            assert reach == ev.reach()
            np.testing.assert_array_equal(column, ev.J[:, i])
