"""Forward kinematics over many samples: joint placements, a frame's positions, speeds, Jacobian.

The one place where the stopping report and the drawings get the tool frame's motion from.
Velocities are taken in ``LOCAL_WORLD_ALIGNED``: the velocity of the frame's origin in world
axes, so the linear Jacobian rows J give that velocity as J v.

**Vectorised over samples.** A stop has hundreds of samples and the arm's points are followed
at each; Pinocchio's ``forwardKinematics`` is called once per sample, and the Python loop
around it cost more than a batched study case's whole simulation. :func:`joint_placements`
computes every joint's placement at every sample with NumPy instead, joint by joint from the
root (``model.parents``): joint j's placement is its parent's, times its fixed placement in
the parent (``model.jointPlacements[j]``), times its motion: a rotation by q about the axis
for a revolute joint, a translation by q along it for a prismatic one (Pinocchio's
``JointModelRX/RY/RZ``, ``JointModelPX/PY/PZ`` and their ``...Unaligned`` forms: every joint
type :func:`vtm_pin.physics.robot.load_robot` accepts, since it refuses joints with nq != 1,
a URDF's ``continuous`` joints among them). A model with any other joint type, and fewer than
:data:`NUMPY_FROM` samples (where Pinocchio is faster), are computed by Pinocchio sample by
sample, so results never depend on which path is taken; the two agree to round-off
(tests/test_kinematics.py checks 1e-12 on the shipped robots).

A frame's linear velocity is the sum over the joints that carry it of w_j x (p - o_j) v_j for a
revolute joint (w_j its axis in the world, o_j its origin, p the frame's origin) and w_j v_j
for a prismatic one (the columns of its linear Jacobian times the rates). The Jacobian itself
(:func:`compute_tool_jacobian`) is asked at a few configurations only and stays Pinocchio's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pinocchio as pin

from ..files.model_cache import ModelCache
from . import body_kernel, motion_kernel
from .robot import Robot

_LWA = pin.LOCAL_WORLD_ALIGNED

#: Samples from which the NumPy steps are taken: they cost ~0.3 ms whatever the count (UR10),
#: Pinocchio ~8 us a sample, so fewer samples go through Pinocchio's loop.
NUMPY_FROM = 32

_X, _Y, _Z = np.eye(3)
#: Joint types computed with NumPy: (revolute, axis), the axis None when the joint holds it.
_MOTIONS: dict[str, tuple[bool, np.ndarray | None]] = {
    "JointModelRX": (True, _X),
    "JointModelRY": (True, _Y),
    "JointModelRZ": (True, _Z),
    "JointModelRevoluteUnaligned": (True, None),
    "JointModelPX": (False, _X),
    "JointModelPY": (False, _Y),
    "JointModelPZ": (False, _Z),
    "JointModelPrismaticUnaligned": (False, None),
}


@dataclass(frozen=True)
class JointChain:
    """A model's joints as arrays (index 0 is the universe).

    Attributes:
        parents: Parent joint of each joint.
        rotations: Fixed rotation of each joint in its parent, shape (njoints, 3, 3).
        translations: Fixed translation of each joint in its parent [m], shape (njoints, 3).
        axes: Unit axis of each joint in its own frame, shape (njoints, 3).
        revolute: Whether each joint turns (else it slides).
        index: Each joint's coordinate in q and v.
        skews: The cross-product matrix [a]x of each joint's axis, shape (njoints, 3, 3).
    """

    parents: tuple[int, ...]
    rotations: np.ndarray
    translations: np.ndarray
    axes: np.ndarray
    revolute: tuple[bool, ...]
    index: tuple[int, ...]
    skews: np.ndarray


def joint_chain(model: pin.Model) -> JointChain | None:
    """The model's joints as arrays; None if a joint is of a type NumPy does not compute."""
    axes = np.zeros((model.njoints, 3))
    revolute, index = [False], [0]
    for j in range(1, model.njoints):
        joint = model.joints[j]
        motion = _MOTIONS.get(joint.shortname())
        if motion is None or joint.nq != 1 or joint.nv != 1 or joint.idx_q != joint.idx_v:
            return None
        turns, axis = motion
        axes[j] = np.asarray(joint.extract().axis, dtype=float) if axis is None else axis
        revolute.append(turns)
        index.append(int(joint.idx_q))
    placements = model.jointPlacements
    x, y, z = axes.T
    zero = np.zeros_like(x)
    skews = np.stack([[zero, -z, y], [z, zero, -x], [-y, x, zero]]).transpose(2, 0, 1)
    return JointChain(
        parents=tuple(int(p) for p in model.parents),
        rotations=np.array([np.asarray(m.rotation) for m in placements]),
        translations=np.array([np.asarray(m.translation) for m in placements]),
        axes=axes,
        revolute=tuple(revolute),
        index=tuple(index),
        skews=np.ascontiguousarray(skews),
    )


