"""Forward kinematics of a tool frame: its positions, speeds and linear Jacobian.

The one place where the stopping report and the drawings get the tool frame's motion from
Pinocchio. Velocities are taken in ``LOCAL_WORLD_ALIGNED``: the velocity of the frame's
origin in world axes, so the linear Jacobian rows J give that velocity as J v.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from .robot import Robot

_LWA = pin.LOCAL_WORLD_ALIGNED


def compute_tool_motion(
    robot: Robot, q: np.ndarray, v: np.ndarray, tool_frame: str | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Tool-frame positions and speeds over samples of (q, v).

    Args:
        robot: The robot.
        q: Joint positions [rad], shape (k, n) (or (n,) for one sample).
        v: Joint rates [rad/s], the same shape.
        tool_frame: Frame followed; the robot's tool frame by default.

    Returns:
        ``(positions, speeds)``: positions of the frame's origin in the world [m], shape
        (k, 3), and the norms of its linear velocities [m/s], shape (k,).
    """
    model = robot.model
    data = model.createData()
    fid = model.getFrameId(tool_frame or robot.tool_frame)
    qs = np.atleast_2d(np.asarray(q, dtype=float))
    vs = np.atleast_2d(np.asarray(v, dtype=float))
    positions = np.empty((len(qs), 3))
    velocities = np.empty((len(qs), 3))
    for i, (qi, vi) in enumerate(zip(qs, vs, strict=True)):
        pin.forwardKinematics(model, data, qi, vi)
        positions[i] = pin.updateFramePlacement(model, data, fid).translation
        velocities[i] = pin.getFrameVelocity(model, data, fid, _LWA).linear
    return positions, np.linalg.norm(velocities, axis=1)


def compute_tool_positions(
    robot: Robot, q: np.ndarray, tool_frame: str | None = None
) -> np.ndarray:
    """Tool-frame positions [m], shape (k, 3), at configurations ``q`` [rad], shape (k, n)."""
    qs = np.atleast_2d(np.asarray(q, dtype=float))
    return compute_tool_motion(robot, qs, np.zeros_like(qs), tool_frame)[0]


def compute_tool_jacobian(robot: Robot, q: np.ndarray, tool_frame: str | None = None) -> np.ndarray:
    """Linear Jacobian of the tool frame's origin in world axes [m/rad] at ``q`` [rad].

    Shape (3, n) for one configuration, shape (n,); (k, 3, n) for k of them, shape (k, n).
    """
    model = robot.model
    data = model.createData()
    fid = model.getFrameId(tool_frame or robot.tool_frame)
    qs = np.asarray(q, dtype=float)
    J = [pin.computeFrameJacobian(model, data, qi, fid, _LWA)[:3] for qi in np.atleast_2d(qs)]
    return np.asarray(J[0] if qs.ndim == 1 else J)
