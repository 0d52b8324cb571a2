import numpy as np
import pinocchio as pin
import pytest
from conftest import robot

from vtm_pin.physics.kinematics import (
    compute_tool_jacobian,
    compute_tool_motion,
    compute_tool_positions,
)

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
