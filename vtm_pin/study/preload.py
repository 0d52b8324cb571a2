"""What a pool worker would load at its first case, loaded once by the pools' fork server.

The fork server imports this module (:data:`vtm_pin.study.executors.PRELOAD`), and only it
should: its import loads, here and once, what every worker forked from the server would
otherwise load for itself at its first case. Measured (issue 27, the UR10 envelope study, one
process): a worker's first 200 cases took ~0.6 s more than its next 200, in

- trimesh and what it imports (~0.3 s), to read the meshes of the arm's points
  (:func:`vtm_pin.physics.arm_points.sample_arm_points`);
- Numba (~0.2 s) and the compiled kernels' first calls (~0.3 s, loading the kernels from
  Numba's cache: :mod:`vtm_pin.physics.chain_dynamics`, :mod:`vtm_pin.physics.body_kernel`,
  :mod:`vtm_pin.physics.arm_kernel`, :mod:`vtm_pin.physics.motion_kernel`), with the ``fast``
  extra.

Everything here is an optimisation only: whatever fails is left for the workers, which meet
it where they always did (a kernel that cannot run falls back to NumPy there, said once).
"""

from __future__ import annotations

import contextlib

import numpy as np
import pinocchio as pin

from ..physics import arm_kernel, body_kernel, chain_dynamics, motion_kernel
from ..physics.arm_points import ArmPoints
from ..physics.kinematics import joint_chain


def warm_kernels() -> bool:
    """Call each compiled kernel once, on a two-joint arm; whether they ran.

    Their arguments are made contiguous, of fixed types, by their callers
    (:func:`~vtm_pin.physics.chain_dynamics.locked_dynamics`,
    :func:`~vtm_pin.physics.body_kernel.body_motions`): one signature each, whatever the robot,
    so a worker's first call finds it compiled.
    """
    if not chain_dynamics.runs():
        return False
    model = pin.Model()
    parent = 0
    for name in ("a", "b"):
        parent = model.addJoint(parent, pin.JointModelRZ(), pin.SE3.Identity(), name)
        model.appendBodyToJoint(parent, pin.Inertia.FromSphere(1.0, 0.1), pin.SE3.Identity())
    chain = joint_chain(model)
    q = np.zeros((1, 2))
    gravity = np.zeros(6)
    body_kernel.body_motions(chain, q, q, (1,), gravity)
    chain_dynamics.locked_dynamics(
        chain,
        q,
        q,
        q,
        np.array([[True, False]]),
        np.stack([np.array([i.toDynamicParameters() for i in model.inertias])]),
        np.zeros(1, dtype=np.int64),
        np.zeros(2),
        gravity,
    )
    points = ArmPoints(
        np.zeros((1, 3)), np.ones(1, dtype=int), np.zeros(1, dtype=int), ("a",), "", "", 0.0, 1
    )
    R, o = np.zeros((1, 2, 3, 3)), np.zeros((1, 2, 3))  # one sample, the world and joint 1
    one = np.ones(1, dtype=int)
    carried = (R[:, 1:], o[:, 1:])  # the joint that carries the point
    arm_kernel.largest_displacements(*carried, one - 1, one, points.groups, points.points, 0, 0)
    arm_kernel.fastest_speeds(R, o, o, points.groups, points.points)
    motion_kernel.frame_motion(chain, q, q, 2, np.zeros(3))
    return True


with contextlib.suppress(Exception):
    import trimesh  # noqa: F401  (imported for the workers)
with contextlib.suppress(Exception):
    warm_kernels()
