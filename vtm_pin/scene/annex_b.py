"""ISO 10218-1 Annex-B test conditions, computed with the robot's own kinematics.

Makers publish stopping data measured under ISO 10218-1 Annex B: only the tested joint moves,
at a fraction of its maximum speed, with the arm at a fraction of its maximum reach
("extension"); the other joints start at rest. Joints whose motion moves the tool vertically
are tested moving down at the signal (the worst case, as Universal Robots test). This module
turns such conditions into an initial state (q, v) of the robot; nothing in it is specific to
one robot: every figure comes from the Pinocchio model.

Definitions:

- **Joint 1** is the first moving joint in velocity order (index 0). Its axis is a fixed line
  in the world (it is the first joint; it is computed with Pinocchio at any q).
- **Horizontal reach** r(q) [m]: the distance from the tool-frame origin to the joint-1 axis
  line.
- **Posed horizontally**: the tool-frame origin lies in the plane through the origin of the
  second moving joint, perpendicular to the joint-1 axis (for an arm with a vertical base
  axis: the tool at shoulder height).
- **Maximum reach** R [m]: the largest r(q) over poses posed horizontally, with every joint
  within its position limits (joint 1 does not change r; it is kept at the guess). Found with
  scipy.optimize (SLSQP with the plane as an equality constraint, bounds = limits, a few
  deterministic starts: the guess, the neutral configuration and six seeded pseudo-random
  poses; the best is taken).
- **Extension e** (0 < e <= 1): the pose posed horizontally with r(q) = e R that is nearest
  (Euclidean in joint space) to a guess pose ``q_guess`` (the scenario's initial q), joint 1
  and joints that cannot move the tool frame left at their guess values (clipped into their
  limits). For e < 1 solved by Newton's method on the problem's KKT conditions from the guess
  (exact second derivatives of the kinematics); when that does not reach a regular local
  minimum within the limits, and at e = 1, with SLSQP from the guess and a few deterministic
  starts. The constraint residuals must be below 1e-9 m, else the conditions are refused.
- **Speed**: ``speed`` (a fraction in (0, 1]) times ``max_speed`` [rad/s or m/s] when given,
  else the tested joint's URDF velocity limit (``model.velocityLimit``).
- **Direction** in ("down", "up", "positive", "negative"), default "down". "down": the tested
  joint's rate has the sign that moves the tool-frame origin along gravity
  (``model.gravity.linear``), i.e. the sign of g_hat . J_lin[:, i] with the tool's
  world-aligned linear Jacobian (``pin.LOCAL_WORLD_ALIGNED``); when that vertical component is
  negligible (|.| <= 1e-9 x max(norm of the column, tiny), e.g. a vertical-axis joint) the
  joint moves in its positive direction and the state records that its motion is not
  vertical. "up" the opposite (and the positive direction too for a joint whose motion is
  not vertical); "positive"/"negative" the sign of the rate directly.
- Initial velocity: zero for every joint but the tested one, which has the signed speed.

The maximum reach is cached per kinematics (the tree, joint placements and axes, the tool
frame's parent joint and placement, position limits), tool frame and guess of the joints that
move the tool (a start of its search), so that a model that differs only in its inertias (a
payload) reuses it; a pose is cached per kinematics, tool frame, extension and guess, so that
the cases of a study that share them compute it once. A study's runner fills this cache with its
cases' poses solved together (:mod:`vtm_pin.scene.annex_b_batch`).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from numbers import Real
from typing import Any

import numpy as np
import pinocchio as pin
from scipy.optimize import least_squares, minimize

from ..exceptions import ConditionsError, excerpt
from ..physics.kinematics import kinematic_data
from ..physics.robot import Robot

#: Test directions a scenario may ask for.
DIRECTIONS: tuple[str, ...] = ("down", "up", "positive", "negative")

#: [m] Largest residual of the pose constraints (r(q) = e R and the plane) accepted.
RESIDUAL_TOL = 1.0e-9
#: [-] A joint's motion counts as not vertical when the vertical component of its tool-velocity
#: column is at most this fraction of the column's norm (round-off of a horizontal column).
VERTICAL_RTOL = 1.0e-9
#: [m] A maximum reach below this is none: the tool frame sits on the joint-1 axis.
MIN_REACH = 1.0e-6
#: Starts of the maximum-reach search beyond the guess and the neutral configuration: fixed
#: pseudo-random poses within the limits (seeded, so that the search is deterministic).
EXTRA_STARTS, START_SEED = 6, 10218
#: [rad or m] Half-width of the start range about a joint's mid-limit when its limits are wider
#: (UR joints turn +-2 pi: starts beyond +-pi repeat poses).
START_HALF_RANGE = math.pi
#: SLSQP's iteration limit (beyond it the last iterate is polished and checked).
SLSQP_MAXITER = 100
#: SLSQP's tolerance on the objective of the maximum-reach search, -r^2/2 [m^2]: R to ~1e-12 m
#: (the maximizers kept must reach R within 1e-9 m).
REACH_FTOL = 1.0e-12
#: SLSQP's tolerance on the objective of the pose search, |q - q_guess|^2/2 [rad^2]: the
#: distance to the guess is minimized to ~1e-5 rad; the constraints are polished to round-off.
POSE_FTOL = 1.0e-10
#: Largest number of residual evaluations of a least-squares search for a feasible pose.
LSQ_MAX_NFEV = 200
#: Newton steps that polish an SLSQP solution onto its constraints (to round-off).
POLISH_STEPS = 4
#: Newton iterations on the KKT system of the pose search before SLSQP takes over.
NEWTON_MAXITER = 40
#: [rad or m] Largest change of a free joint in one Newton step (a longer step is shortened):
#: keeps the iterates in the guess's basin of the (2 pi periodic) kinematics.
NEWTON_MAX_STEP = 0.5
#: [rad or m] Newton's stationarity tolerance: |(x - g) + J_c^T lambda| (max norm), i.e. the
#: distance to the guess is minimized to round-off (SLSQP's POSE_FTOL gives ~1e-5 rad).
KKT_TOL = 1.0e-11
#: [m] Newton's constraint tolerance: round-off of a ~1 m arm, 1e-4 of RESIDUAL_TOL.
NEWTON_CTOL = 1.0e-13
#: Halvings of a Newton step before the line search gives up (the KKT residual did not fall).
NEWTON_HALVINGS = 30
#: [-] Smallest ratio of the constraint Jacobian's singular values, and smallest eigenvalue of
#: the reduced Hessian of the Lagrangian (its identity part gives 1 at a regular minimum),
#: for Newton's point to count as a regular local minimum; else SLSQP decides.
NEWTON_REGULAR = 1.0e-8
#: Entries kept in the caches of maximum reaches and of poses.
REACH_CACHE_SIZE, POSE_CACHE_SIZE = 64, 4096

_LWA = pin.LOCAL_WORLD_ALIGNED


def _fraction(key: str, value: object, what: str) -> float:
    """A fraction in (0, 1], or :class:`ConditionsError` naming ``key``."""
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ConditionsError(key, f"{what} must be a number in (0, 1], not {excerpt(value)}")
    x = float(value)
    if not (math.isfinite(x) and 0.0 < x <= 1.0):
        raise ConditionsError(key, f"{what} must be in (0, 1] (1 = 100 %), not {x!r}")
    return x


@dataclass(frozen=True)
class Conditions:
    """ISO 10218-1 Annex-B test conditions of one joint (validated on construction).

    Attributes:
        joint: Name of the tested joint.
        speed: Fraction of the joint's maximum speed [-], in (0, 1].
        extension: Fraction of the maximum reach R [-], in (0, 1].
        max_speed: The joint's maximum speed [rad/s, or m/s for a prismatic joint], > 0; None:
            the URDF velocity limit.
        direction: One of :data:`DIRECTIONS`.

    Raises:
        ConditionsError: A value is out of range; ``key`` names the field.
    """

    joint: str
    speed: float = 1.0
    extension: float = 1.0
    max_speed: float | None = None
    direction: str = "down"

    def __post_init__(self) -> None:
        if not isinstance(self.joint, str) or not self.joint:
            raise ConditionsError(
                "joint", f"the tested joint must be a joint name, not {excerpt(self.joint)}"
            )
        object.__setattr__(self, "speed", _fraction("speed", self.speed, "the speed fraction"))
        object.__setattr__(
            self, "extension", _fraction("extension", self.extension, "the extension fraction")
        )
        top = self.max_speed
        if top is not None:
            if isinstance(top, bool) or not isinstance(top, Real):
                raise ConditionsError(
                    "max_speed", f"must be a number > 0 [rad/s or m/s], not {excerpt(top)}"
                )
            top = float(top)
            if not (math.isfinite(top) and top > 0.0):
                raise ConditionsError(
                    "max_speed", f"must be finite and > 0 [rad/s or m/s], not {top!r}"
                )
            object.__setattr__(self, "max_speed", top)
        if self.direction not in DIRECTIONS:
            raise ConditionsError(
                "direction",
                f"must be one of {', '.join(DIRECTIONS)}, not {excerpt(self.direction)}",
            )


@dataclass(frozen=True, eq=False)
class TestState:
    """The computed Annex-B test state.

    Attributes:
        q: Pose [rad or m], shape (nq,).
        v: Joint rates [rad/s or m/s], shape (nv,): zero but for the tested joint.
        speed: Signed rate of the tested joint [rad/s or m/s].
        reach: Horizontal reach r(q) of the pose [m].
        max_reach: Maximum reach R [m].
        vertical: Whether the tested joint moves the tool frame vertically at ``q``.
        joint_index: Index of the tested joint in ``q`` and ``v``.
        unit: Unit of the tested joint's rate: "rad/s" (revolute) or "m/s" (prismatic).
    """

    __test__ = False  # not a pytest test class

    q: np.ndarray
    v: np.ndarray
    speed: float
    reach: float
    max_reach: float
    vertical: bool
    joint_index: int
    unit: str = "rad/s"


def horizontal_reach(robot: Robot, tool_frame: str, q: np.ndarray | Sequence[float]) -> float:
    """Horizontal reach r(q): distance of the tool-frame origin from the joint-1 axis [m].

    Args:
        robot: The robot.
        tool_frame: Frame whose origin is measured.
        q: Joint positions [rad or m], shape (nq,).

    Raises:
        ConditionsError: The robot has no frame ``tool_frame``.
    """
    chain = _robot_chain(robot, tool_frame)
    return _Evaluator(robot.model, chain, _as_q(robot.model, q)).reach()


def max_reach(robot: Robot, tool_frame: str, q_guess: np.ndarray | Sequence[float]) -> float:
    """Maximum reach R [m]: the largest horizontal reach over poses posed horizontally.

    Cached per kinematics, tool frame and the guess of the joints varied (the guess is one
    start of the search), so that a model with other inertias (a payload) reuses it.

    Args:
        robot: The robot.
        tool_frame: Frame whose reach is measured.
        q_guess: A guess pose [rad or m], shape (nq,): one start of the search. Joint 1 and
            the joints that cannot move the tool frame do not change r and are kept.

    Raises:
        ConditionsError: The robot cannot be posed horizontally (key "extension").
    """
    model = robot.model
    chain = _robot_chain(robot, tool_frame)
    return _max_reach(model, chain, _clip(model, _as_q(model, q_guess))).R


def extension_pose(
    robot: Robot, tool_frame: str, extension: float, q_guess: np.ndarray | Sequence[float]
) -> np.ndarray:
    """The pose posed horizontally at reach ``extension`` x R nearest to ``q_guess``.

    Cached per kinematics, tool frame, extension and guess.

    Args:
        robot: The robot.
        tool_frame: Frame whose reach is set.
        extension: Fraction e of the maximum reach R [-], in (0, 1].
        q_guess: Guess pose [rad or m], shape (nq,); joint 1 and the joints that cannot move
            the tool frame keep their values (clipped into their limits).

    Returns:
        The pose [rad or m], shape (nq,), within the position limits.

    Raises:
        ConditionsError: ``extension`` is not in (0, 1], or no pose meets the constraints to
            1e-9 m (key "extension").
    """
    e = _fraction("extension", extension, "the extension fraction")
    model = robot.model
    chain = _robot_chain(robot, tool_frame)
    return _extension_pose(model, chain, e, _clip(model, _as_q(model, q_guess)))


def compute_test_state(
    robot: Robot,
    tool_frame: str,
    conditions: Conditions,
    q_guess: np.ndarray | Sequence[float],
) -> TestState:
    """The Annex-B test state: the extension pose and the tested joint's signed speed.

    Args:
        robot: The robot.
        tool_frame: Frame whose reach and vertical motion define the pose and the direction.
        conditions: The test conditions.
        q_guess: Guess pose [rad or m], shape (nq,) (the scenario's initial q).

    Raises:
        ConditionsError: The joint is unknown (key "joint"), the joint has no velocity limit
            and no ``max_speed`` is given (key "max_speed"), or the pose cannot be reached
            (key "extension").
    """
    model = robot.model
    if conditions.joint not in robot.joints:
        raise ConditionsError(
            "joint",
            f"the robot has no joint '{excerpt(conditions.joint)}'; "
            f"its joints are: {', '.join(robot.joints)}",
        )
    i = robot.joints.index(conditions.joint)
    chain = _robot_chain(robot, tool_frame)
    unit = "m/s" if chain.prismatic[i] else "rad/s"
    top = _max_speed(model, conditions, i, unit)
    guess = _clip(model, _as_q(model, q_guess))
    q = _extension_pose(model, chain, conditions.extension, guess)
    R = _max_reach(model, chain, guess).R
    reach, column = _reach_and_column(model, chain, q, kinematic_data(robot), i)
    sign, vertical = _direction(model, column, conditions.direction)
    speed = sign * conditions.speed * top
    v = np.zeros(model.nv)
    v[i] = speed
    return TestState(
        q=q,
        v=v,
        speed=speed,
        reach=reach,
        max_reach=R,
        vertical=vertical,
        joint_index=i,
        unit=unit,
    )


def describe_conditions(conditions: Conditions, state: TestState, tool_frame: str) -> list[str]:
    """Assumption lines, in SI units, that state the Annex-B conditions of a run.

    Args:
        conditions: The conditions asked for.
        state: The test state computed from them.
        tool_frame: The frame whose reach and vertical motion were used.

    Returns:
        One line each for the convention, the speed, the extension and the direction.
    """
    j, u, d = conditions.joint, state.unit, conditions.direction
    top = abs(state.speed) / conditions.speed
    source = (
        "annex_b.max_speed"
        if conditions.max_speed is not None
        else f"the URDF velocity limit of '{j}'"
    )
    rate = f"rate {state.speed:+.4g} {u}"
    if d in ("positive", "negative"):
        how = f"the {rate} is {d} as asked"
        if state.vertical:
            how += " (it moves the tool frame vertically)"
    elif state.vertical:
        how = f"the {rate} moves the tool frame {'along' if d == 'down' else 'against'} gravity"
    else:
        how = (
            f"'{j}' does not move the tool frame vertically at this pose, so it moves in its "
            f"positive direction ({rate})"
        )
    return [
        f"ISO 10218-1 Annex-B test conditions: only joint '{j}' moves at the stop signal; "
        "every other joint starts at rest.",
        f"Annex-B speed: {conditions.speed:.4g} x {top:.4g} {u} ({source}) = "
        f"{abs(state.speed):.4g} {u}.",
        f"Annex-B extension: e = {conditions.extension:.4g}: tool frame '{tool_frame}' is "
        f"{state.reach:.4g} m from the joint-1 axis, of a maximum reach R = "
        f"{state.max_reach:.4g} m, posed horizontally (in the plane through the origin of the "
        "second moving joint, perpendicular to the joint-1 axis).",
        f"Annex-B direction '{d}': {how}.",
    ]


# --------------------------------------------------------------------------------------------
# Model queries


@dataclass(frozen=True, eq=False)
class _Chain:
    """What the pose problems need of one model's kinematics and tool frame.

    Attributes:
        key: The kinematics and tool frame as bytes (the key of the caches).
        frame: Id of the tool frame.
        free: Velocity indices of the joints varied: those that move the tool frame, but
            joint 1.
        point: A point of the joint-1 axis line in the world [m], shape (3,).
        axis: Unit direction of the joint-1 axis in the world [-], shape (3,).
        plane_joint: Pinocchio id of the second moving joint (its origin is in the plane).
        prismatic: Whether each joint (velocity order) translates, shape (nv,).
    """

    key: tuple[Any, ...]
    frame: int
    free: np.ndarray
    point: np.ndarray
    axis: np.ndarray
    plane_joint: int
    prismatic: np.ndarray


def _as_q(model: pin.Model, q: np.ndarray | Sequence[float]) -> np.ndarray:
    """``q`` as a float array of shape (nq,), or ValueError."""
    arr = np.array(q, dtype=float).reshape(-1)
    if arr.shape != (model.nq,) or not np.isfinite(arr).all():
        raise ValueError(f"q must hold {model.nq} finite values, not {excerpt(q)}")
    return arr


def _clip(model: pin.Model, q: np.ndarray) -> np.ndarray:
    """``q`` clipped into the position limits."""
    return np.clip(q, model.lowerPositionLimit, model.upperPositionLimit)


def _kinematics_key(model: pin.Model, tool_frame: str) -> tuple[Any, ...]:
    """The model's kinematics and the tool frame as a hashable key (inertias left out).

    Holds the tree (parents), the joint placements, the joints' motion subspaces (axes),
    the tool frame's id, parent joint and placement, and the position limits.
    """
    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    frame_id = int(model.getFrameId(tool_frame))
    frame = model.frames[frame_id]
    return (
        tool_frame,
        frame_id,
        tuple(model.parents),
        np.array([p.homogeneous for p in model.jointPlacements]).tobytes(),
        np.array([np.asarray(jd.S) for jd in data.joints[1:]]).tobytes(),
        int(frame.parentJoint),
        frame.placement.homogeneous.tobytes(),
        model.lowerPositionLimit.tobytes(),
        model.upperPositionLimit.tobytes(),
    )


def _robot_chain(robot: Robot, tool_frame: str) -> _Chain:
    """:func:`_chain` of the robot's model, kept in its cache (a kinematic entry)."""
    return robot.cache.get(
        ("annex_b_chain", tool_frame), lambda: _chain(robot.model, tool_frame), kinematic=True
    )


def _chain(model: pin.Model, tool_frame: str) -> _Chain:
    """The :class:`_Chain` of ``model`` and ``tool_frame`` (cached on the kinematics key).

    Raises:
        ConditionsError: No such frame, or fewer than two moving joints (key "extension").
    """
    if not model.existFrame(tool_frame):
        raise ConditionsError(
            "extension", f"the robot has no frame '{excerpt(tool_frame)}' to pose and measure"
        )
    key = _kinematics_key(model, tool_frame)
    hit = _recall(_CHAIN_CACHE, key)
    if hit is not None:
        return hit
    if model.nv < 2:
        raise ConditionsError(
            "extension",
            "posing the arm horizontally needs a second moving joint (its origin sets the "
            f"plane); the robot has {model.nv}",
        )
    frame = int(model.getFrameId(tool_frame))
    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    S = [np.asarray(jd.S).reshape(6) for jd in data.joints[1:]]  # (linear, angular), local
    support = [j for j in model.supports[model.frames[frame].parentJoint] if j > 0]
    free = np.array(sorted(model.idx_vs[j] for j in support if model.idx_vs[j] != 0), dtype=int)
    local = S[0][3:] if np.linalg.norm(S[0][3:]) > 0.0 else S[0][:3]
    joint1 = data.oMi[1]  # in velocity order the first joint is Pinocchio joint 1
    axis = joint1.rotation @ local
    chain = _Chain(
        key=key,
        frame=frame,
        free=free,
        point=joint1.translation.copy(),
        axis=axis / np.linalg.norm(axis),
        plane_joint=next(j for j in range(1, model.njoints) if model.idx_vs[j] == 1),
        prismatic=np.array([np.linalg.norm(s[3:]) == 0.0 for s in S]),
    )
    _remember(_CHAIN_CACHE, key, chain, REACH_CACHE_SIZE)
    return chain


def _max_speed(model: pin.Model, conditions: Conditions, i: int, unit: str) -> float:
    """The tested joint's maximum speed [rad/s or m/s]: ``max_speed`` or the URDF limit."""
    if conditions.max_speed is not None:
        return conditions.max_speed
    limit = float(model.velocityLimit[i])
    if not (math.isfinite(limit) and limit > 0.0):
        raise ConditionsError(
            "max_speed",
            f"the URDF gives joint '{conditions.joint}' no velocity limit: "
            f"set annex_b.max_speed [{unit}]",
        )
    return limit


def _direction(model: pin.Model, column: np.ndarray, direction: str) -> tuple[float, bool]:
    """Sign of the tested joint's rate and whether it moves the tool frame vertically.

    Args:
        model: The model (its gravity sets "down").
        column: The tested joint's column of the tool's world-aligned linear Jacobian
            [m/rad or m/m], shape (3,).
        direction: One of :data:`DIRECTIONS`.
    """
    g = np.asarray(model.gravity.linear, dtype=float)
    g_norm = float(np.linalg.norm(g))
    down = float(g @ column) / g_norm if g_norm > 0.0 else 0.0
    vertical = abs(down) > VERTICAL_RTOL * max(float(np.linalg.norm(column)), _TINY)
    if direction == "positive":
        return 1.0, vertical
    if direction == "negative":
        return -1.0, vertical
    if not vertical:
        return 1.0, False
    along = 1.0 if down > 0.0 else -1.0
    return (along if direction == "down" else -along), True


# --------------------------------------------------------------------------------------------
# Pose problems


class _Evaluator:
    """r(q), the plane offset h(q) [m] and their gradients over the free joints.

    SLSQP asks for the objective, the constraints and their gradients at the same point one
    after another; one frame Jacobian (which also places the frame) answers them all.
    """

    def __init__(
        self, model: pin.Model, chain: _Chain, q_base: np.ndarray, data: pin.Data | None = None
    ) -> None:
        self.model = model
        self.data = model.createData() if data is None else data  # scratch space: all computed
        self.chain = chain
        self.q = q_base.copy()
        self.J6 = np.zeros((6, model.nv))
        self.J = self.J6[:3]
        self.Jf6 = self.J6[:, chain.free]
        pin.forwardKinematics(model, self.data, self.q)
        joint = chain.plane_joint
        origin = (self.data.oMi[model.parents[joint]] * model.jointPlacements[joint]).translation
        # The plane's origin moves only with joint 1, which stays put: its height is constant.
        self.plane_height = float(chain.axis @ (origin - chain.point))
        self._key: bytes | None = None
        self.r = self.h = 0.0
        self.dr = self.dh = np.zeros(len(chain.free))
        self._lower = _lower_triangle(len(chain.free))
        self.at(self.q[chain.free])

    def at(self, x: np.ndarray) -> _Evaluator:
        """Evaluate at free-joint values ``x`` [rad or m] (kept while ``x`` does not change)."""
        key = np.asarray(x, dtype=float).tobytes()  # exact, and cheaper than comparing arrays
        if key == self._key:
            return self
        chain = self.chain
        self.q[chain.free] = x
        self.J6 = pin.computeFrameJacobian(self.model, self.data, self.q, chain.frame, _LWA)
        self.J = self.J6[:3]
        self.Jf6 = self.J6[:, chain.free]
        Jf = self.Jf6[:3]
        along, radial = _offset(self.data, chain)
        self.r = float(np.linalg.norm(radial))
        self.h = along - self.plane_height
        self.dr = (radial / self.r) @ Jf if self.r > 0.0 else np.zeros(len(x))
        self.dh = chain.axis @ Jf
        self._key = key
        return self

    def reach(self) -> float:
        """r(q) at the last point [m]."""
        return self.r

    def lagrangian_hessian(self, lam: np.ndarray) -> np.ndarray:
        """I + lam[0] d2r + lam[1] d2h over the free joints at the last point, (n, n).

        The Hessian of |x - g|^2 / 2 + lam . (r - target, h), in closed form from the frame
        Jacobian's columns (no other kinematics): the free joints are a chain in velocity order
        (all carry the tool frame), so with w_k the angular and v_k the linear column of joint
        k (w_k = 0 for a prismatic joint), the tool origin p has d2p/dq_i dq_j =
        w_min(i,j) x v_max(i,j): turning an inner joint turns the outer one's column with it;
        moving an outer joint moves p about the inner axis. With a the joint-1 axis, u the unit
        radial direction and P = I - a a^T: d2h = a . d2p and
        d2r = u . d2p + ((P V)^T (P V) - dr dr^T) / r; the two projections of d2p are one,
        along lam[0] u + lam[1] a.
        """
        V, W = self.Jf6[:3], self.Jf6[3:]
        axis = self.chain.axis
        k = lam[1] * axis
        H = np.eye(V.shape[1])
        if self.r > 0.0:
            d = self.data.oMf[self.chain.frame].translation - self.chain.point
            k = k + lam[0] * (d - float(axis @ d) * axis) / self.r
            PV = V - np.outer(axis, axis @ V)
            H += (lam[0] / self.r) * (PV.T @ PV - np.outer(self.dr, self.dr))
        kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        M = (kx @ W).T @ V  # (i, j), i <= j: k . (w_i x v_j) = (k x w_i) . v_j
        M[self._lower] = M.T[self._lower]
        return H + M

    def polish(self, x: np.ndarray, target: float | None, bounds: _Bounds) -> np.ndarray:
        """Newton steps (minimum norm) onto h = 0, and onto r = ``target`` unless None."""
        for _ in range(POLISH_STEPS):
            self.at(x)
            rows = [self.dh] if target is None else [self.dr, self.dh]
            c = np.array([self.h] if target is None else [self.r - target, self.h])
            if np.max(np.abs(c)) <= _POLISHED:
                break
            step = np.linalg.lstsq(np.array(rows), -c, rcond=1e-10)[0]
            x = np.clip(x + step, bounds[0], bounds[1])
        self.at(x)
        return x

    def residual(self, target: float | None) -> float:
        """Largest constraint residual at the last point [m]."""
        return max(abs(self.h), 0.0 if target is None else abs(self.r - target))


def _lower_triangle(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices below the diagonal of an (n, n) matrix (cached: NumPy builds them slowly)."""
    hit = _LOWER.get(n)
    if hit is None:
        hit = _LOWER[n] = np.tril_indices(n, -1)
    return hit


_Bounds = tuple[np.ndarray, np.ndarray]


def _bounds(model: pin.Model, chain: _Chain) -> _Bounds:
    """Position limits of the free joints [rad or m]."""
    return model.lowerPositionLimit[chain.free], model.upperPositionLimit[chain.free]


def _starts(model: pin.Model, chain: _Chain, guess: np.ndarray) -> list[np.ndarray]:
    """Starts of the maximum-reach search: the guess, the neutral pose, and seeded poses."""
    lo, hi = _bounds(model, chain)
    finite = np.isfinite(lo) & np.isfinite(hi)
    mid = np.where(finite, 0.5 * (np.where(finite, lo, 0.0) + np.where(finite, hi, 0.0)), 0.0)
    half = np.where(finite, np.minimum(0.5 * (hi - lo), START_HALF_RANGE), START_HALF_RANGE)
    rng = np.random.default_rng(START_SEED)
    starts = [guess[chain.free], np.clip(pin.neutral(model)[chain.free], lo, hi)]
    starts += [mid + half * rng.uniform(-1.0, 1.0, len(mid)) for _ in range(EXTRA_STARTS)]
    return starts


def _slsqp(
    fun: Callable[[np.ndarray], tuple[float, np.ndarray]],
    constraints: list[dict[str, Any]],
    x0: np.ndarray,
    bounds: _Bounds,
    ftol: float,
) -> np.ndarray:
    """SLSQP from ``x0`` with an objective returning (value, gradient); its last iterate.

    The iterate is returned even when SLSQP stops short: the caller polishes it and keeps it
    only if it meets the constraints.
    """
    result = minimize(
        fun,
        x0,
        jac=True,
        method="SLSQP",
        bounds=list(zip(bounds[0], bounds[1], strict=True)),
        constraints=constraints,
        options={"ftol": ftol, "maxiter": SLSQP_MAXITER},
    )
    return np.clip(np.asarray(result.x, dtype=float), bounds[0], bounds[1])


@dataclass(frozen=True, eq=False)
class _Reach:
    """A maximum reach and the poses found that reach it.

    Attributes:
        R: The maximum reach [m].
        poses: Free-joint values [rad or m] of the maximizers found, those within 1e-9 m of R
            (one per start that found the maximum).
    """

    R: float
    poses: tuple[np.ndarray, ...]


def _offset(data: pin.Data, chain: _Chain) -> tuple[float, np.ndarray]:
    """The tool origin's offset from joint 1's origin, the frame placed in ``data``.

    Returns:
        Along joint 1's axis [m], and across it (radial) [m], shape (3,).
    """
    d = data.oMf[chain.frame].translation - chain.point
    along = float(chain.axis @ d)
    return along, d - along * chain.axis


def _reach_and_column(
    model: pin.Model, chain: _Chain, q: np.ndarray, data: pin.Data, i: int
) -> tuple[float, np.ndarray]:
    """r(q) [m] and column ``i`` of the tool's world-aligned linear Jacobian at q, (3,).

    What an :class:`_Evaluator` at q gives (its :meth:`~_Evaluator.reach` and ``J[:, i]``),
    the same products, without what only the pose problems read.
    """
    J6 = pin.computeFrameJacobian(model, data, q, chain.frame, _LWA)
    return float(np.linalg.norm(_offset(data, chain)[1])), np.asarray(J6[:3, i]).copy()


def _max_reach(model: pin.Model, chain: _Chain, guess: np.ndarray) -> _Reach:
    """R [m] and the poses of the free joints that reach it (cached).

    Raises:
        ConditionsError: No start reaches the plane, or R is nil (key "extension").
    """
    key = (chain.key, guess[chain.free].tobytes())
    hit = _recall(_REACH_CACHE, key)
    if hit is not None:
        return hit
    ev = _Evaluator(model, chain, guess)
    bounds = _bounds(model, chain)

    def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
        ev.at(x)
        return -0.5 * ev.r**2, -ev.r * ev.dr

    name = model.frames[chain.frame].name
    if not len(chain.free):
        raise ConditionsError(
            "extension",
            f"no joint but joint 1 moves the tool frame '{name}': it cannot be posed",
        )
    plane = [{"type": "eq", "fun": lambda x: ev.at(x).h, "jac": lambda x: ev.at(x).dh}]
    found: list[tuple[float, np.ndarray]] = []
    for x0 in _starts(model, chain, guess):
        x = ev.polish(_slsqp(fun, plane, x0, bounds, REACH_FTOL), None, bounds)
        if ev.residual(None) <= RESIDUAL_TOL:
            found.append((ev.r, x))
    if not found:
        raise ConditionsError(
            "extension",
            f"the tool frame '{name}' cannot be posed horizontally (in the plane through the "
            "second moving joint, perpendicular to the joint-1 axis) within the position limits",
        )
    R = max(r for r, _ in found)
    if R < MIN_REACH:
        raise ConditionsError(
            "extension",
            f"the tool frame '{name}' cannot leave the joint-1 axis (maximum reach {R:.3g} m): "
            f"extension needs a reach > {MIN_REACH:g} m",
        )
    reach = _Reach(R, tuple(x for r, x in found if r >= R - RESIDUAL_TOL))
    _remember(_REACH_CACHE, key, reach, REACH_CACHE_SIZE)
    return reach


def _extension_pose(model: pin.Model, chain: _Chain, e: float, guess: np.ndarray) -> np.ndarray:
    """:func:`extension_pose` of a clipped guess (cached per chain, extension and guess)."""
    key = (chain.key, e, guess.tobytes())
    hit = _recall(_POSE_CACHE, key)
    if hit is None:
        hit = _solve_extension(model, chain, e, guess)
        _remember(_POSE_CACHE, key, hit, POSE_CACHE_SIZE)
    return hit.copy()


def _solve_extension(model: pin.Model, chain: _Chain, e: float, guess: np.ndarray) -> np.ndarray:
    """The pose at reach e R in the plane nearest to ``guess`` [rad or m], shape (nq,).

    For e < 1, Newton's method on the KKT system of the problem (:func:`_newton`) first,
    from the guess: its pose is taken when it converges to a regular local minimum along a
    path within the position limits (every case of the shipped UR studies; a few times
    cheaper than SLSQP). Like SLSQP it finds a local minimum: where several lie about a guess
    far from every pose at r = e R (e.g. a guess near a stretched arm), it may end in another
    one than the SLSQP path below would take (nearer or farther). Newton does not start from
    the maximizer of r: there dr and dh are parallel and its KKT matrix is singular.
    Otherwise SLSQP minimizes the distance to the guess, from the guess and from the
    maximizer of r found nearest to it (a pose at r = R in the plane: a warm start for large
    e); if neither meets the constraints (near the smallest reach of a folded arm), bounded
    least squares finds a pose that does from the starts of the maximum-reach search in
    turn, and SLSQP moves it towards the guess. The nearest pose that meets the constraints
    is taken.

    At e = 1 the gradients of r and of the plane are parallel at the solutions, where the
    equality r = R stalls SLSQP: it keeps r >= R - 0.5e-9 m instead (r <= R in the plane), from
    the maximizer nearest to the guess.

    Raises:
        ConditionsError: No start meets the constraints to 1e-9 m (key "extension").
    """
    reach = _max_reach(model, chain, guess)
    target = e * reach.R
    ev = _Evaluator(model, chain, guess)
    bounds = _bounds(model, chain)
    g = guess[chain.free]
    if e < 1.0:
        x = _newton(ev, g, target, bounds)
        if x is not None:
            return _pose(guess, chain, x)
    nearest_max = min(reach.poses, key=lambda x: float(np.linalg.norm(x - g)))

    def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
        return 0.5 * float((x - g) @ (x - g)), x - g

    plane = {"type": "eq", "fun": lambda x: ev.at(x).h, "jac": lambda x: ev.at(x).dh}
    if e == 1.0:
        # r <= R in the plane: r >= R - tol keeps SLSQP on the maximizers, along which it
        # moves the nearest one found towards the guess (the wrist rolls of a straight arm).
        floor = target - 0.5 * RESIDUAL_TOL
        at_max = {"type": "ineq", "fun": lambda x: ev.at(x).r - floor, "jac": lambda x: ev.at(x).dr}
        moved = ev.polish(
            _slsqp(fun, [at_max, plane], nearest_max, bounds, POSE_FTOL), None, bounds
        )
        return _pose(guess, chain, _nearest(ev, [nearest_max, moved], g, target, e, reach.R))

    reach_row = {"type": "eq", "fun": lambda x: ev.at(x).r - target, "jac": lambda x: ev.at(x).dr}
    cons = [reach_row, plane]
    candidates = [
        ev.polish(_slsqp(fun, cons, x0, bounds, POSE_FTOL), target, bounds)
        for x0 in (g, nearest_max)
    ]
    if not any(_meets(ev, x, target) for x in candidates):
        # Near a limit of the reach (a folded arm) SLSQP may not find the constraints from
        # the warm starts: find them first by bounded least squares, from the guess, the
        # neutral configuration and the seeded starts in turn; SLSQP then moves the first
        # pose found towards the guess.
        for x0 in _starts(model, chain, guess):
            x = _feasible(ev, x0, target, bounds)
            if _meets(ev, x, target):
                moved = ev.polish(_slsqp(fun, cons, x, bounds, POSE_FTOL), target, bounds)
                candidates += [x, moved]
                break
    return _pose(guess, chain, _nearest(ev, candidates, g, target, e, reach.R))


def _newton(ev: _Evaluator, g: np.ndarray, target: float, bounds: _Bounds) -> np.ndarray | None:
    """The pose nearest to ``g`` on r = ``target``, h = 0, by Newton on the KKT system; or None.

    Minimizes |x - g|^2 / 2 subject to c(x) = (r - target, h) = 0 by Newton's method on the
    KKT system (x - g) + J_c^T lambda = 0, c(x) = 0, J_c = (dr; dh), with the Lagrangian's
    Hessian I + lambda_r d2r + lambda_h d2h (:meth:`_Evaluator.lagrangian_hessian`, exact: the
    convergence is quadratic), from the guess with lambda = 0 (the first step is the
    minimum-norm step onto the linearized constraints, as SLSQP's). A step that moves a joint by
    more than :data:`NEWTON_MAX_STEP` is shortened, then halved until the KKT residual's norm
    falls. It stops once |c| <= :data:`NEWTON_CTOL` and the stationarity residual is
    <= :data:`KKT_TOL`. The position limits are not constraints of this problem: an iterate
    beyond one ends the search, so the pose returned is an interior local minimum of the
    bounded problem, reached by a path within the limits.

    Returns:
        The free-joint values [rad or m], or None (then SLSQP decides) when Newton does not
        converge within :data:`NEWTON_MAXITER` iterations, when a step leaves the position
        limits (the nearest pose may need an active limit), when the line search fails, or
        when the point found is not a regular local minimum (dependent constraint gradients,
        or a reduced Hessian that is not positive definite: a saddle or a farthest pose).
    """
    n = len(g)
    if n < 2:
        return None  # two constraints need two free joints to be regular
    K = np.zeros((n + 2, n + 2))  # the KKT matrix [[H, J_c^T], [J_c, 0]]

    def kkt(x: np.ndarray, lam: np.ndarray) -> tuple[np.ndarray, float]:
        ev.at(x)
        K[n, :n], K[n + 1, :n] = ev.dr, ev.dh
        F = np.concatenate([(x - g) + K[n:, :n].T @ lam, [ev.r - target, ev.h]])
        return F, math.sqrt(float(F @ F))

    x, lam = g.copy(), np.zeros(2)  # at the guess the multipliers are nil
    F, norm = kkt(x, lam)
    for _ in range(NEWTON_MAXITER):
        if max(abs(F[n]), abs(F[n + 1])) <= NEWTON_CTOL and np.max(np.abs(F[:n])) <= KKT_TOL:
            return x if _regular_minimum(ev, x, lam) else None
        K[:n, :n] = ev.lagrangian_hessian(lam)
        K[:n, n:] = K[n:, :n].T
        try:
            step = np.linalg.solve(K, -F)
        except np.linalg.LinAlgError:
            return None
        alpha = min(1.0, NEWTON_MAX_STEP / max(float(np.max(np.abs(step[:n]))), _TINY))
        for _ in range(NEWTON_HALVINGS):
            F_new, norm_new = kkt(x + alpha * step[:n], lam + alpha * step[n:])
            if norm_new <= (1.0 - 1e-4 * alpha) * norm:
                break
            alpha *= 0.5
        else:
            return None
        x, lam, F, norm = x + alpha * step[:n], lam + alpha * step[n:], F_new, norm_new
        if np.any(x < bounds[0]) or np.any(x > bounds[1]):
            return None  # a path through a limit: the bounded search may end elsewhere
    return None


def _regular_minimum(ev: _Evaluator, x: np.ndarray, lam: np.ndarray) -> bool:
    """Whether a KKT point ``x`` with multipliers ``lam`` is a regular local minimum.

    Regular: the constraint gradients dr, dh are independent (singular-value ratio above
    :data:`NEWTON_REGULAR`); a minimum: the Lagrangian's Hessian is positive definite on their
    null space (smallest eigenvalue above :data:`NEWTON_REGULAR`), the second-order
    sufficient condition.
    """
    ev.at(x)
    Jc = np.array([ev.dr, ev.dh])
    _, sv, Vt = np.linalg.svd(Jc)
    if sv[-1] <= NEWTON_REGULAR * sv[0]:
        return False
    Z = Vt[len(sv) :].T  # a basis of the constraints' tangent space
    H = ev.lagrangian_hessian(lam)
    return Z.shape[1] == 0 or float(np.linalg.eigvalsh(Z.T @ H @ Z)[0]) > NEWTON_REGULAR


def _feasible(ev: _Evaluator, x0: np.ndarray, target: float, bounds: _Bounds) -> np.ndarray:
    """A pose near ``x0`` with r = ``target`` in the plane, by bounded least squares."""

    def residuals(x: np.ndarray) -> np.ndarray:
        ev.at(x)
        return np.array([ev.r - target, ev.h])

    def jacobian(x: np.ndarray) -> np.ndarray:
        ev.at(x)
        return np.array([ev.dr, ev.dh])

    lo, hi = bounds
    # least_squares needs a start strictly inside finite bounds.
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    x0 = np.clip(x0, lo + 1e-9 * span, hi - 1e-9 * span)
    result = least_squares(
        residuals,
        x0,
        jac=jacobian,
        bounds=bounds,
        method="trf",
        xtol=1e-15,
        ftol=1e-15,
        gtol=1e-15,
        max_nfev=LSQ_MAX_NFEV,
    )
    return ev.polish(np.clip(result.x, lo, hi), target, bounds)


def _meets(ev: _Evaluator, x: np.ndarray, target: float) -> bool:
    """Whether free-joint values ``x`` meet the constraints to 1e-9 m."""
    return ev.at(x).residual(target) <= RESIDUAL_TOL


def _nearest(
    ev: _Evaluator,
    candidates: list[np.ndarray],
    g: np.ndarray,
    target: float,
    e: float,
    R: float,
) -> np.ndarray:
    """The candidate nearest to ``g`` that meets the constraints, or ConditionsError."""
    good = [x for x in candidates if _meets(ev, x, target)]
    if not good:
        worst = min(ev.at(x).residual(target) for x in candidates)
        raise ConditionsError(
            "extension",
            f"the arm cannot be posed horizontally at {e:g} x the maximum reach {R:.4g} m "
            f"(best constraint residual {worst:.3g} m, allowed {RESIDUAL_TOL:g} m); "
            "try another initial pose, or an extension in (0, 1]",
        )
    return min(good, key=lambda x: float(np.linalg.norm(x - g)))


def _pose(guess: np.ndarray, chain: _Chain, x: np.ndarray) -> np.ndarray:
    """The guess with its free joints set to ``x`` [rad or m]."""
    q = guess.copy()
    q[chain.free] = x
    return q


def _recall(cache: OrderedDict[Any, Any], key: Any) -> Any:
    """The entry ``key`` of an LRU cache (marked as recently used), or None."""
    try:
        cache.move_to_end(key)
        return cache[key]
    except KeyError:  # absent, or evicted by another thread meanwhile
        return None


def _remember(cache: OrderedDict[Any, Any], key: Any, value: Any, size: int) -> None:
    """Store ``value`` in an LRU cache of ``size`` entries."""
    cache[key] = value
    cache.move_to_end(key)
    while len(cache) > size:
        cache.popitem(last=False)


#: Smallest positive float: the floor of a column norm in the vertical test.
_TINY = float(np.finfo(float).tiny)
#: [m] A polish stops once every residual is below this (round-off of a 1 m arm).
_POLISHED = 1.0e-14
_CHAIN_CACHE: OrderedDict[tuple[Any, ...], _Chain] = OrderedDict()
_REACH_CACHE: OrderedDict[tuple[Any, ...], _Reach] = OrderedDict()
_POSE_CACHE: OrderedDict[tuple[Any, ...], np.ndarray] = OrderedDict()
_LOWER: dict[int, tuple[np.ndarray, np.ndarray]] = {}
