from typing import Any

import numpy as np
import pinocchio as pin
import pytest
from conftest import KERNEL_PATHS, SCENARIOS, robot

from vtm_pin import load_scenario, run_scenario
from vtm_pin.outputs.stopping import compute_stopping_report
from vtm_pin.physics import body_kernel, kinematics
from vtm_pin.physics.arm_points import fastest_point_speeds, point_speeds, sample_arm_points
from vtm_pin.physics.kinematics import (
    NUMPY_FROM,
    compute_tool_jacobian,
    compute_tool_motion,
    compute_tool_positions,
    joint_placements,
    tool_column_norms,
)
from vtm_pin.physics.robot import Robot

#: Against closed-form geometry: round-off of sums of a few sines and cosines [m, m/s, m/rad].
FK_TOL = 1e-12
#: Central differences with step FD_STEP [rad]: truncation ~ FD_STEP^2 |d^3 p| ~ 1e-12 and
#: round-off ~ 1e-16 / FD_STEP ~ 1e-10 for a robot of metre size [m/rad, m/s].
FD_STEP = 1e-6
FD_TOL = 1e-8

PENDULUM_Q = [np.zeros(3), np.array([0.3, -1.1, 2.0]), np.full(3, np.pi / 6)]


def pendulum_tip(q):
    """Closed-form tip of the 3R pendulum (unit links, axes along y, q = 0 hangs down) [m]."""
    phi = np.cumsum(q)
    return np.array([-np.sum(np.sin(phi)), 0.0, -np.sum(np.cos(phi))])


def pendulum_jacobian(q):
    """d tip / d q_j = sum over links i >= j of (-cos phi_i, 0, sin phi_i) [m/rad]."""
    phi = np.cumsum(q)
    columns = np.column_stack([-np.cos(phi), np.zeros(3), np.sin(phi)])
    return np.cumsum(columns[::-1], axis=0)[::-1].T


@pytest.mark.parametrize("q", PENDULUM_Q, ids=range(len(PENDULUM_Q)))
def test_pendulum_tip_position_speed_and_jacobian_match_closed_form(q):
    pendulum = robot("planar_3r")
    v = np.array([0.7, -0.2, 1.5])  # [rad/s]
    positions, speeds = compute_tool_motion(pendulum, q, v)
    J = pendulum_jacobian(q)
    np.testing.assert_allclose(positions, [pendulum_tip(q)], atol=FK_TOL)
    np.testing.assert_allclose(speeds, [np.linalg.norm(J @ v)], atol=FK_TOL)
    np.testing.assert_allclose(compute_tool_jacobian(pendulum, q), J, atol=FK_TOL)


def test_positions_over_samples_keep_their_order():
    q = np.array(PENDULUM_Q)
    positions = compute_tool_positions(robot("planar_3r"), q)
    assert positions.shape == (3, 3)
    np.testing.assert_allclose(positions, [pendulum_tip(qi) for qi in q], atol=FK_TOL)


def test_arm_positions_match_pinocchios_frame_placements():
    arm = robot("rx160l")
    rng = np.random.default_rng(1)
    q = rng.uniform(-2.0, 2.0, (4, arm.nv))
    data = arm.model.createData()
    fid = arm.model.getFrameId(arm.tool_frame)
    expected = []
    for qi in q:
        pin.framesForwardKinematics(arm.model, data, qi)
        expected.append(data.oMf[fid].translation.copy())
    np.testing.assert_allclose(compute_tool_positions(arm, q), expected, atol=FK_TOL)


def test_arm_jacobian_and_speed_match_central_differences_of_the_positions():
    arm = robot("rx160l")
    rng = np.random.default_rng(2)
    q, v = rng.uniform(-2.0, 2.0, arm.nv), rng.uniform(-1.0, 1.0, arm.nv)
    steps = FD_STEP * np.eye(arm.nv)
    plus = compute_tool_positions(arm, q + steps)
    minus = compute_tool_positions(arm, q - steps)
    J = compute_tool_jacobian(arm, q)
    np.testing.assert_allclose(J, ((plus - minus) / (2.0 * FD_STEP)).T, atol=FD_TOL)
    along = compute_tool_positions(arm, [q + FD_STEP * v, q - FD_STEP * v])
    _, speed = compute_tool_motion(arm, q, v)
    velocity = (along[0] - along[1]) / (2.0 * FD_STEP)
    assert speed[0] == pytest.approx(np.linalg.norm(velocity), abs=FD_TOL)


