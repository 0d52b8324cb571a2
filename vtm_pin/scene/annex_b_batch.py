"""Annex-B extension poses by Newton's method on the KKT system, over many cases at once.

The pose at reach r = e R nearest to a guess g (:mod:`vtm_pin.scene.annex_b`) minimizes
|x - g|^2 / 2 subject to r(x) = e R and h(x) = 0 (the plane). :func:`newton_many` solves it by
Newton's method on its KKT system for many targets at once, as array operations over the
lanes, with the joints' placements from NumPy
(:func:`vtm_pin.physics.kinematics.numpy_placements`). A study's cases share the kinematics, the
tool frame and the guess and differ in e: :func:`solve_poses` solves them together and keeps
each pose in Annex B's pose cache, where the cases' builds find it (~0.3 against ~1.3 ms a UR10
pose one by one). A single case takes the same iteration for one lane
(:func:`newton_alone`): a lane's arithmetic does not depend on the other lanes, so a case's pose
is the same to the bit whether it was solved alone or in a study, with either engine
(``tests/test_annex_b_batch.py``).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pinocchio as pin

from ..physics.kinematics import JointChain, joint_chain, numpy_placements
from ..physics.robot import Robot
from . import annex_b as ab


@dataclass(frozen=True)
class _State:
    """The pose problem's functions at each lane's iterate (see ``annex_b._Evaluator``).

    Attributes:
        r: Horizontal reach [m], shape (B,).
        h: Offset from the plane [m], shape (B,).
        dr: Gradient of r over the free joints, shape (B, n).
        dh: Gradient of h, shape (B, n).
        radial: The tool origin's radial offset from the joint-1 axis [m], shape (B, 3).
        J6: The tool frame's world-aligned Jacobian over the free joints (linear, angular),
            shape (B, 6, n).
    """

    r: np.ndarray
    h: np.ndarray
    dr: np.ndarray
    dh: np.ndarray
    radial: np.ndarray
    J6: np.ndarray

    def take(self, rows: np.ndarray) -> _State:
        """The lanes ``rows`` only."""
        return _State(*(x[rows] for x in (self.r, self.h, self.dr, self.dh, self.radial, self.J6)))

    def put(self, rows: np.ndarray, other: _State) -> None:
        """Set the lanes ``rows`` to ``other``'s."""
        for mine, theirs in zip(
            (self.r, self.h, self.dr, self.dh, self.radial, self.J6),
            (other.r, other.h, other.dr, other.dh, other.radial, other.J6),
            strict=True,
        ):
            mine[rows] = theirs


class _Lanes:
    """r, h and their gradients at many free-joint values, by NumPy kinematics."""

    def __init__(self, model: pin.Model, chain: ab._Chain, joints: JointChain, guess: np.ndarray):
        self.chain, self.joints, self.guess = chain, joints, guess
        frame = model.frames[chain.frame]
        self.parent = int(frame.parentJoint)
        self.offset = np.asarray(frame.placement.translation, dtype=float)
        # The joint of each free velocity index (every joint has one coordinate here).
        by_index = {k: j for j, k in enumerate(joints.index) if j > 0}
        self.free_joints = [by_index[int(k)] for k in chain.free]
        self.plane_height = ab._Evaluator(model, chain, guess).plane_height

    def at(self, X: np.ndarray) -> _State:
        """The functions at free-joint values ``X`` [rad or m], shape (B, n)."""
        chain = self.chain
        qs = np.repeat(self.guess[None, :], len(X), axis=0)
        qs[:, chain.free] = X
        R, p = numpy_placements(self.joints, qs)  # (B, njoints, 3, 3), (B, njoints, 3)
        tool = p[:, self.parent] + R[:, self.parent] @ self.offset
        J6 = np.zeros((len(X), 6, len(chain.free)))
        for c, j in enumerate(self.free_joints):
            w = R[:, j] @ self.joints.axes[j]  # the joint's axis in the world
            if self.joints.revolute[j]:
                J6[:, :3, c] = np.cross(w, tool - p[:, j])
                J6[:, 3:, c] = w
            else:
                J6[:, :3, c] = w
        d = tool - chain.point
        along = d @ chain.axis
        radial = d - along[:, None] * chain.axis
        r = np.linalg.norm(radial, axis=1)
        safe = np.where(r > 0.0, r, 1.0)
        dr = np.einsum("bi,bik->bk", radial / safe[:, None], J6[:, :3])
        dr[r <= 0.0] = 0.0
        dh = np.einsum("i,bik->bk", chain.axis, J6[:, :3])
        return _State(r, along - self.plane_height, dr, dh, radial, J6)


