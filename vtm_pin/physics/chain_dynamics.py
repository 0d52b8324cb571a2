r"""Forward dynamics with locked joints over many states, each with its own bodies, compiled.

The batched engine evaluates, at every Runge-Kutta stage, the states of its lanes whose phase
has joints locked, or whose bodies' inertias (a payload's) differ from the batch's model. With
L the locked coordinates and f the free ones (v_L = 0, a_L = 0):

.. math:: M_{ff}\, a_f = \tau_f - b_f, \qquad \lambda_L = M_{Lf}\, a_f + b_L - \tau_L,

with b = RNEA(q, v, 0) (gravity included) and lambda the locks' holding torques (0 at free
joints). Its NumPy path (:class:`vtm_pin.core.batch._Dynamics`) gets M's free columns and b from
1 + k batched Pinocchio RNEA passes, adds a payload's terms through its body's Jacobian, and
solves with LAPACK: a few dozen array operations a call. This module computes the same, state
by state, compiled by Numba (the ``fast`` extra), in the world frame at the world's origin,
where a subtree's spatial inertia is the plain sum of its bodies':

- each joint's placement, motion subspace S_j, the bodies' velocities V_j and their
  accelerations C_j at a = 0 with gravity (C_0 = -g), as
  :mod:`~vtm_pin.physics.body_kernel` computes them;
- each body's spatial inertia in the world at the origin, from its mass m, first moment
  h = m c and rotational inertia I_o about its joint's origin (Pinocchio's dynamic
  parameters): h_w = R h + m p and I_O = R I_o R^T - [R h]x [p]x - [p]x [R h]x - m [p]x^2;
  it maps a motion (v, w) to the force (m v - h_w x w, h_w x v + I_O w);
- the composite inertia Ic_j of joint j's subtree: M_kj = S_k . (Ic_j S_j) for every k that
  carries j (plus the armature on the diagonal);
- the bodies' forces f_j = I_j C_j + V_j x* I_j V_j, summed over each subtree (F_j):
  b_j = S_j . F_j;
- M_ff a_f = tau_f - b_f by Cholesky (M_ff is positive definite; a pivot that is not
  positive gives NaN accelerations for that state alone, as a singular LAPACK solve does).

Exact up to round-off: agrees with Pinocchio's RNEA and CRBA to ~1e-15 relative
(``tests/test_chain_dynamics.py``). The per-body steps are written out in scalars, not as
products of small work arrays, whose views Numba keeps in memory: ~1.0-1.1 us a UR10 state
with locks against 1.7-1.9 us before (issue 27, one process; the same numbers, bit for bit).
Without Numba, or with ``NUMBA_DISABLE_JIT=1`` (:data:`AVAILABLE` False), the batched engine
keeps its NumPy path; so it does, after one warning, if Numba is installed but cannot import
or compile here (:func:`~vtm_pin.physics.body_kernel.fall_back`). The first call of a process
compiles the kernel (~9 s) unless Numba's cache beside this file holds it. Numba
checks only this file for changes: body_kernel's placement and motion helpers are compiled
into the cached kernel, so after editing them alone, delete ``__pycache__/chain_dynamics*.nb*``
(a new install replaces both files and so renews the cache).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from . import body_kernel

#: Whether the compiled kernel may run (as :data:`vtm_pin.physics.body_kernel.AVAILABLE`).
AVAILABLE = body_kernel.AVAILABLE


def runs() -> bool:
    """Whether the kernel runs: :data:`AVAILABLE`, and Numba has not failed here.

    (:func:`~vtm_pin.physics.body_kernel.fall_back` switches both kernels off for the process.)
    """
    return AVAILABLE and body_kernel.AVAILABLE


def locked_dynamics(
    chain: Any,
    qs: np.ndarray,
    vs: np.ndarray,
    taus: np.ndarray,
    locked: np.ndarray,
    parameters: np.ndarray,
    which: np.ndarray,
    armature: np.ndarray,
    gravity: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Accelerations and holding torques of states with locks, compiled (module docstring).

    Args:
        chain: The model's joints (:func:`~vtm_pin.physics.kinematics.joint_chain`).
        qs: Configurations [rad or m], shape (B, nq).
        vs: Rates [rad/s or m/s], shape (B, nv), exactly 0 at locked joints.
        taus: Applied torques [N m or N], shape (B, nv).
        locked: Lock masks, shape (B, nv).
        parameters: Bodies' dynamic parameters, Pinocchio's ``toDynamicParameters`` of each
            joint's body (m [kg], h = m c [kg m], I_o [kg m^2]: xx, xy, yy, xz, yz, zz about the
            joint's origin, in its frame), shape (P, njoints, 10).
        which: Each state's row of ``parameters``, shape (B,).
        armature: The model's armature [kg m^2], shape (nv,).
        gravity: The model's gravity as a spatial acceleration [m/s^2], shape (6,).

    Returns:
        ``(a, lam)``: accelerations [rad/s^2] (0 at locked joints) and holding torques [N m]
        (0 at free joints), shapes (B, nv).
    """
    count, nv = len(qs), vs.shape[1]
    a, lam = np.zeros((count, nv)), np.zeros((count, nv))
    _compiled()(
        *body_kernel.chain_arrays(chain),
        np.ascontiguousarray(qs, dtype=float),
        np.ascontiguousarray(vs, dtype=float),
        np.ascontiguousarray(taus, dtype=float),
        np.ascontiguousarray(locked, dtype=np.bool_),
        np.ascontiguousarray(parameters, dtype=float),
        np.ascontiguousarray(which, dtype=np.int64),
        np.ascontiguousarray(armature, dtype=float),
        np.ascontiguousarray(gravity, dtype=float),
        a,
        lam,
    )
    return a, lam


