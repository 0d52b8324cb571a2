r"""Holonomic constraints between frames: loop closures and docking, with Pinocchio kinematics.

A constraint gives, at (q, v), its residual h(q), its Jacobian J(q) (J v = dh/dt) and the
acceleration term gamma = (dJ/dt) v, so that J a + gamma = 0 on the constraint manifold.
Joint locks are handled separately (:mod:`vtm_pin.numerics.constraints`): their rows are unit rows
and locked joints are removed from the integrated coordinates.

* ``point``: the origin of ``frame_a`` coincides with the origin of ``frame_b`` (loop closure) or
  with a fixed world point (docking). Rows: world x, y, z components, or a chosen subset
  (``axes``; a planar mechanism keeps x and z, its y row being identically zero).
* ``pose``: also the orientations agree; rotation rows are R_b log3(R_b^T R_a) in world axes.

Velocities and Jacobians are taken in ``LOCAL_WORLD_ALIGNED`` at each frame's origin, so for
coincident points the linear rows of J_a - J_b are exactly dh/dq.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ..exceptions import ConstraintError, ConstraintNotMet, VtmWarning, excerpt
from ..numerics.constraints import check_independent
from ..numerics.dynamics import compute_M
from ..numerics.transitions.projected import compute_null_space_projector
from ..physics.robot import Robot

_AXES = {"x": 0, "y": 1, "z": 2, "rx": 3, "ry": 4, "rz": 5}
_LWA = pin.LOCAL_WORLD_ALIGNED
#: A frame constraint activating at an event must hold there to within this distance [m] and
#: angle [rad]: the frames meet (or the docked frame is at its target). Farther apart, the
#: activation would pull them together with Baumgarte forces no mechanism exerts.
ACTIVATION_TOLERANCE = 1e-3


@dataclass(frozen=True)
class FrameConstraint:
    """A loop closure (``frame_b`` given) or a docking to the world (``frame_b`` None).

    Attributes:
        name: Name used in reports.
        frame_a: Frame of the robot that is constrained.
        frame_b: Second frame of a loop closure; None for docking to ``target``.
        mode: ``"point"`` (3 translation rows) or ``"pose"`` (3 translation + 3 rotation rows).
        axes: Rows kept, among x, y, z (and rx, ry, rz for ``pose``), world axes.
        target: Docking target pose in the world; None until latched at activation.
    """

    name: str
    frame_a: str
    frame_b: str | None = None
    mode: str = "point"
    axes: tuple[str, ...] = ()
    target: pin.SE3 | None = None

    def __post_init__(self) -> None:
        if self.mode not in ("point", "pose"):
            raise ConstraintError(
                f"Constraint '{self.name}': mode '{self.mode}' is not point or pose"
            )
        allowed = ("x", "y", "z") if self.mode == "point" else tuple(_AXES)
        if not self.axes:
            object.__setattr__(self, "axes", allowed)
        bad = [a for a in self.axes if a not in allowed]
        if bad:
            raise ConstraintError(
                f"Constraint '{self.name}': axis '{bad[0]}' not allowed for {self.mode}; "
                f"allowed: {', '.join(allowed)}"
            )
        object.__setattr__(self, "axes", tuple(sorted(set(self.axes), key=_AXES.__getitem__)))

    @property
    def size(self) -> int:
        """Number of constraint rows."""
        return len(self.axes)

    def check(self, model: pin.Model) -> None:
        """Raise if a frame is not in the model, or the constraint can constrain nothing.

        A loop between two frames of the same body, or a docking of a frame fixed to the
        world, has a zero Jacobian in every configuration.
        """
        for frame in (self.frame_a, self.frame_b):
            if frame is not None and not model.existFrame(frame):
                names = ", ".join(f.name for f in model.frames)
                raise ConstraintError(
                    f"Constraint '{excerpt(self.name)}': no frame '{excerpt(frame)}'; "
                    f"frames: {names}"
                )
        joint_a = model.frames[model.getFrameId(self.frame_a)].parentJoint
        if self.frame_b is None and joint_a == 0:
            raise ConstraintError(
                f"Constraint '{excerpt(self.name)}': frame '{excerpt(self.frame_a)}' is fixed to "
                "the world, so docking it constrains nothing; dock a frame that moves"
            )
        if (
            self.frame_b is not None
            and model.frames[model.getFrameId(self.frame_b)].parentJoint == joint_a
        ):
            raise ConstraintError(
                f"Constraint '{excerpt(self.name)}': frames '{excerpt(self.frame_a)}' and "
                f"'{excerpt(self.frame_b)}' move with the same body, so the loop closes nothing"
            )

    def latch(self, model: pin.Model, data: pin.Data, q: np.ndarray) -> FrameConstraint:
        """A docking constraint whose target is frame_a's pose at q (activation in place)."""
        if self.frame_b is not None or self.target is not None:
            return self
        pin.framesForwardKinematics(model, data, q)
        pose = data.oMf[model.getFrameId(self.frame_a)].copy()
        return dataclasses.replace(self, target=pose)

    def evaluate(
        self, model: pin.Model, data: pin.Data
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """h, J (rows x nv) and gamma = (dJ/dt) v at the state of ``data``.

        ``data`` must hold ``forwardKinematics(q, v, 0)``, ``computeJointJacobians`` and
        ``updateFramePlacements`` of the current state (see :func:`compute_kinematics`).
        """
        ia = model.getFrameId(self.frame_a)
        pose_a = data.oMf[ia]
        jac = pin.getFrameJacobian(model, data, ia, _LWA).copy()
        acc = pin.getFrameClassicalAcceleration(model, data, ia, _LWA).vector.copy()
        if self.frame_b is not None:
            ib = model.getFrameId(self.frame_b)
            pose_b = data.oMf[ib]
            jac -= pin.getFrameJacobian(model, data, ib, _LWA)
            acc -= pin.getFrameClassicalAcceleration(model, data, ib, _LWA).vector
        else:
            if self.target is None:
                raise ConstraintError(f"Docking constraint '{self.name}' has no target yet")
            pose_b = self.target
        h = np.empty(6)
        h[:3] = pose_a.translation - pose_b.translation
        h[3:] = pose_b.rotation @ pin.log3(pose_b.rotation.T @ pose_a.rotation)
        rows = [_AXES[a] for a in self.axes]
        return h[rows], jac[rows], acc[rows]


def compute_kinematics(model: pin.Model, data: pin.Data, q: np.ndarray, v: np.ndarray) -> None:
    """Fill ``data`` with what :meth:`FrameConstraint.evaluate` reads (zero acceleration)."""
    pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)