def _hessian(s: _State, lam: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The Lagrangian's Hessian I + lam[0] d2r + lam[1] d2h at every lane, shape (B, n, n).

    The Hessian of |x - g|^2 / 2 + lam . (r - target, h), in closed form from the frame
    Jacobian's columns (no other kinematics): the free joints are a chain in velocity order
    (all carry the tool frame), so with w_k the angular and v_k the linear column of joint k
    (w_k = 0 for a prismatic joint), the tool origin p has d2p/dq_i dq_j = w_min(i,j) x
    v_max(i,j): turning an inner joint turns the outer one's column with it; moving an outer
    joint moves p about the inner axis. With a the joint-1 axis, u the unit radial direction
    and P = I - a a^T: d2h = a . d2p and d2r = u . d2p + ((P V)^T (P V) - dr dr^T) / r; the
    two projections of d2p are one, along lam[0] u + lam[1] a.
    """
    V, W = s.J6[:, :3], s.J6[:, 3:]
    count, n = len(lam), V.shape[2]
    positive = s.r > 0.0
    safe = np.where(positive, s.r, 1.0)
    scale = np.where(positive, lam[:, 0] / safe, 0.0)
    k = lam[:, 1:2] * axis + scale[:, None] * s.radial
    PV = V - axis[None, :, None] * np.einsum("i,bik->bk", axis, V)[:, None, :]
    H = np.broadcast_to(np.eye(n), (count, n, n)) + scale[:, None, None] * (
        PV.transpose(0, 2, 1) @ PV - s.dr[:, :, None] * s.dr[:, None, :]
    )
    M = np.cross(k[:, :, None], W, axis=1).transpose(0, 2, 1) @ V  # (k x w_i) . v_j
    lower = _lower_triangle(n)
    M[:, lower[0], lower[1]] = M[:, lower[1], lower[0]]
    return H + M


def _residual(
    s: _State, X: np.ndarray, lam: np.ndarray, g: np.ndarray, targets: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The KKT residual F = ((x - g) + J_c^T lam, r - target, h) and its norm, per lane."""
    F = np.concatenate(
        [
            (X - g) + s.dr * lam[:, :1] + s.dh * lam[:, 1:],
            (s.r - targets)[:, None],
            s.h[:, None],
        ],
        axis=1,
    )
    return F, np.sqrt(np.einsum("bi,bi->b", F, F))


def _regular(s: _State, lam: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Whether each lane's KKT point is a regular local minimum, shape (B,) bool.

    Regular: the constraint gradients dr, dh are independent (singular-value ratio above
    ``NEWTON_REGULAR``); a minimum: the Lagrangian's Hessian is positive definite on their
    null space (smallest eigenvalue above ``NEWTON_REGULAR``), the second-order sufficient
    condition.
    """
    Jc = np.stack([s.dr, s.dh], axis=1)
    _, sv, Vt = np.linalg.svd(Jc)
    independent = sv[:, -1] > ab.NEWTON_REGULAR * sv[:, 0]
    Z = Vt[:, 2:].transpose(0, 2, 1)  # bases of the constraints' tangent spaces
    if Z.shape[2] == 0:
        return independent
    reduced = Z.transpose(0, 2, 1) @ _hessian(s, lam, axis) @ Z
    return independent & (np.linalg.eigvalsh(reduced)[:, 0] > ab.NEWTON_REGULAR)


def _solve(K: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The Newton steps -K^-1 F per lane, and which lanes' K were not singular."""
    try:
        return np.linalg.solve(K, -F[:, :, None])[:, :, 0], np.ones(len(K), dtype=bool)
    except np.linalg.LinAlgError:  # rare: lane by lane, to know which
        steps, ok = np.zeros_like(F), np.ones(len(K), dtype=bool)
        for b in range(len(K)):
            try:
                steps[b] = np.linalg.solve(K[b], -F[b])
            except np.linalg.LinAlgError:
                ok[b] = False
        return steps, ok


@dataclass
class _Iterates:
    """The lanes still iterating: their indices, iterates, multipliers, residuals, functions."""

    lanes: np.ndarray
    X: np.ndarray
    lam: np.ndarray
    F: np.ndarray
    norm: np.ndarray
    s: _State

    def keep(self, mask: np.ndarray) -> None:
        """Keep the lanes of ``mask`` only."""
        self.lanes, self.X, self.lam = self.lanes[mask], self.X[mask], self.lam[mask]
        self.F, self.norm, self.s = self.F[mask], self.norm[mask], self.s.take(mask)


def newton_many(
    lanes: _Lanes, g: np.ndarray, targets: np.ndarray, bounds: ab._Bounds
) -> list[np.ndarray | None]:
    """The pose nearest to ``g`` on r = target, h = 0 for each target [m], or None.

    Minimizes |x - g|^2 / 2 subject to c(x) = (r - target, h) = 0 by Newton's method on the
    KKT system (x - g) + J_c^T lambda = 0, c(x) = 0, J_c = (dr; dh), with the Lagrangian's
    exact Hessian (:func:`_hessian`: the convergence is quadratic), from the guess with
    lambda = 0 (the first step is the minimum-norm step onto the linearized constraints, as
    SLSQP's). A step that moves a joint by more than ``NEWTON_MAX_STEP`` is shortened, then
    halved until the KKT residual's norm falls. A lane stops once |c| <= ``NEWTON_CTOL`` and
    the stationarity residual is <= ``KKT_TOL``. The position limits are not constraints of
    this problem: an iterate beyond one ends the lane's search, so a pose returned is an
    interior local minimum of the bounded problem, reached by a path within the limits.
    Lanes that are done leave the iteration; each lane's arithmetic is its own.

    Returns:
        Per target, the free-joint values [rad or m], or None (then SLSQP decides) when Newton
        does not converge within ``NEWTON_MAXITER`` iterations, when a step leaves the position
        limits (the nearest pose may need an active limit), when the line search fails, or
        when the point found is not a regular local minimum (dependent constraint gradients,
        or a reduced Hessian that is not positive definite: a saddle or a farthest pose).
    """
    n, axis = len(g), lanes.chain.axis
    out: list[np.ndarray | None] = [None] * len(targets)
    X = np.repeat(g[None, :], len(targets), axis=0)
    lam = np.zeros((len(targets), 2))
    s = lanes.at(X)
    F, norm = _residual(s, X, lam, g, targets)
    it = _Iterates(np.arange(len(targets)), X, lam, F, norm, s)
    for _ in range(ab.NEWTON_MAXITER):
        done = (np.abs(it.F[:, n:]).max(axis=1) <= ab.NEWTON_CTOL) & (
            np.abs(it.F[:, :n]).max(axis=1) <= ab.KKT_TOL
        )
        if done.any():
            regular = _regular(it.s.take(done), it.lam[done], axis)
            for b, x, ok in zip(it.lanes[done], it.X[done], regular, strict=True):
                out[b] = x.copy() if ok else None
            it.keep(~done)
        if it.lanes.size == 0:
            break
        _step(lanes, it, g, targets[it.lanes], bounds)
    return out


def _step(
    lanes: _Lanes, it: _Iterates, g: np.ndarray, targets: np.ndarray, bounds: ab._Bounds
) -> None:
    """One Newton step of every lane in ``it``, with its line search; drops refused lanes."""
    n = len(g)
    K = np.zeros((it.lanes.size, n + 2, n + 2))
    K[:, :n, :n] = _hessian(it.s, it.lam, lanes.chain.axis)
    K[:, n, :n], K[:, n + 1, :n] = it.s.dr, it.s.dh
    K[:, :n, n:] = K[:, n:, :n].transpose(0, 2, 1)
    step, ok = _solve(K, it.F)
    largest = np.maximum(np.abs(step[:, :n]).max(axis=1), ab._TINY)
    alpha = np.minimum(1.0, ab.NEWTON_MAX_STEP / largest)
    pending = np.flatnonzero(ok)
    accepted = np.zeros(it.lanes.size, dtype=bool)
    X, lam, F, norm = it.X.copy(), it.lam.copy(), it.F.copy(), it.norm.copy()
    s = it.s.take(np.arange(it.lanes.size))  # a copy, updated lane by lane
    for _ in range(ab.NEWTON_HALVINGS):
        a = alpha[pending, None]
        X_new, lam_new = (
            it.X[pending] + a * step[pending, :n],
            it.lam[pending] + a * step[pending, n:],
        )
        s_new = lanes.at(X_new)
        F_new, norm_new = _residual(s_new, X_new, lam_new, g, targets[pending])
        better = norm_new <= (1.0 - 1e-4 * alpha[pending]) * it.norm[pending]
        rows = pending[better]
        X[rows], lam[rows], F[rows], norm[rows] = (
            X_new[better],
            lam_new[better],
            F_new[better],
            norm_new[better],
        )
        s.put(rows, s_new.take(better))
        accepted[rows] = True
        pending = pending[~better]
        if pending.size == 0:
            break
        alpha[pending] *= 0.5
    inside = np.all((X >= bounds[0]) & (X <= bounds[1]), axis=1)
    it.X, it.lam, it.F, it.norm, it.s = X, lam, F, norm, s
    it.keep(accepted & inside)


def newton_alone(
    model: pin.Model, chain: ab._Chain, guess: np.ndarray, target: float, bounds: ab._Bounds
) -> np.ndarray | None:
    """:func:`newton_many` for one target reach [m]: the free-joint values, or None."""
    joints = _joints(model, chain)
    if joints is None or len(chain.free) < 2:
        return None  # two constraints need two free joints to be regular
    lanes = _Lanes(model, chain, joints, guess)
    return newton_many(lanes, guess[chain.free], np.array([target]), bounds)[0]


def solve_poses(
    robot: Robot, tool_frame: str, q_guess: np.ndarray, extensions: Iterable[float]
) -> int:
    """Solve the extension poses of one robot, tool frame and guess at once, for the cache.

    Each extension e < 1 whose pose is not yet in Annex B's pose cache is solved by Newton's
    method over the lanes (:func:`newton_many`); each pose found is kept in the cache under
    the key its case's :func:`~vtm_pin.scene.annex_b.compute_test_state` looks up, so that
    the case finds it there. Poses Newton refuses, and e = 1, are left to the cases.

    Args:
        robot: The robot (its kinematics; a payload does not change them).
        tool_frame: The frame whose reach is posed.
        q_guess: The guess pose [rad or m], shape (nq,) (the scenario's initial q).
        extensions: The extensions e asked for [-].

    Returns:
        The number of poses solved and cached.

    Raises:
        ConditionsError: The pose problem cannot be set up (the frame, the chain or the
            maximum reach; the cases' builds report the same).
    """
    model = robot.model
    chain = ab._chain(model, tool_frame)
    joints = _joints(model, chain)
    guess = ab._clip(model, ab._as_q(model, q_guess))
    wanted = sorted(
        {
            float(e)
            for e in extensions
            if 0.0 < float(e) < 1.0 and (chain.key, float(e), guess.tobytes()) not in ab._POSE_CACHE
        }
    )[: ab.POSE_CACHE_SIZE]
    if joints is None or len(chain.free) < 2 or not wanted:
        return 0
    reach = ab._max_reach(model, chain, guess)
    es = np.array(wanted)
    lanes = _Lanes(model, chain, joints, guess)
    poses = newton_many(lanes, guess[chain.free], es * reach.R, ab._bounds(model, chain))
    solved = 0
    for e, x in zip(wanted, poses, strict=True):
        if x is not None:
            key = (chain.key, e, guess.tobytes())
            ab._remember(ab._POSE_CACHE, key, ab._pose(guess, chain, x), ab.POSE_CACHE_SIZE)
            solved += 1
    return solved


def _joints(model: pin.Model, chain: ab._Chain) -> JointChain | None:
    """The model's joints as arrays (cached per kinematics), or None.

    None for a joint type NumPy does not compute: Newton is then not taken, SLSQP decides.
    """
    key = chain.key
    if key not in _JOINTS:
        ab._remember(_JOINTS, key, joint_chain(model), ab.REACH_CACHE_SIZE)
    return ab._recall(_JOINTS, key)


def _lower_triangle(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices below the diagonal of an (n, n) matrix (cached: NumPy builds them slowly)."""
    hit = _LOWER.get(n)
    if hit is None:
        hit = _LOWER[n] = np.tril_indices(n, -1)
    return hit


_JOINTS: OrderedDict[tuple[Any, ...], JointChain | None] = OrderedDict()
_LOWER: dict[int, tuple[np.ndarray, np.ndarray]] = {}