def _world_inertia(
    theta: np.ndarray, R: np.ndarray, p: np.ndarray, h: np.ndarray, inertia: np.ndarray
) -> float:
    """A body's first moment h [kg m] and inertia [kg m^2] about the world's origin; its mass.

    R I_o R^T - [R h]x [p]x - [p]x [R h]x - m [p]x^2, written out in scalars (as
    :func:`~vtm_pin.physics.body_kernel._place`), each sum in its matrix product's order.
    """
    m = theta[0]
    i00, i01, i11, i02, i12, i22 = theta[4], theta[5], theta[6], theta[7], theta[8], theta[9]
    r00, r01, r02 = R[0, 0], R[0, 1], R[0, 2]
    r10, r11, r12 = R[1, 0], R[1, 1], R[1, 2]
    r20, r21, r22 = R[2, 0], R[2, 1], R[2, 2]
    px, py, pz = p[0], p[1], p[2]
    rh0 = r00 * theta[1] + r01 * theta[2] + r02 * theta[3]  # R h
    rh1 = r10 * theta[1] + r11 * theta[2] + r12 * theta[3]
    rh2 = r20 * theta[1] + r21 * theta[2] + r22 * theta[3]
    h[0], h[1], h[2] = rh0 + m * px, rh1 + m * py, rh2 + m * pz
    t00 = r00 * i00 + r01 * i01 + r02 * i02  # T = R I_o
    t01 = r00 * i01 + r01 * i11 + r02 * i12
    t02 = r00 * i02 + r01 * i12 + r02 * i22
    t10 = r10 * i00 + r11 * i01 + r12 * i02
    t11 = r10 * i01 + r11 * i11 + r12 * i12
    t12 = r10 * i02 + r11 * i12 + r12 * i22
    t20 = r20 * i00 + r21 * i01 + r22 * i02
    t21 = r20 * i01 + r21 * i11 + r22 * i12
    t22 = r20 * i02 + r21 * i12 + r22 * i22
    d = 2.0 * (px * rh0 + py * rh1 + pz * rh2) + m * (px * px + py * py + pz * pz)
    inertia[0, 0] = (t00 * r00 + t01 * r01 + t02 * r02) + (-(rh0 * px + px * rh0) - m * px * px + d)
    inertia[0, 1] = (t00 * r10 + t01 * r11 + t02 * r12) + (-(rh1 * px + py * rh0) - m * px * py)
    inertia[0, 2] = (t00 * r20 + t01 * r21 + t02 * r22) + (-(rh2 * px + pz * rh0) - m * px * pz)
    inertia[1, 0] = (t10 * r00 + t11 * r01 + t12 * r02) + (-(rh0 * py + px * rh1) - m * py * px)
    inertia[1, 1] = (t10 * r10 + t11 * r11 + t12 * r12) + (-(rh1 * py + py * rh1) - m * py * py + d)
    inertia[1, 2] = (t10 * r20 + t11 * r21 + t12 * r22) + (-(rh2 * py + pz * rh1) - m * py * pz)
    inertia[2, 0] = (t20 * r00 + t21 * r01 + t22 * r02) + (-(rh0 * pz + px * rh2) - m * pz * px)
    inertia[2, 1] = (t20 * r10 + t21 * r11 + t22 * r12) + (-(rh1 * pz + py * rh2) - m * pz * py)
    inertia[2, 2] = (t20 * r20 + t21 * r21 + t22 * r22) + (-(rh2 * pz + pz * rh2) - m * pz * pz + d)
    return m