def test_another_frame_can_be_followed():
    q = PENDULUM_Q[1]
    # joint 3's frame sits at the end of link 2: the tip less link 3
    elbow = pendulum_tip(q) - np.array([-np.sin(np.sum(q)), 0.0, -np.cos(np.sum(q))])
    positions = compute_tool_positions(robot("planar_3r"), q, "joint3")
    np.testing.assert_allclose(positions, [elbow], atol=FK_TOL)


def test_tool_jacobians_of_many_configurations_are_those_of_each():
    arm = robot("ur10")
    rng = np.random.default_rng(3)
    qs = rng.uniform(-np.pi, np.pi, (4, arm.nv))
    many = compute_tool_jacobian(arm, qs)
    assert many.shape == (4, 3, arm.nv)
    for q, J in zip(qs, many, strict=True):
        np.testing.assert_array_equal(J, compute_tool_jacobian(arm, q))


# --- Forward kinematics vectorised over samples (kinematics.joint_placements) ---------------

#: NumPy's placements against Pinocchio's: products of a few rotations, each step rounding at
#: ~1e-16; 1e-12 [-, m, m/s] leaves room for chains of a dozen joints.
VEC_TOL = 1e-12
#: Samples per check: above NUMPY_FROM, so that the NumPy path is the one tested.
SAMPLES = max(64, NUMPY_FROM + 1)
SHIPPED = ["ur10", "planar_3r", "rx160l", "panda"]


def pinocchio_placements(model, qs):
    """Pinocchio's data.oMi at each row of ``qs``: rotations (T, njoints, 3, 3), origins."""
    data = model.createData()
    R, p = [], []
    for q in qs:
        pin.forwardKinematics(model, data, q)
        R.append([np.array(m.rotation) for m in data.oMi])
        p.append([np.array(m.translation) for m in data.oMi])
    return np.array(R), np.array(p)


def pinocchio_frame_motion(model, fid, qs, vs):
    """Pinocchio's frame origin [m] and LOCAL_WORLD_ALIGNED linear velocity [m/s] per sample."""
    data = model.createData()
    positions, velocities = [], []
    for q, v in zip(qs, vs, strict=True):
        pin.forwardKinematics(model, data, q, v)
        positions.append(pin.updateFramePlacement(model, data, fid).translation.copy())
        velocities.append(pin.getFrameVelocity(model, data, fid, pin.LOCAL_WORLD_ALIGNED).linear)
    return np.array(positions), np.array(velocities)


def random_states(model, seed, count=SAMPLES):
    """Seeded configurations within +-pi [rad] (+-0.2 m for prismatic joints) and rates."""
    rng = np.random.default_rng(seed)
    lower = np.maximum(model.lowerPositionLimit, -np.pi)
    upper = np.minimum(model.upperPositionLimit, np.pi)
    qs = rng.uniform(lower, upper, (count, model.nq))
    return qs, rng.uniform(-2.0, 2.0, (count, model.nv))


