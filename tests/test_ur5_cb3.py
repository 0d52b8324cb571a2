"""The UR5 (CB3) model robots/ur5_cb3.urdf, built from Universal Robots' published figures.

The kinematics are checked against a DH implementation written here (not the URDF's numbers):
UR's standard DH table, T_i = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i), with the URDF joint
angle equal to theta_i. Masses and centres of mass are the published ones; the centres of
mass are given in UR's DH link frames and compared in the world.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest
from conftest import UR_JOINTS

from vtm_pin.outputs.pipeline import run
from vtm_pin.physics.robot import load_robot
from vtm_pin.scene import annex_b
from vtm_pin.scene.annex_b import Conditions, compute_test_state, horizontal_reach, max_reach
from vtm_pin.scene.scenario import build_scenario

JOINTS = UR_JOINTS
#: UR5 (CB3) DH parameters [m, rad] (UR's table; the CB3 manual's "serie 3").
D = (0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823)
A = (0.0, -0.425, -0.39225, 0.0, 0.0, 0.0)
ALPHA = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)
#: Published link masses [kg], shoulder to wrist 3, and centres of mass [m] in DH frames 1-6.
MASSES = (3.7, 8.393, 2.275, 1.219, 1.219, 0.1879)
COMS_DH = (
    (0.0, -0.02561, 0.00193),
    (0.2125, 0.0, 0.11336),
    (0.15, 0.0, 0.0265),
    (0.0, -0.0018, 0.01634),
    (0.0, 0.0018, 0.01634),
    (0.0, 0.0, -0.001159),
)
#: Assumed drives (robots/ur5_cb3.yaml): gear ratio and rotor inertia [kg m^2] per joint.
GEAR_RATIO = 101.0
ROTOR_INERTIA = (1.0e-4, 1.0e-4, 1.0e-4, 3.0e-5, 3.0e-5, 3.0e-5)
#: UR's published reach of the UR5 [m] (to the tool flange).
PUBLISHED_REACH = 0.85
#: UR's Annex-B test speed for the UR5 (CB3) stopping table: 183 deg/s.
TEST_SPEED = math.radians(183.0)

#: [m, -] Pose and centre-of-mass agreement with the DH chain: both are products of six
#: transforms of entries <= 1 m, exact up to round-off (~1e-15); 1e-12 leaves a wide margin
#: but catches any wrong digit of the geometry (>= 1e-6 m).
KIN_TOL = 1.0e-12
#: [kg] Masses are copied decimals: only the parse's round-off (~1e-16 kg) is allowed.
MASS_TOL = 1.0e-12
#: [kg m^2] Armature = 101^2 x rotor inertia, a product of two doubles: round-off only.
ARMATURE_TOL = 1.0e-12
#: [m] annex_b polishes its poses to the shoulder plane and R to ~1e-12 m, and meets r = e R
#: to 1e-9 m; 1e-9 m is its own acceptance bound.
REACH_TOL = 1.0e-9
#: [-] Sanity window of R / published reach: UR measure 850 mm to the flange with the wrist
#: folded; annex_b's R (tool0 at shoulder height, as far as the limits allow) lets the wrist
#: links (d5 + d6 = 0.177 m) point outwards too, adding up to ~12 %. A window, not a match.
REACH_WINDOW = 0.15
#: Seed and count of the random configurations of the kinematics check.
SEED, N_RANDOM = 5, 20


@pytest.fixture(scope="module")
def ur5():
    return load_robot("ur5_cb3")


def dh(theta: float, d: float, a: float, alpha: float) -> np.ndarray:
    """Standard DH transform Rz(theta) Tz(d) Tx(a) Rx(alpha), 4 x 4."""
    ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
    return np.array(
        [
            [ct, -st * ca, st * sa, a * ct],
            [st, ct * ca, -ct * sa, a * st],
            [0.0, sa, ca, d],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def dh_frames(q: np.ndarray) -> list[np.ndarray]:
    """World poses of DH frames 1..6 at q (frame 0 = the world = base_link)."""
    frames, T = [], np.eye(4)
    for theta, d, a, alpha in zip(q, D, A, ALPHA, strict=True):
        T = T @ dh(theta, d, a, alpha)
        frames.append(T)
    return frames


def test_loads_with_the_published_joint_names_and_assumed_drives(ur5):
    assert ur5.joints == JOINTS
    assert ur5.tool_frame == "tool0"
    assert ur5.model.nq == ur5.model.nv == 6
    np.testing.assert_array_equal(ur5.gear_ratio, [GEAR_RATIO] * 6)
    np.testing.assert_allclose(
        ur5.model.armature, GEAR_RATIO**2 * np.array(ROTOR_INERTIA), rtol=0, atol=ARMATURE_TOL
    )
    assert ur5.model.armature[0] == pytest.approx(1.0201, abs=ARMATURE_TOL)
    assert ur5.model.armature[5] == pytest.approx(0.30603, abs=ARMATURE_TOL)
    np.testing.assert_array_equal(ur5.model.velocityLimit, [3.15] * 6)
    np.testing.assert_array_equal(ur5.model.effortLimit, [150, 150, 150, 28, 28, 28])
    two_pi = np.array([2 * math.pi, 2 * math.pi, math.pi, 2 * math.pi, 2 * math.pi, 2 * math.pi])
    np.testing.assert_array_equal(ur5.model.upperPositionLimit, two_pi)
    np.testing.assert_array_equal(ur5.model.lowerPositionLimit, -two_pi)
    text = " ".join(ur5.assumptions)
    assert "PUBLISHED" in text and "ASSUMED" in text and "rotational inertias" in text


def test_link_masses_and_total_mass_are_the_published_ones(ur5):
    model = ur5.model
    for name, mass in zip(JOINTS, MASSES, strict=True):
        assert model.inertias[model.getJointId(name)].mass == pytest.approx(mass, abs=MASS_TOL)
    # The base is fixed to the ground and massless in the model: 16.9939 kg moves.
    assert pin.computeTotalMass(model) == pytest.approx(sum(MASSES), abs=MASS_TOL)
    assert sum(MASSES) == pytest.approx(16.9939, abs=MASS_TOL)


@pytest.mark.parametrize("q", [np.zeros(6), np.array([0.3, -1.1, 1.7, -0.4, 0.9, 2.2])])
def test_centres_of_mass_sit_where_ur_publishes_them(ur5, q):
    model, data = ur5.model, ur5.model.createData()
    pin.forwardKinematics(model, data, q)
    for name, frame, com in zip(JOINTS, dh_frames(q), COMS_DH, strict=True):
        jid = model.getJointId(name)
        world = data.oMi[jid].act(model.inertias[jid].lever)
        expected = frame[:3, :3] @ np.array(com) + frame[:3, 3]
        np.testing.assert_allclose(world, expected, rtol=0, atol=KIN_TOL, err_msg=name)


def test_upper_arm_centre_of_mass_at_zero_by_hand(ur5):
    """At q = 0 DH frame 2 sits at the elbow (-0.425, 0, d1) with x2 = x0, y2 = z0, z2 = -y0:
    the com [0.2125, 0, 0.11336] is halfway along the upper arm, 0.11336 m towards -y."""
    model, data = ur5.model, ur5.model.createData()
    pin.forwardKinematics(model, data, np.zeros(6))
    jid = model.getJointId("shoulder_lift_joint")
    world = data.oMi[jid].act(model.inertias[jid].lever)
    np.testing.assert_allclose(world, [-0.2125, -0.11336, 0.089159], rtol=0, atol=KIN_TOL)


def test_zero_pose_is_urs_stretched_arm(ur5):
    """q = 0: the arm horizontal along -x, wrist 2 down, the flange facing -y (by hand)."""
    model, data = ur5.model, ur5.model.createData()
    pin.framesForwardKinematics(model, data, np.zeros(6))
    tool = data.oMf[model.getFrameId("tool0")]
    expected = [-0.425 - 0.39225, -0.10915 - 0.0823, 0.089159 - 0.09465]
    np.testing.assert_allclose(tool.translation, expected, rtol=0, atol=KIN_TOL)
    np.testing.assert_allclose(tool.rotation[:, 2], [0.0, -1.0, 0.0], rtol=0, atol=KIN_TOL)
    elbow = data.oMi[model.getJointId("elbow_joint")].translation
    np.testing.assert_allclose(elbow, [-0.425, 0.0, 0.089159], rtol=0, atol=KIN_TOL)


def test_tool0_pose_equals_the_dh_forward_kinematics(ur5):
    model, data = ur5.model, ur5.model.createData()
    frame = model.getFrameId("tool0")
    rng = np.random.default_rng(SEED)
    for _ in range(N_RANDOM):
        q = rng.uniform(model.lowerPositionLimit, model.upperPositionLimit)
        pin.framesForwardKinematics(model, data, q)
        np.testing.assert_allclose(
            data.oMf[frame].homogeneous, dh_frames(q)[-1], rtol=0, atol=KIN_TOL, err_msg=str(q)
        )


def test_max_reach_is_plausible_against_the_published_850_mm(ur5):
    R = max_reach(ur5, "tool0", np.zeros(6))
    assert abs(R / PUBLISHED_REACH - 1.0) < REACH_WINDOW, R
    # Independent lower bound, by hand: arm horizontal (q2 = q3 = 0), q4 = -pi/2 turns wrist 2
    # outwards (-x), and the wrist-3 offset d6 points along -y (whichever q5 of 0, +-pi/2, pi
    # keeps tool0 at shoulder height and goes furthest): r = hypot(a2 + a3 - d5, d4 + d6).
    by_hand = math.hypot(0.425 + 0.39225 + 0.09465, 0.10915 + 0.0823)
    best = 0.0
    for q5 in (0.0, math.pi / 2, math.pi, -math.pi / 2):
        q = np.array([0.0, 0.0, 0.0, -math.pi / 2, q5, 0.0])
        tool = dh_frames(q)[-1][:3, 3]
        if abs(tool[2] - D[0]) < KIN_TOL:
            r = math.hypot(tool[0], tool[1])
            assert horizontal_reach(ur5, "tool0", q) == pytest.approx(r, abs=KIN_TOL)
            best = max(best, r)
    assert best == pytest.approx(by_hand, abs=KIN_TOL)
    assert R >= by_hand - REACH_TOL
    print(f"UR5 (CB3) max reach R = {R:.6f} m (published 0.850 m; by hand >= {by_hand:.6f} m)")


def test_annex_b_state_and_category_0_stop_of_the_shoulder(ur5):
    conditions = Conditions(
        joint="shoulder_lift_joint", speed=1.0, max_speed=TEST_SPEED, extension=1.0
    )
    state = compute_test_state(ur5, "tool0", conditions, np.zeros(6))
    assert state.vertical and state.joint_index == 1
    # Moving down is the positive direction of shoulder_lift_joint (about -y0 at q1 = 0).
    assert state.speed == pytest.approx(TEST_SPEED, abs=1e-15)
    np.testing.assert_array_equal(np.flatnonzero(state.v), [1])
    assert state.reach == pytest.approx(state.max_reach, abs=REACH_TOL)
    tool = dh_frames(state.q)[-1][:3, 3]
    assert tool[2] == pytest.approx(D[0], abs=REACH_TOL)  # at shoulder height
    assert annex_b.horizontal_reach(ur5, "tool0", state.q) == pytest.approx(
        math.hypot(tool[0], tool[1]), abs=KIN_TOL
    )

    raw = {
        "robot": "ur5_cb3",
        "annex_b": {
            "joint": "shoulder_lift_joint",
            "speed": 1.0,
            "max_speed": TEST_SPEED,
            "extension": 1.0,
        },
        "payload": {"mass": 5.0},
        "duration": 1.0,
        "integrator": {"method": "dop853", "rtol": 1.0e-8, "atol": 1.0e-10},
        "stop": {"t": 0.0, "category": 0},
        "brakes": {
            j: {"delay": 0.05, "sliding_torque": 1.0, "static_torque": 1.25} for j in JOINTS
        },
    }
    scenario = build_scenario(raw, source="ur5_cb3 annex-b test")
    output = run(scenario)
    report = output.stopping[output.rule]
    lift = report.joints[1]
    assert lift.joint == "shoulder_lift_joint"
    assert lift.stopped and 0.05 < lift.stop_time < 1.0
    assert lift.stop_angle > 0.0  # it kept moving down until the brake held it
    print(
        f"UR5 (CB3) shoulder, cat. 0, 5 kg, brakes 101 / 126 N m joint side: "
        f"{lift.stop_angle:.3f} rad in {lift.stop_time * 1e3:.0f} ms "
        f"(published 0.70 rad, 530 ms)"
    )
