"""Bodies' Jacobians, velocities and bias accelerations over many states, compiled (Numba).

:func:`~vtm_pin.physics.kinematics.body_motions` computes them with NumPy over all states at
once, joint by joint: a few dozen small array operations a joint, which NumPy does badly
(UR10, one body, 281 states a call: ~6.5 us a state, of which the placements ~2.2 us). The
batched engine asks for them at every stage of every lane that carries its own payload
(:class:`vtm_pin.core.batch._Dynamics`), where they were most of the dynamics' time. This is the
same arithmetic, state by state, compiled by Numba: the ``fast`` extra installs it (~0.6-1.3 us
a state). Without Numba, or with ``NUMBA_DISABLE_JIT=1``, :data:`AVAILABLE` is False and the
NumPy path runs, the default and the fallback; both agree with Pinocchio to round-off
(``tests/test_kinematics.py``). The first call of a process compiles the kernel (~4 s) unless
Numba's cache beside this file holds it (~0.1 s; the package folder must be writable).
"""

from __future__ import annotations

import functools
import os
import warnings
from importlib.util import find_spec
from typing import Any

import numpy as np

from ..exceptions import VtmWarning

#: Whether the compiled kernel runs: Numba is installed (the ``fast`` extra) and its own switch
#: ``NUMBA_DISABLE_JIT`` is not set to 1. Otherwise the NumPy path runs. Set False for the
#: process if Numba is installed but cannot import or compile here (:func:`fall_back`).
AVAILABLE = find_spec("numba") is not None and os.environ.get("NUMBA_DISABLE_JIT", "0") == "0"


def failures() -> tuple[type[BaseException], ...]:
    """What a compiled kernel's first call raises when Numba cannot run here.

    Numba's import refusing this NumPy or Python (ImportError), or its compiler failing
    (``NumbaError``). A kernel's own errors at run time are none of these.
    """
    try:
        from numba.core.errors import NumbaError
    except ImportError:
        return (ImportError,)
    return (ImportError, NumbaError)


def fall_back(exc: BaseException) -> None:
    """The compiled kernels cannot run here: the NumPy path from now on, said once.

    :data:`AVAILABLE` goes off, and with it :func:`vtm_pin.physics.chain_dynamics.runs`; the
    results are the same, slower.
    """
    global AVAILABLE
    if AVAILABLE:
        warnings.warn(
            f"the fast extra's compiled kernels cannot run here ({type(exc).__name__}: "
            f"{str(exc).splitlines()[0] if str(exc) else ''}); the NumPy path runs instead "
            "(the same results, slower)",
            VtmWarning,
            stacklevel=3,
        )
    AVAILABLE = False