@pytest.mark.parametrize("name", SHIPPED)
def test_joint_placements_match_pinocchios_forward_kinematics(name):
    arm = robot(name)
    qs, _ = random_states(arm.model, seed=11)
    assert kinematics.joint_chain(arm.model) is not None  # their joints all take the NumPy path
    R, p = joint_placements(arm, qs)
    R_ref, p_ref = pinocchio_placements(arm.model, qs)
    njoints = arm.model.njoints
    assert R.shape == (SAMPLES, njoints, 3, 3) and p.shape == (SAMPLES, njoints, 3)
    np.testing.assert_allclose(R, R_ref, rtol=0, atol=VEC_TOL)
    np.testing.assert_allclose(p, p_ref, rtol=0, atol=VEC_TOL)
    # the bare model gives the same; lanes (leading axes) are rows like any other
    R_model, _ = joint_placements(arm.model, qs)
    np.testing.assert_array_equal(R_model, R)
    R_lanes, p_lanes = joint_placements(arm, qs.reshape(2, SAMPLES // 2, -1))
    assert R_lanes.shape == (2, SAMPLES // 2, arm.model.njoints, 3, 3)
    np.testing.assert_allclose(R_lanes.reshape(R.shape), R, rtol=0, atol=VEC_TOL)
    np.testing.assert_allclose(p_lanes.reshape(p.shape), p, rtol=0, atol=VEC_TOL)


@pytest.mark.parametrize("name", SHIPPED)
@pytest.mark.parametrize("count", [SAMPLES, 3], ids=["numpy", "few"])
def test_tool_positions_and_speeds_match_pinocchios_frame_motion(name, count):
    arm = robot(name)
    qs, vs = random_states(arm.model, seed=12, count=count)
    fid = arm.model.getFrameId(arm.tool_frame)
    positions, speeds = compute_tool_motion(arm, qs, vs)
    ref_positions, ref_velocities = pinocchio_frame_motion(arm.model, fid, qs, vs)
    np.testing.assert_allclose(positions, ref_positions, rtol=0, atol=VEC_TOL)
    np.testing.assert_allclose(speeds, np.linalg.norm(ref_velocities, axis=1), rtol=0, atol=VEC_TOL)
    np.testing.assert_allclose(compute_tool_positions(arm, qs), positions, rtol=0, atol=VEC_TOL)


@pytest.mark.parametrize("name", SHIPPED)
def test_tool_column_norms_are_those_of_pinocchios_jacobian(name):
    arm = robot(name)
    qs, _ = random_states(arm.model, seed=15, count=8)
    norms = tool_column_norms(arm, joint_placements(arm, qs))
    ref = np.linalg.norm(compute_tool_jacobian(arm, qs), axis=1)  # (T, nv)
    np.testing.assert_allclose(norms, ref, rtol=0, atol=VEC_TOL)


@KERNEL_PATHS
@pytest.mark.parametrize("name", SHIPPED)
def test_the_fastest_arm_points_are_pinocchios_point_by_point(name, compiled, monkeypatch):
    """fastest_point_speeds (many states at once, compiled or NumPy) against point_speeds
    (Pinocchio's forward kinematics, one state): the same largest speed to round-off."""
    monkeypatch.setattr(body_kernel, "AVAILABLE", compiled)
    arm = robot(name)
    points = sample_arm_points(arm)
    qs, vs = random_states(arm.model, seed=16, count=8)
    fastest = fastest_point_speeds(arm, points, joint_placements(arm, qs), vs)
    ref = [np.max(point_speeds(arm, points, q, v)) for q, v in zip(qs, vs, strict=True)]
    np.testing.assert_allclose(fastest, ref, rtol=0, atol=VEC_TOL)
    assert np.all(fastest > 0.0)


def every_joint_type():
    """A tree of every 1-DoF joint type vtm-pin loads, unaligned axes and two branches, and a
    tool frame on the second branch; plus its joint types in order."""
    model = pin.Model()
    tilted = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    joints = [
        pin.JointModelRZ(),
        pin.JointModelRevoluteUnaligned(*tilted),
        pin.JointModelPX(),
        pin.JointModelRX(),
        pin.JointModelPrismaticUnaligned(*(-tilted)),
        pin.JointModelRY(),
        pin.JointModelPY(),
        pin.JointModelPZ(),
    ]
    parents = [0, 1, 2, 3, 4, 2, 6, 7]  # joint 6 branches off joint 2
    rng = np.random.default_rng(5)
    for k, (joint, parent) in enumerate(zip(joints, parents, strict=True)):
        placement = pin.SE3(pin.exp3(rng.normal(size=3)), rng.normal(scale=0.3, size=3))
        jid = model.addJoint(parent, joint, placement, f"j{k + 1}")
        model.appendBodyToJoint(jid, pin.Inertia.Random(), pin.SE3.Identity())
    tool = pin.SE3(pin.exp3(rng.normal(size=3)), np.array([0.1, -0.2, 0.3]))
    model.addFrame(pin.Frame("tool", model.njoints - 1, tool, pin.FrameType.OP_FRAME))
    return model, [j.shortname() for j in joints]


def test_every_joint_type_vtm_pin_loads_takes_the_numpy_path_and_matches_pinocchio():
    model, kinds = every_joint_type()
    assert set(kinds) == set(kinematics._MOTIONS)  # the tree has each type the table knows
    assert kinematics.joint_chain(model) is not None
    names = tuple(model.names[1:])
    tree = Robot("tree", "tree", model, names, np.ones(model.nv), tool_frame="tool")
    qs, vs = random_states(model, seed=13)
    R, p = joint_placements(tree, qs)
    R_ref, p_ref = pinocchio_placements(model, qs)
    np.testing.assert_allclose(R, R_ref, rtol=0, atol=VEC_TOL)
    np.testing.assert_allclose(p, p_ref, rtol=0, atol=VEC_TOL)
    positions, speeds = compute_tool_motion(tree, qs, vs)
    ref_positions, ref_velocities = pinocchio_frame_motion(model, model.getFrameId("tool"), qs, vs)
    np.testing.assert_allclose(positions, ref_positions, rtol=0, atol=VEC_TOL)
    np.testing.assert_allclose(speeds, np.linalg.norm(ref_velocities, axis=1), rtol=0, atol=VEC_TOL)


def test_a_joint_type_numpy_does_not_compute_falls_back_to_pinocchio():
    """A continuous joint (nq = 2, which load_robot refuses) and a spherical one: the model
    goes through Pinocchio's loop, with the same results as Pinocchio's own."""
    model = pin.Model()
    first = model.addJoint(0, pin.JointModelRUBZ(), pin.SE3.Identity(), "continuous")
    model.addJoint(first, pin.JointModelSpherical(), pin.SE3(np.eye(3), np.ones(3)), "ball")
    assert kinematics.joint_chain(model) is None
    rng = np.random.default_rng(14)
    qs = np.array([pin.randomConfiguration(model, -np.ones(6), np.ones(6)) for _ in range(40)])
    qs = np.array([pin.normalize(model, q) for q in qs + rng.normal(scale=0.1, size=qs.shape)])
    R, p = joint_placements(model, qs)
    R_ref, p_ref = pinocchio_placements(model, qs)
    np.testing.assert_array_equal(R, R_ref)
    np.testing.assert_array_equal(p, p_ref)


@pytest.mark.parametrize("name", ["ur10_annex_b", "ur10_estop_cat0"])
def test_the_stopping_reports_tool_path_and_speed_are_pinocchios_on_the_shipped_ur10_stops(name):
    scenario = load_scenario(SCENARIOS / f"{name}.yaml")
    result = run_scenario(scenario)
    report = compute_stopping_report(scenario.robot, result, scenario.brakes, scenario.tool_frame)
    model = scenario.robot.model
    fid = model.getFrameId(report.tool_frame)
    positions, velocities = pinocchio_frame_motion(model, fid, result.q, result.v)
    i0 = len(result.q) - len(report.tcp_path)
    assert len(result.q) >= NUMPY_FROM  # the NumPy path
    np.testing.assert_allclose(report.tcp_path, positions[i0:], rtol=0, atol=VEC_TOL)
    peak = np.max(np.linalg.norm(velocities[i0:], axis=1))
    assert report.tcp_peak_speed == pytest.approx(peak, rel=0, abs=VEC_TOL)


#: The two ways of computing the bodies' motions: NumPy over all states, and the compiled
#: kernel (state by state, with Numba: the ``fast`` extra, which the ``test`` extra installs).
BODY_MOTIONS = {
    "numpy": kinematics.numpy_body_motions,
    "compiled": pytest.param(
        body_kernel.body_motions,
        marks=pytest.mark.skipif(not body_kernel.AVAILABLE, reason="Numba is not installed"),
    ),
}


@pytest.mark.parametrize("way", BODY_MOTIONS.values(), ids=BODY_MOTIONS.keys())
@pytest.mark.parametrize("name", ["ur10", "tree"])
def test_body_motions_are_pinocchios_local_jacobians_velocities_and_bias_accelerations(
    name: str, way: Any
) -> None:
    """body_motions against Pinocchio's getJointJacobian(LOCAL), data.v and data.a_gf (RNEA at
    a = 0, gravity included), every joint of the UR10 and of the tree of every joint type,
    by NumPy and by the compiled kernel.

    Tolerance VEC_TOL [-, m/s, m/s^2] relative to 1 + the largest entry: the accelerations
    reach ~10 m/s^2 (gravity), each step a few products rounding at ~1e-16."""
    model = robot("ur10").model if name == "ur10" else every_joint_type()[0]
    qs, vs = random_states(model, seed=15, count=8)
    joints = tuple(range(1, model.njoints))
    J, V, C = way(kinematics.joint_chain(model), qs, vs, joints, model.gravity.vector)
    assert J.shape == (8, len(joints), 6, model.nv) and V.shape == C.shape == (8, len(joints), 6)
    data = model.createData()
    for b, (q, v) in enumerate(zip(qs, vs, strict=True)):
        pin.rnea(model, data, q, v, np.zeros(model.nv))
        pin.computeJointJacobians(model, data, q)
        for i, j in enumerate(joints):
            for ours, theirs in [
                (J[b, i], pin.getJointJacobian(model, data, j, pin.LOCAL)),
                (V[b, i], data.v[j].vector),
                (C[b, i], data.a_gf[j].vector),
            ]:
                scale = 1.0 + np.abs(theirs).max()
                np.testing.assert_allclose(ours, theirs, rtol=0, atol=VEC_TOL * scale)


@KERNEL_PATHS
@pytest.mark.parametrize("name", [*SHIPPED, "tree"])
def test_frame_motion_is_pinocchios_placements_and_tool_motion(name, compiled, monkeypatch):
    """frame_motion (compiled, or NumPy's placements and tool motion) against Pinocchio's
    forward kinematics sample by sample, on every shipped arm and the tree of every joint
    type (a tool frame on a branch, sliding joints on its path)."""
    monkeypatch.setattr(body_kernel, "AVAILABLE", compiled)
    if name == "tree":
        model, _ = every_joint_type()
        arm = Robot(
            "tree", "tree", model, tuple(model.names[1:]), np.ones(model.nv), tool_frame="tool"
        )
    else:
        arm = robot(name)
    qs, vs = random_states(arm.model, seed=17)
    (R, p), positions, speeds = kinematics.frame_motion(arm, qs, vs)
    R_ref, p_ref = pinocchio_placements(arm.model, qs)
    np.testing.assert_allclose(R, R_ref, rtol=0, atol=VEC_TOL)
    np.testing.assert_allclose(p, p_ref, rtol=0, atol=VEC_TOL)
    fid = arm.model.getFrameId(arm.tool_frame)
    ref_positions, ref_velocities = pinocchio_frame_motion(arm.model, fid, qs, vs)
    np.testing.assert_allclose(positions, ref_positions, rtol=0, atol=VEC_TOL)
    np.testing.assert_allclose(speeds, np.linalg.norm(ref_velocities, axis=1), rtol=0, atol=VEC_TOL)
    # one sample, and a frame on the world (it stays where it is), as well
    (R1, _), one, _ = kinematics.frame_motion(arm, qs[:1], vs[:1])
    np.testing.assert_allclose(one, ref_positions[:1], rtol=0, atol=VEC_TOL)
    assert R1.shape == (1, arm.model.njoints, 3, 3)
    _, still, none = kinematics.frame_motion(arm, qs, vs, "universe")
    np.testing.assert_array_equal(still, np.zeros((len(qs), 3)))
    np.testing.assert_array_equal(none, np.zeros(len(qs)))
