"""Generated n-link serial chains, for scaling studies and tests."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from ..exceptions import RobotLoadError
from .robot import Robot

LINK_LENGTH = 0.2  # [m]
LINK_MASS = 1.0  # [kg]
LINK_WIDTH = 0.04  # [m], square cross-section


def build_chain(n: int, spatial: bool = False) -> Robot:
    """A serial chain of ``n`` identical slender links hanging from the world origin.

    Args:
        n: Number of links and revolute joints, >= 1.
        spatial: False: all axes along y (a planar chain); True: axes alternate y, x, z.

    Returns:
        The chain as a :class:`Robot` with joints ``joint1`` ... ``joint<n>``; gravity
        (0, 0, -9.81) m/s^2; each link 0.2 m long, 1 kg, COM at mid-length.
    """
    if n < 1:
        raise RobotLoadError(f"chain of {n} links", "a chain needs at least one link")
    model = pin.Model()
    model.gravity.linear = np.array([0.0, 0.0, -9.81])
    axes = [pin.JointModelRY(), pin.JointModelRX(), pin.JointModelRZ()]
    transverse = LINK_MASS * (LINK_LENGTH**2 + LINK_WIDTH**2) / 12.0
    axial = LINK_MASS * (2 * LINK_WIDTH**2) / 12.0
    inertia = pin.Inertia(
        LINK_MASS,
        np.array([0.0, 0.0, -LINK_LENGTH / 2]),
        np.diag([transverse, transverse, axial]),
    )
    parent = 0
    body_frame = 0  # the universe frame
    placement = pin.SE3.Identity()
    names = []
    for i in range(n):
        joint = axes[i % 3] if spatial else axes[0]
        name = f"joint{i + 1}"
        parent = model.addJoint(parent, joint, placement, name)
        joint_frame = model.addJointFrame(parent, body_frame)
        model.appendBodyToJoint(parent, inertia, pin.SE3.Identity())
        body_frame = model.addBodyFrame(f"link{i + 1}", parent, pin.SE3.Identity(), joint_frame)
        placement = pin.SE3(np.eye(3), np.array([0.0, 0.0, -LINK_LENGTH]))
        names.append(name)
    model.addFrame(pin.Frame("tip", parent, body_frame, placement, pin.OP_FRAME))
    kind = "spatial" if spatial else "planar"
    return Robot(
        name=f"{kind}_chain_{n}",
        source="generated",
        model=model,
        joints=tuple(names),
        gear_ratio=np.ones(n),
        tool_frame="tip",
    )