def _dot6(x: np.ndarray, y: np.ndarray) -> float:
    return x[0] * y[0] + x[1] * y[1] + x[2] * y[2] + x[3] * y[3] + x[4] * y[4] + x[5] * y[5]


def _apply(
    m: float, h: np.ndarray, inertia: np.ndarray, motion: np.ndarray, out: np.ndarray
) -> None:
    """The force (m v - h x w, h x v + I w) of inertia (m, h, I) on the motion (v, w)."""
    v0, v1, v2, w0, w1, w2 = motion[0], motion[1], motion[2], motion[3], motion[4], motion[5]
    h0, h1, h2 = h[0], h[1], h[2]
    out[0] = m * v0 - (h1 * w2 - h2 * w1)
    out[1] = m * v1 - (h2 * w0 - h0 * w2)
    out[2] = m * v2 - (h0 * w1 - h1 * w0)
    out[3] = (h1 * v2 - h2 * v1) + (inertia[0, 0] * w0 + inertia[0, 1] * w1 + inertia[0, 2] * w2)
    out[4] = (h2 * v0 - h0 * v2) + (inertia[1, 0] * w0 + inertia[1, 1] * w1 + inertia[1, 2] * w2)
    out[5] = (h0 * v1 - h1 * v0) + (inertia[2, 0] * w0 + inertia[2, 1] * w1 + inertia[2, 2] * w2)


def _force(
    m: float,
    h: np.ndarray,
    inertia: np.ndarray,
    V: np.ndarray,
    C: np.ndarray,
    out: np.ndarray,
    work: np.ndarray,
) -> None:
    """A body's force I C + V x* (I V): (w x f, w x n + v x f) for the momentum (f, n) = I V."""
    _apply(m, h, inertia, C, out)
    _apply(m, h, inertia, V, work)
    v0, v1, v2, w0, w1, w2 = V[0], V[1], V[2], V[3], V[4], V[5]
    f0, f1, f2, n0, n1, n2 = work[0], work[1], work[2], work[3], work[4], work[5]
    out[0] += w1 * f2 - w2 * f1
    out[1] += w2 * f0 - w0 * f2
    out[2] += w0 * f1 - w1 * f0
    out[3] += w1 * n2 - w2 * n1 + v1 * f2 - v2 * f1
    out[4] += w2 * n0 - w0 * n2 + v2 * f0 - v0 * f2
    out[5] += w0 * n1 - w1 * n0 + v0 * f1 - v1 * f0


def _cholesky(M: np.ndarray, free: np.ndarray, k: int, L: np.ndarray) -> None:
    """L L^T = M_ff of the first ``k`` indices ``free``; NaN from a pivot that is not positive."""
    for r in range(k):
        for c in range(r + 1):
            s = M[free[r], free[c]]
            for m in range(c):
                s -= L[r, m] * L[c, m]
            if r == c:
                L[r, r] = np.sqrt(s) if s > 0.0 else np.nan
            else:
                L[r, c] = s / L[c, c]


def _solve(
    M: np.ndarray,
    b: np.ndarray,
    tau: np.ndarray,
    locked: np.ndarray,
    a: np.ndarray,
    lam: np.ndarray,
    L: np.ndarray,
    free: np.ndarray,
    x: np.ndarray,
) -> None:
    """a_f from M_ff a_f = tau_f - b_f (Cholesky), a_L = 0; lam_L = M_Lf a_f + b_L - tau_L."""
    nv = b.size
    k = 0
    for i in range(nv):
        a[i] = 0.0
        lam[i] = 0.0
        if not locked[i]:
            free[k] = i
            k += 1
    _cholesky(M, free, k, L)
    for r in range(k):  # L y = tau_f - b_f, then L^T x = y
        s = tau[free[r]] - b[free[r]]
        for m in range(r):
            s -= L[r, m] * x[m]
        x[r] = s / L[r, r]
    for r in range(k - 1, -1, -1):
        s = x[r]
        for m in range(r + 1, k):
            s -= L[m, r] * x[m]
        x[r] = s / L[r, r]
        a[free[r]] = x[r]
    for i in range(nv):
        if locked[i]:
            s = b[i] - tau[i]
            for r in range(k):
                s += M[i, free[r]] * x[r]
            lam[i] = s


