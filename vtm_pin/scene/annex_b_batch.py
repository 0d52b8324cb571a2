"""Annex-B extension poses of many cases at once: Newton's method over the lanes.

A study varies the extension e of one scenario: its cases share the robot's kinematics, the
tool frame and the guess pose, and differ in the reach asked for, r = e R. Case by case,
:func:`vtm_pin.scene.annex_b.compute_test_state` solves each pose by Newton's method on the
KKT system of the pose problem (``annex_b._newton``, with Pinocchio's frame Jacobian at each
iterate): ~1.2 ms a UR10 case, more than half of a study case's build. :func:`solve_poses`
takes the same iteration for all the extensions at once, as array operations over the lanes,
with the joints' placements from NumPy (:func:`vtm_pin.physics.kinematics.joint_placements`'s
arithmetic) in place of Pinocchio's, and keeps each pose it finds in Annex B's pose cache, where
the cases' builds find it.

The iteration is ``_newton``'s, lane by lane: the same start (the guess, nil multipliers), the
same exact Hessian of the Lagrangian, step limit, line search, stopping tests, the same test
of a regular local minimum, and the same refusals (a step out of the limits, a failed line
search, no convergence). A lane refused is not cached: its case's build solves it on its own
(Newton again, then SLSQP). The poses agree with ``_newton``'s to round-off
(``tests/test_annex_b_batch.py``); a case's figures therefore do not depend on whether its pose
was solved with others or alone, beyond round-off. A stopping time can amplify that round-off to
~1e-8 s at rtol 1e-8 (a step accepted or rejected; ``tests/test_batch.py``,
``STOP_TIME_TOLERANCE``). The iteration is not used for a single case: one lane's NumPy
operations cost more than Pinocchio's Newton (the scalar engine's build in
``benchmarks/batched_study.py``, which sends one case at a time: 9.1 ms a case with this
iteration for one lane, 3.2 ms with Pinocchio's Newton, two runs within the hour).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from ..physics.kinematics import JointChain, joint_chain, joint_placements
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

    def __init__(self, robot: Robot, chain: ab._Chain, joints: JointChain, guess: np.ndarray):
        self.robot, self.chain, self.joints, self.guess = robot, chain, joints, guess
        model = robot.model
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
        R, p = joint_placements(self.robot, qs)  # (B, njoints, 3, 3), (B, njoints, 3)
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
    """``annex_b._Evaluator.lagrangian_hessian`` at every lane, shape (B, n, n)."""
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
    lower = ab._lower_triangle(n)
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
    """``annex_b._regular_minimum`` at every lane, shape (B,) bool."""
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
    """``annex_b._newton`` for each target reach [m] at once: free-joint values or None."""
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
    joints = joint_chain(model)
    chain = ab._chain(model, tool_frame)
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
    lanes = _Lanes(robot, chain, joints, guess)
    poses = newton_many(lanes, guess[chain.free], es * reach.R, ab._bounds(model, chain))
    solved = 0
    for e, x in zip(wanted, poses, strict=True):
        if x is not None:
            key = (chain.key, e, guess.tobytes())
            ab._remember(ab._POSE_CACHE, key, ab._pose(guess, chain, x), ab.POSE_CACHE_SIZE)
            solved += 1
    return solved