def _numpy_placements(chain: JointChain, qs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World placements of every joint at each row of ``qs`` (see :func:`joint_placements`).

    Joint by joint from the root, each step as a few matrix products over all samples at once:
    a rotation by q about the unit axis a is c I + s [a]x + (1 - c) a a^T (Rodrigues).
    """
    count, njoints = len(qs), len(chain.parents)
    R = np.empty((njoints, count, 3, 3))  # joint-major: each joint's samples are contiguous
    p = np.empty((njoints, count, 3))
    R[0], p[0] = np.eye(3), 0.0
    term = np.empty((count, 3, 3))
    for j in range(1, njoints):
        parent = chain.parents[j]
        rows = R[parent].reshape(-1, 3)  # the parent's rotations, stacked: (3 count, 3)
        fixed = (rows @ chain.rotations[j]).reshape(count, 3, 3)
        np.add(p[parent], (rows @ chain.translations[j]).reshape(count, 3), out=p[j])
        q = qs[:, chain.index[j]]
        axis = chain.axes[j]
        along = (fixed.reshape(-1, 3) @ axis).reshape(count, 3)  # the axis in the world
        if chain.revolute[j]:
            c, s = np.cos(q)[:, None, None], np.sin(q)[:, None, None]
            crossed = (fixed.reshape(-1, 3) @ chain.skews[j]).reshape(count, 3, 3)
            # c fixed + s crossed + ((1 - c) along) axis, in place, in that order
            np.multiply(c, fixed, out=R[j])
            R[j] += np.multiply(s, crossed, out=term)
            np.multiply((1.0 - c) * along[:, :, None], axis, out=term)
            R[j] += term
        else:
            R[j] = fixed
            p[j] += along * q[:, None]
    return R.transpose(1, 0, 2, 3), p.transpose(1, 0, 2)


def _pinocchio_placements(model: pin.Model, qs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The same as :func:`_numpy_placements`, by Pinocchio one sample at a time."""
    data = model.createData()
    R = np.empty((len(qs), model.njoints, 3, 3))
    p = np.empty((len(qs), model.njoints, 3))
    for row, q in enumerate(qs):
        pin.forwardKinematics(model, data, q)
        for j in range(model.njoints):
            R[row, j] = data.oMi[j].rotation
            p[row, j] = data.oMi[j].translation
    return R, p


#: Chains of the models seen, by their kinematics (:func:`kinematics_key`): a study builds a
#: copy of its robot per case (a payload's), whose own cache starts empty.
_CHAINS = ModelCache(16)


def kinematics_key(robot: Robot) -> tuple[Any, ...]:
    """What the motion of the robot's joints depends on, hashable, kept in the robot's cache.

    The joints' names, parents, types (with the axis of an unaligned one) and fixed placements
    (exact bytes): two models with equal keys place their joints alike (a payload changes the
    inertias only). Frames are not in it.
    """

    def build() -> tuple[Any, ...]:
        model = robot.model
        joints = []
        for joint in model.joints:
            kind = joint.shortname()
            axis = joint.extract().axis.tobytes() if kind.endswith("Unaligned") else b""
            joints.append((kind, axis))
        placements = b"".join(m.homogeneous.tobytes() for m in model.jointPlacements)
        return tuple(model.names), tuple(model.parents), tuple(joints), placements

    return robot.cache.get("kinematics_key", build, kinematic=True)


def cached_chain(robot: Robot) -> JointChain | None:
    """:func:`joint_chain` of the robot's model, kept in its cache, shared by equal kinematics."""

    def shared() -> tuple[JointChain | None]:
        return _CHAINS.get(kinematics_key(robot), lambda: (joint_chain(robot.model),))

    return robot.cache.get("kinematic_chain", shared, kinematic=True)[0]


def numpy_chain(robot: Robot) -> JointChain:
    """:func:`cached_chain`, for the NumPy kinematics that need it.

    Raises:
        ValueError: The model has a joint type the NumPy kinematics do not take.
    """
    chain = cached_chain(robot)
    if chain is None:
        raise ValueError("the model has a joint type the NumPy kinematics do not take")
    return chain


def pinocchio_data(robot: Robot) -> pin.Data:
    """The robot's Pinocchio ``Data``, one per model, kept in its cache.

    Every call computes what it reads (see :mod:`vtm_pin.files.model_cache`).
    """
    return robot.cache.get("data", robot.model.createData)


def kinematic_data(robot: Robot) -> pin.Data:
    """A Pinocchio ``Data`` for the robot's kinematics only (placements, Jacobians, rates).

    One for the models that differ in their bodies' inertias only (a payload's variants:
    a kinematic entry of the cache), not one per model: a study drawing a payload per case
    would make one a case (~70 us). Every call computes what it reads.
    """
    return robot.cache.get("kinematic_data", robot.model.createData, kinematic=True)


def joint_placements(model: pin.Model | Robot, qs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every joint's placement in the world (Pinocchio's ``data.oMi``) at many configurations.

    Args:
        model: The Pinocchio model, or a robot (whose cache then keeps the model's joints).
        qs: Configurations [rad or m], shape (..., nq): any leading shape (samples, lanes).

    Returns:
        ``(R, p)``: rotations, shape (..., njoints, 3, 3), and origins [m], shape
        (..., njoints, 3), of the joints' frames (index 0 is the world: identity, 0).
    """
    if isinstance(model, Robot):
        chain, model = cached_chain(model), model.model
    else:
        chain = joint_chain(model)
    qs = np.asarray(qs, dtype=float)
    lead = qs.shape[:-1]
    flat = qs.reshape(-1, model.nq)
    if chain is None or len(flat) < NUMPY_FROM:
        R, p = _pinocchio_placements(model, flat)
    else:
        R, p = _numpy_placements(chain, flat)
    return R.reshape(*lead, model.njoints, 3, 3), p.reshape(*lead, model.njoints, 3)


def _frame_velocity(
    chain: JointChain, R: np.ndarray, p: np.ndarray, joint: int, origin: np.ndarray, vs: np.ndarray
) -> np.ndarray:
    """Linear velocity [m/s] of a point ``origin`` [m], shape (T, 3), carried by ``joint``.

    The sum over the joints from ``joint`` to the root of their Jacobian columns
    (:func:`_frame_columns`) times their rates ``vs`` [rad/s or m/s], shape (T, nv). Shape
    (T, 3).
    """
    columns, path = _frame_columns(chain, R, p, joint, origin)
    if not path:
        return np.zeros((len(R), 3))
    terms = columns * vs[:, [chain.index[j] for j in path], None]
    # summed from ``joint`` to the root, one joint after the other (the reduced axis is not
    # the innermost one, so NumPy adds in order)
    return np.add.reduce(terms, axis=1)


def _frame_columns(
    chain: JointChain, R: np.ndarray, p: np.ndarray, joint: int, origin: np.ndarray
) -> tuple[np.ndarray, list[int]]:
    """The linear Jacobian columns of a point ``origin`` [m], shape (T, 3), carried by ``joint``.

    Per joint from ``joint`` to the root: w_j x (origin - o_j) if it turns, w_j if it slides
    (w_j its axis in the world, o_j its origin; ``R``, ``p`` the joints' placements at the T
    samples). Returns the columns [m/rad or -], shape (T, len(path), 3), formed all at once,
    and their joints ``path``.
    """
    path = []
    j = joint
    while j > 0:
        path.append(j)
        j = chain.parents[j]
    count = len(R)
    axes = np.empty((count, len(path), 3))  # each joint's axis in the world
    for k, j in enumerate(path):
        axes[:, k] = (R[:, j].reshape(-1, 3) @ chain.axes[j]).reshape(-1, 3)
    columns = axes.copy()
    turns = [k for k, j in enumerate(path) if chain.revolute[j]]
    if turns:
        arms = origin[:, None] - p[:, [path[k] for k in turns]]
        columns[:, turns] = cross(axes[:, turns], arms)
    return columns, path


def tool_column_norms(
    robot: Robot,
    placements: tuple[np.ndarray, np.ndarray],
    tool_frame: str | None = None,
) -> np.ndarray:
    """|J_j|: the lengths of the tool frame's linear Jacobian columns [m/rad or -], shape (T, nv).

    At T samples whose joints' placements ``(R, p)`` are at hand (:func:`joint_placements`):
    the tool speed joint j gives at a unit rate; 0 for joints that do not carry the tool.

    Raises:
        ValueError: The model has a joint type the NumPy kinematics do not take.
    """
    chain = numpy_chain(robot)
    R, p = placements
    _, frame = _frame(robot.model, robot, tool_frame)
    columns, path = _frame_columns(chain, R, p, int(frame.parentJoint), _origins(R, p, frame))
    out = np.zeros((len(R), robot.nv))
    out[:, [chain.index[j] for j in path]] = np.sqrt(np.einsum("tki,tki->tk", columns, columns))
    return out


def body_velocities(
    chain: JointChain, R: np.ndarray, p: np.ndarray, v: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Each joint's body's angular velocity and its origin's velocity, world axes, at T states.

    Args:
        chain: The model's joints (:func:`joint_chain`).
        R: The joints' rotations at the states, shape (T, njoints, 3, 3).
        p: Their origins [m], shape (T, njoints, 3).
        v: The rates [rad/s or m/s], shape (T, nv).

    Returns:
        ``(omega, velocity)`` [rad/s, m/s], each shape (T, njoints, 3): a point x fixed to
        body j moves at velocity[:, j] + omega[:, j] x (x - p[:, j]).
    """
    omega = np.zeros(p.shape)
    velocity = np.zeros(p.shape)
    for j in range(1, len(chain.parents)):
        parent = chain.parents[j]
        along = (R[:, j].reshape(-1, 3) @ chain.axes[j]).reshape(-1, 3) * v[:, [chain.index[j]]]
        velocity[:, j] = velocity[:, parent] + cross(omega[:, parent], p[:, j] - p[:, parent])
        omega[:, j] = omega[:, parent]
        if chain.revolute[j]:
            omega[:, j] += along
        else:
            velocity[:, j] += along
    return omega, velocity


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of two (T, 3) arrays (``np.cross`` costs more on small ones)."""
    a0, a1, a2 = a.T
    b0, b1, b2 = b.T
    return np.column_stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products along the last axis (of length 3), broadcast.

    ``np.cross`` costs more on small arrays; these are its products and differences, so its
    bits.
    """
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _frame(model: pin.Model, robot: Robot, tool_frame: str | None) -> tuple[int, pin.Frame]:
    fid = model.getFrameId(tool_frame or robot.tool_frame)
    return fid, model.frames[fid]


def _origins(R: np.ndarray, p: np.ndarray, frame: pin.Frame) -> np.ndarray:
    """World positions [m] of ``frame``'s origin, shape (T, 3), from the joints' placements."""
    joint = int(frame.parentJoint)
    offset = np.asarray(frame.placement.translation, dtype=float)
    return p[:, joint] + (R[:, joint].reshape(-1, 3) @ offset).reshape(-1, 3)


def compute_tool_motion(
    robot: Robot,
    q: np.ndarray,
    v: np.ndarray,
    tool_frame: str | None = None,
    placements: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Tool-frame positions and speeds over samples of (q, v).

    Args:
        robot: The robot.
        q: Joint positions [rad], shape (k, n) (or (n,) for one sample).
        v: Joint rates [rad/s], the same shape.
        tool_frame: Frame followed; the robot's tool frame by default.
        placements: The joints' placements at ``q`` (:func:`joint_placements`), if they are
            at hand: they replace the NumPy steps (Pinocchio's loop, below :data:`NUMPY_FROM`
            samples, does not need them).

    Returns:
        ``(positions, speeds)``: positions of the frame's origin in the world [m], shape
        (k, 3), and the norms of its linear velocities [m/s], shape (k,).
    """
    model = robot.model
    fid, frame = _frame(model, robot, tool_frame)
    qs = np.atleast_2d(np.asarray(q, dtype=float))
    vs = np.atleast_2d(np.asarray(v, dtype=float))
    if qs.shape != vs.shape:
        raise ValueError(f"q has shape {qs.shape} and v {vs.shape}; they must be the same")
    chain = cached_chain(robot)
    if chain is None or len(qs) < NUMPY_FROM:
        return _pinocchio_motion(model, fid, qs, vs)
    R, p = _numpy_placements(chain, qs) if placements is None else placements
    positions = _origins(R, p, frame)
    velocities = _frame_velocity(chain, R, p, int(frame.parentJoint), positions, vs)
    return positions, np.sqrt(np.einsum("ki,ki->k", velocities, velocities))


def frame_motion(
    robot: Robot, q: np.ndarray, v: np.ndarray, tool_frame: str | None = None
) -> tuple[tuple[np.ndarray, np.ndarray], np.ndarray, np.ndarray]:
    """Every joint's placement and a frame's path and speed over samples (q, v), shape (k, n).

    :func:`joint_placements` and :func:`compute_tool_motion` at once; with the ``fast``
    extra, by :mod:`~vtm_pin.physics.motion_kernel` for a model whose joints the NumPy
    kinematics take (the two agree to round-off).

    Returns:
        ``((R, p), positions, speeds)``: as :func:`joint_placements` and
        :func:`compute_tool_motion` return them.
    """
    chain = cached_chain(robot)
    if chain is not None and motion_kernel.runs():
        _, frame = _frame(robot.model, robot, tool_frame)
        offset = np.asarray(frame.placement.translation, dtype=float)
        try:
            return motion_kernel.frame_motion(chain, q, v, int(frame.parentJoint), offset)
        except body_kernel.failures() as exc:  # Numba cannot run here: NumPy from now on
            body_kernel.fall_back(exc)
    placements = joint_placements(robot, q)
    return placements, *compute_tool_motion(robot, q, v, tool_frame, placements)


def _pinocchio_motion(
    model: pin.Model, fid: int, qs: np.ndarray, vs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`compute_tool_motion` by Pinocchio one sample at a time."""
    data = model.createData()
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
    _, frame = _frame(robot.model, robot, tool_frame)
    return _origins(*joint_placements(robot, qs), frame)


def compute_tool_jacobian(robot: Robot, q: np.ndarray, tool_frame: str | None = None) -> np.ndarray:
    """Linear Jacobian of the tool frame's origin in world axes [m/rad] at ``q`` [rad].

    Shape (3, n) for one configuration, shape (n,); (k, 3, n) for k of them, shape (k, n).
    By Pinocchio, one configuration at a time: it is asked at a few (the stop signal, the
    impacts), where one Pinocchio call is faster than the NumPy steps.
    """
    model = robot.model
    data = kinematic_data(robot)
    fid = model.getFrameId(tool_frame or robot.tool_frame)
    qs = np.asarray(q, dtype=float)
    J = [pin.computeFrameJacobian(model, data, qi, fid, _LWA)[:3] for qi in np.atleast_2d(qs)]
    return np.asarray(J[0] if qs.ndim == 1 else J)


def body_motions(
    chain: JointChain, qs: np.ndarray, vs: np.ndarray, joints: tuple[int, ...], gravity: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Jacobians, velocities and bias accelerations of some joints' bodies, local frames.

    Spatial vectors are Pinocchio's (linear, angular), each body's in its joint's frame.
    Joint k's motion subspace in the world at the world's origin is (o_k x w_k, w_k) for a
    revolute joint (w_k its axis in the world, o_k its origin; :func:`_numpy_placements`), (w_k,
    0) for a prismatic one. From the root, with V_0 = 0 and C_0 = -g (the bias acceleration
    RNEA starts from, gravity included): V_k = V_parent + S_k v_k and C_k = C_parent + V_k x
    (S_k v_k) (k's subspace moves with its body). A joint j's body Jacobian has the columns S_k
    of the joints k that carry it, and V_j = J_j v; all three are then expressed in joint j's
    frame (Pinocchio's ``oMi[j].actInv``): Pinocchio's ``getJointJacobian(..., LOCAL)``,
    ``data.v[j]`` and ``data.a_gf[j]`` at zero acceleration, to round-off. The arrays are
    held component first (each component's samples contiguous: the products are then a
    few long vector operations).

    Args:
        chain: The model's joints (:func:`joint_chain`).
        qs: Configurations [rad or m], shape (B, nq).
        vs: Rates [rad/s or m/s], shape (B, nv).
        joints: The joints whose bodies are asked for.
        gravity: The model's gravity as a spatial acceleration [m/s^2], shape (6,).

    With Numba installed (the ``fast`` extra) the same arithmetic runs compiled, state by
    state (:mod:`vtm_pin.physics.body_kernel`: ~0.6-1.3 against ~4-7 us a state for one body
    of the UR10), else with NumPy (:func:`numpy_body_motions`). ``NUMBA_DISABLE_JIT=1`` in
    the environment, Numba's own switch, picks NumPy.

    Returns:
        ``(J, V, C)``: shapes (B, len(joints), 6, nv), (B, len(joints), 6) [m/s, rad/s] and
        (B, len(joints), 6) [m/s^2, rad/s^2].
    """
    if body_kernel.AVAILABLE:
        try:
            return body_kernel.body_motions(chain, qs, vs, joints, gravity)
        except body_kernel.failures() as exc:  # Numba cannot run here: NumPy from now on
            body_kernel.fall_back(exc)
    return numpy_body_motions(chain, qs, vs, joints, gravity)


def numpy_body_motions(
    chain: JointChain, qs: np.ndarray, vs: np.ndarray, joints: tuple[int, ...], gravity: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`body_motions` with NumPy over all states at once, joint by joint (views)."""
    R, p = _numpy_placements(chain, qs)
    nv = vs.shape[1]
    axes = np.einsum("bjik,jk->ijb", R, chain.axes)  # every joint's axis in the world
    origins = np.ascontiguousarray(p.transpose(2, 1, 0))  # (3, njoints, B)
    turns = np.array(chain.revolute)[:, None]
    S = np.empty((6, *axes.shape[1:]))
    S[:3] = np.where(turns, _cross_first(origins, axes), axes)
    S[3:] = np.where(turns, axes, 0.0)
    S[:, 0] = 0.0  # the universe
    index = np.array(chain.index)
    Sv = S * vs[:, index].T
    V = _from_root(chain.parents, Sv)
    bias = _motion_cross_first(V, Sv)
    bias[:, 0] = -np.asarray(gravity, dtype=float)[:, None]
    C = _from_root(chain.parents, bias)
    picked = list(joints)
    X = np.zeros((6, len(picked), nv + 2, len(qs)))  # the columns of J, then V and C
    for d, j in enumerate(picked):
        k = j
        while k > 0:
            X[:, d, index[k]] = S[:, k]
            k = chain.parents[k]
    X[:, :, nv] = V[:, picked]
    X[:, :, nv + 1] = C[:, picked]
    linear = X[:3] + _cross_first(X[3:], origins[:, picked, None])  # at each joint's origin
    turn = R[:, picked].transpose(2, 3, 1, 0)[:, :, :, None]  # [k, i]: R_ki, (3, 3, D, 1, B)
    local = np.empty_like(X)
    for part, vector in ((slice(0, 3), linear), (slice(3, 6), X[3:])):  # R^T x
        local[part] = turn[0] * vector[0] + turn[1] * vector[1] + turn[2] * vector[2]
    local = local.transpose(3, 1, 0, 2)  # (B, D, 6, nv + 2)
    return local[..., :nv], local[..., nv], local[..., nv + 1]


def _from_root(parents: tuple[int, ...], terms: np.ndarray) -> np.ndarray:
    """Sums of ``terms[:, k]`` over each joint k and the joints that carry it (axis 1).

    A chain (each joint's parent the one before) is one cumulative sum, which adds in the
    same order as the loop over a tree's joints.
    """
    if parents == (0, *range(len(parents) - 1)):
        return np.cumsum(terms, axis=1)
    out = terms.copy()
    for k in range(1, len(parents)):
        out[:, k] += out[:, parents[k]]
    return out


def _cross_first(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products along the first axis (of length 3), broadcast over the others."""
    return np.stack(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


def _motion_cross_first(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Spatial motion cross products a x b along the first axis (linear, angular)."""
    linear = _cross_first(a[3:], b[:3]) + _cross_first(a[:3], b[3:])
    return np.concatenate([linear, _cross_first(a[3:], b[3:])])