def _subtrees(
    parents: np.ndarray,
    index: np.ndarray,
    S: np.ndarray,
    F: np.ndarray,
    cm: np.ndarray,
    ch: np.ndarray,
    ci: np.ndarray,
    b: np.ndarray,
) -> None:
    """Sum forces and inertias over subtrees (parents come before children); b_j = S_j . F_j."""
    for j in range(parents.size - 1, 0, -1):
        b[index[j]] = _dot6(S[j], F[j])
        parent = parents[j]
        if parent > 0:
            cm[parent] += cm[j]
            for r in range(6):  # element by element: no temporary arrays
                F[parent, r] += F[j, r]
            for r in range(3):
                ch[parent, r] += ch[j, r]
                for c in range(3):
                    ci[parent, r, c] += ci[j, r, c]


def _mass_matrix(
    parents: np.ndarray,
    index: np.ndarray,
    S: np.ndarray,
    cm: np.ndarray,
    ch: np.ndarray,
    ci: np.ndarray,
    armature: np.ndarray,
    M: np.ndarray,
    G: np.ndarray,
) -> None:
    """M_kj = S_k . (Ic_j S_j) for every k that carries j, the armature on the diagonal."""
    nv = M.shape[0]
    for r in range(nv):
        for c in range(nv):
            M[r, c] = 0.0
    for j in range(1, parents.size):
        _apply(cm[j], ch[j], ci[j], S[j], G)
        k = j
        while k > 0:
            M[index[k], index[j]] = _dot6(S[k], G)
            M[index[j], index[k]] = M[index[k], index[j]]
            k = parents[k]
        M[index[j], index[j]] += armature[index[j]]


def _kernel(
    parents: np.ndarray,
    rotations: np.ndarray,
    translations: np.ndarray,
    axes: np.ndarray,
    revolute: np.ndarray,
    index: np.ndarray,
    qs: np.ndarray,
    vs: np.ndarray,
    taus: np.ndarray,
    locked: np.ndarray,
    parameters: np.ndarray,
    which: np.ndarray,
    armature: np.ndarray,
    gravity: np.ndarray,
    a: np.ndarray,
    lam: np.ndarray,
) -> None:
    """Fill a and lam state by state (see :func:`locked_dynamics` and the module docstring)."""
    count, nv = parents.size, vs.shape[1]
    R, p = np.zeros((count, 3, 3)), np.zeros((count, 3))
    S, V, C = np.zeros((count, 6)), np.zeros((count, 6)), np.zeros((count, 6))
    cm, ch, ci = np.zeros(count), np.zeros((count, 3)), np.zeros((count, 3, 3))
    F, G, work = np.zeros((count, 6)), np.empty(6), np.empty(6)
    M, b = np.zeros((nv, nv)), np.zeros(nv)
    L, free, x = np.zeros((nv, nv)), np.zeros(nv, dtype=np.int64), np.zeros(nv)
    for i in range(3):
        R[0, i, i] = 1.0
    for s in range(qs.shape[0]):
        for r in range(6):
            C[0, r] = -gravity[r]
        theta = parameters[which[s]]
        for j in range(1, count):
            parent = parents[j]
            angle, rate = qs[s, index[j]], vs[s, index[j]]
            turns = revolute[j]
            _place(j, parent, rotations[j], translations[j], axes[j], turns, angle, R, p, S)
            _move(j, parent, rate, S, V, C)
            # the body's own inertia, summed over its subtree below (parents before children)
            cm[j] = _world_inertia(theta[j], R[j], p[j], ch[j], ci[j])
            _force(cm[j], ch[j], ci[j], V[j], C[j], F[j], work)
        _subtrees(parents, index, S, F, cm, ch, ci, b)
        _mass_matrix(parents, index, S, cm, ch, ci, armature, M, G)
        _solve(M, b, taus[s], locked[s], a[s], lam[s], L, free, x)


@functools.cache
def _compiled() -> Any:
    """The kernel, compiled at the first call of a process (with body_kernel's helpers)."""
    import numba

    body_kernel._compiled()  # its placement and motion helpers, compiled under their names
    jit = numba.njit(cache=True)
    globals().update(_place=body_kernel._place, _move=body_kernel._move)
    helpers = (_world_inertia, _dot6, _apply, _force, _subtrees, _mass_matrix, _cholesky, _solve)
    globals().update({f.__name__: jit(f) for f in helpers})
    return jit(_kernel)


_place = body_kernel._place
_move = body_kernel._move