def body_motions(
    chain: Any, qs: np.ndarray, vs: np.ndarray, joints: tuple[int, ...], gravity: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`~vtm_pin.physics.kinematics.body_motions`, compiled (see there for the arguments).

    Returns:
        ``(J, V, C)``: shapes (B, len(joints), 6, nv), (B, len(joints), 6), (B, len(joints),
        6), contiguous.
    """
    count, nv, picked = len(qs), vs.shape[1], np.array(joints, dtype=np.int64)
    J = np.zeros((count, picked.size, 6, nv))
    V = np.empty((count, picked.size, 6))
    C = np.empty((count, picked.size, 6))
    _compiled()(
        *chain_arrays(chain),
        np.ascontiguousarray(qs, dtype=float),
        np.ascontiguousarray(vs, dtype=float),
        picked,
        np.ascontiguousarray(gravity, dtype=float),
        J,
        V,
        C,
    )
    return J, V, C


def chain_arrays(chain: Any) -> tuple[np.ndarray, ...]:
    """A :class:`~vtm_pin.physics.kinematics.JointChain` as the compiled kernels take it.

    Its parents, fixed rotations and translations, axes, revolute flags and coordinates,
    contiguous.
    """
    return (
        np.array(chain.parents, dtype=np.int64),
        np.ascontiguousarray(chain.rotations, dtype=float),
        np.ascontiguousarray(chain.translations, dtype=float),
        np.ascontiguousarray(chain.axes, dtype=float),
        np.array(chain.revolute, dtype=np.bool_),
        np.array(chain.index, dtype=np.int64),
    )


def _cross(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


def _local(R: np.ndarray, o: np.ndarray, x: np.ndarray, out: np.ndarray) -> None:
    """A world spatial vector (linear, angular) at the world's origin in a joint's frame."""
    m0 = x[0] + x[4] * o[2] - x[5] * o[1]  # the linear part at the joint's origin: lin + ang x o
    m1 = x[1] + x[5] * o[0] - x[3] * o[2]
    m2 = x[2] + x[3] * o[1] - x[4] * o[0]
    for i in range(3):
        out[i] = R[0, i] * m0 + R[1, i] * m1 + R[2, i] * m2
        out[3 + i] = R[0, i] * x[3] + R[1, i] * x[4] + R[2, i] * x[5]


def _place(
    j: int,
    parent: int,
    rotation: np.ndarray,
    translation: np.ndarray,
    a: np.ndarray,
    revolute: bool,
    angle: float,
    R: np.ndarray,
    p: np.ndarray,
    S: np.ndarray,
    work: np.ndarray,
) -> None:
    """Joint j's world placement (R, p) and motion subspace S at the world's origin."""
    fixed, w, t = work[:3], work[3], work[4]
    for r in range(3):
        p[j, r] = p[parent, r]
        for c in range(3):
            p[j, r] += R[parent, r, c] * translation[c]
            fixed[r, c] = 0.0
            for k in range(3):
                fixed[r, c] += R[parent, r, k] * rotation[k, c]
    for r in range(3):
        w[r] = fixed[r, 0] * a[0] + fixed[r, 1] * a[1] + fixed[r, 2] * a[2]
    if revolute:  # Rodrigues: fixed (cos I + sin [a]x + (1 - cos) a a^T)
        cos, sin = np.cos(angle), np.sin(angle)
        for r in range(3):
            _cross(fixed[r], a, t)  # row r of fixed [a]x: (row r) x a
            for c in range(3):
                R[j, r, c] = cos * fixed[r, c] + sin * t[c] + (1.0 - cos) * w[r] * a[c]
        _cross(p[j], w, t)  # (o x w, w)
        for r in range(3):
            S[j, r] = t[r]
            S[j, 3 + r] = w[r]
    else:  # (w, 0)
        for r in range(3):
            for c in range(3):
                R[j, r, c] = fixed[r, c]
            p[j, r] += w[r] * angle
            S[j, r] = w[r]
            S[j, 3 + r] = 0.0


def _move(
    j: int,
    parent: int,
    rate: float,
    S: np.ndarray,
    Vw: np.ndarray,
    Cw: np.ndarray,
    work: np.ndarray,
) -> None:
    """Joint j's body's velocity V = V_parent + S v_j and bias C = C_parent + V x (S v_j)."""
    Sv, w, t = work[0], work[1, :3], work[2, :3]
    for r in range(6):
        Sv[r] = S[j, r] * rate
        Vw[j, r] = Vw[parent, r] + Sv[r]
    _cross(Vw[j, 3:], Sv[:3], t)  # motion cross product: (ang x lin + lin x ang, ang x ang)
    _cross(Vw[j, :3], Sv[3:], w)
    for r in range(3):
        Cw[j, r] = Cw[parent, r] + t[r] + w[r]
    _cross(Vw[j, 3:], Sv[3:], t)
    for r in range(3):
        Cw[j, 3 + r] = Cw[parent, 3 + r] + t[r]


def _kernel(
    parents: np.ndarray,
    rotations: np.ndarray,
    translations: np.ndarray,
    axes: np.ndarray,
    revolute: np.ndarray,
    index: np.ndarray,
    qs: np.ndarray,
    vs: np.ndarray,
    picked: np.ndarray,
    gravity: np.ndarray,
    J: np.ndarray,
    V: np.ndarray,
    C: np.ndarray,
) -> None:
    """Fill J, V, C state by state (see :func:`body_motions`).

    Placements, motion subspaces, velocities and bias accelerations from the root, then the
    picked bodies' in their own frames.
    """
    count = parents.size
    R, p = np.zeros((count, 3, 3)), np.zeros((count, 3))
    S, Vw, Cw = np.zeros((count, 6)), np.zeros((count, 6)), np.zeros((count, 6))
    place, move, column = np.empty((5, 3)), np.empty((3, 6)), np.empty(6)
    for i in range(3):
        R[0, i, i] = 1.0
    for b in range(qs.shape[0]):
        for r in range(6):
            Cw[0, r] = -gravity[r]
        for j in range(1, count):
            angle, rate = qs[b, index[j]], vs[b, index[j]]
            parent = parents[j]
            _place(
                j,
                parent,
                rotations[j],
                translations[j],
                axes[j],
                revolute[j],
                angle,
                R,
                p,
                S,
                place,
            )
            _move(j, parent, rate, S, Vw, Cw, move)
        for d in range(picked.size):
            j = picked[d]
            k = j
            while k > 0:
                _local(R[j], p[j], S[k], column)
                for r in range(6):
                    J[b, d, r, index[k]] = column[r]
                k = parents[k]
            _local(R[j], p[j], Vw[j], V[b, d])
            _local(R[j], p[j], Cw[j], C[b, d])


@functools.cache
def _compiled() -> Any:
    """The kernel, compiled at the first call of a process.

    Numba is imported then, not with the package (~0.4 s), and the kernel compiled (~4 s) or
    loaded from Numba's cache beside this file. The helpers are compiled first, under their
    own names, so that the kernel calls them compiled.
    """
    import numba

    jit = numba.njit(cache=True)
    globals().update({f.__name__: jit(f) for f in (_cross, _local, _place, _move)})
    return jit(_kernel)