def check_activation(
    frames: Sequence[FrameConstraint], model: pin.Model, data: pin.Data, q: np.ndarray, t: float
) -> None:
    """Refuse frame constraints activating at ``t`` away from where they hold.

    Args:
        frames: Constraints activating at ``t``, targets latched.
        model: The robot model.
        data: Its data (overwritten).
        q: Configuration at the activation [rad].
        t: Activation time [s].

    Raises:
        ConstraintNotMet: A constraint's residual exceeds :data:`ACTIVATION_TOLERANCE`.
    """
    if not frames:
        return
    compute_kinematics(model, data, q, np.zeros(model.nv))
    for frame in frames:
        h, _, _ = frame.evaluate(model, data)
        linear = np.array([_AXES[a] < 3 for a in frame.axes], dtype=bool)
        distance = float(np.max(np.abs(h[linear]), initial=0.0))
        angle = float(np.max(np.abs(h[~linear]), initial=0.0))
        if not (distance <= ACTIVATION_TOLERANCE and angle <= ACTIVATION_TOLERANCE):
            raise ConstraintNotMet(frame.name, t, distance, angle, ACTIVATION_TOLERANCE)


def stack(
    constraints: tuple[FrameConstraint, ...], model: pin.Model, data: pin.Data
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """h, J and gamma of several constraints stacked in order (kinematics already computed)."""
    if not constraints:
        return np.zeros(0), np.zeros((0, model.nv)), np.zeros(0)
    parts = [c.evaluate(model, data) for c in constraints]
    return (
        np.concatenate([p[0] for p in parts]),
        np.vstack([p[1] for p in parts]),
        np.concatenate([p[2] for p in parts]),
    )


#: Initial corrections larger than this [rad, rad/s] are reported with a warning.
PROJECTION_WARNING = 1e-6
#: Gauss-Newton steps allowed to bring q onto the constraints.
PROJECTION_ITERATIONS = 50


def project_initial_state(
    robot: Robot, q: np.ndarray, v: np.ndarray, frames: Sequence[FrameConstraint]
) -> tuple[np.ndarray, np.ndarray]:
    """Bring (q, v) onto the frame constraints: Gauss-Newton on h(q), then J v = 0.

    The velocity is corrected with the momentum-consistent projection (the ``kkt`` jump of
    activating the constraints), the configuration by minimum-norm steps.

    Raises:
        ConstraintError: The constraints cannot be met from q (no convergence), or their rows
            are redundant there (a loop closing a frame on itself, a docked base frame).
    """
    model, data = robot.model, robot.model.createData()
    q0, v0 = q.copy(), v.copy()
    q = q.copy()
    for _ in range(PROJECTION_ITERATIONS):
        compute_kinematics(model, data, q, np.zeros(robot.nv))
        h, J, _ = stack(tuple(frames), model, data)
        if np.max(np.abs(h), initial=0.0) < 1e-13:
            break
        q = q - np.linalg.lstsq(J, h, rcond=None)[0]
    else:
        raise ConstraintError(
            f"The initial configuration cannot be brought onto the constraints "
            f"(|h| = {np.max(np.abs(h)):.3g} after {PROJECTION_ITERATIONS} steps)"
        )
    compute_kinematics(model, data, q, v)
    _, J, _ = stack(tuple(frames), model, data)
    check_independent(J, [f"{f.name}.{a}" for f in frames for a in f.axes])
    v = compute_null_space_projector(compute_M(model, data, q), J) @ v
    dq, dv = np.max(np.abs(q - q0)), np.max(np.abs(v - v0))
    if dq > PROJECTION_WARNING or dv > PROJECTION_WARNING:
        warnings.warn(
            f"Initial state moved onto the constraints by up to {dq:.3g} rad and {dv:.3g} rad/s",
            VtmWarning,
            stacklevel=3,
        )
    return q, v
