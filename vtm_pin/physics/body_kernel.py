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
) -> None:
    """Joint j's world placement (R, p) and motion subspace S at the world's origin.

    Written out in scalars (no views of work arrays, which Numba does not keep in registers:
    the dynamics kernel ran 1.7 times slower); every sum in the order of the matrix products
    it spells, so the numbers are those of the loops, bit for bit.
    """
    a0, a1, a2 = a[0], a[1], a[2]
    t0, t1, t2 = translation[0], translation[1], translation[2]
    cos, sin = (np.cos(angle), np.sin(angle)) if revolute else (1.0, 0.0)
    for r in range(3):  # row r of fixed = R_parent rotation, then of R
        q0, q1, q2 = R[parent, r, 0], R[parent, r, 1], R[parent, r, 2]
        p[j, r] = ((p[parent, r] + q0 * t0) + q1 * t1) + q2 * t2
        f0 = ((0.0 + q0 * rotation[0, 0]) + q1 * rotation[1, 0]) + q2 * rotation[2, 0]
        f1 = ((0.0 + q0 * rotation[0, 1]) + q1 * rotation[1, 1]) + q2 * rotation[2, 1]
        f2 = ((0.0 + q0 * rotation[0, 2]) + q1 * rotation[1, 2]) + q2 * rotation[2, 2]
        w = f0 * a0 + f1 * a1 + f2 * a2  # the axis in the world
        S[j, 3 + r] = w
        if revolute:  # Rodrigues: fixed (cos I + sin [a]x + (1 - cos) a a^T)
            x0, x1, x2 = f1 * a2 - f2 * a1, f2 * a0 - f0 * a2, f0 * a1 - f1 * a0  # (row) x a
            one = (1.0 - cos) * w
            R[j, r, 0] = cos * f0 + sin * x0 + one * a0
            R[j, r, 1] = cos * f1 + sin * x1 + one * a1
            R[j, r, 2] = cos * f2 + sin * x2 + one * a2
        else:
            R[j, r, 0], R[j, r, 1], R[j, r, 2] = f0, f1, f2
            p[j, r] += w * angle
    w0, w1, w2 = S[j, 3], S[j, 4], S[j, 5]
    if revolute:  # (o x w, w)
        o0, o1, o2 = p[j, 0], p[j, 1], p[j, 2]
        S[j, 0], S[j, 1], S[j, 2] = o1 * w2 - o2 * w1, o2 * w0 - o0 * w2, o0 * w1 - o1 * w0
    else:  # (w, 0)
        S[j, 0], S[j, 1], S[j, 2] = w0, w1, w2
        S[j, 3] = S[j, 4] = S[j, 5] = 0.0


def _move(j: int, parent: int, rate: float, S: np.ndarray, Vw: np.ndarray, Cw: np.ndarray) -> None:
    """Joint j's body's velocity V = V_parent + S v_j and bias C = C_parent + V x (S v_j).

    The motion cross product (ang x lin + lin x ang, ang x ang), in scalars (see :func:`_place`).
    """
    s0, s1, s2 = S[j, 0] * rate, S[j, 1] * rate, S[j, 2] * rate
    s3, s4, s5 = S[j, 3] * rate, S[j, 4] * rate, S[j, 5] * rate
    v0, v1, v2 = Vw[parent, 0] + s0, Vw[parent, 1] + s1, Vw[parent, 2] + s2
    v3, v4, v5 = Vw[parent, 3] + s3, Vw[parent, 4] + s4, Vw[parent, 5] + s5
    Vw[j, 0], Vw[j, 1], Vw[j, 2], Vw[j, 3], Vw[j, 4], Vw[j, 5] = v0, v1, v2, v3, v4, v5
    Cw[j, 0] = (Cw[parent, 0] + (v4 * s2 - v5 * s1)) + (v1 * s5 - v2 * s4)
    Cw[j, 1] = (Cw[parent, 1] + (v5 * s0 - v3 * s2)) + (v2 * s3 - v0 * s5)
    Cw[j, 2] = (Cw[parent, 2] + (v3 * s1 - v4 * s0)) + (v0 * s4 - v1 * s3)
    Cw[j, 3] = Cw[parent, 3] + (v4 * s5 - v5 * s4)
    Cw[j, 4] = Cw[parent, 4] + (v5 * s3 - v3 * s5)
    Cw[j, 5] = Cw[parent, 5] + (v3 * s4 - v4 * s3)


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
    column = np.empty(6)
    for i in range(3):
        R[0, i, i] = 1.0
    for b in range(qs.shape[0]):
        for r in range(6):
            Cw[0, r] = -gravity[r]
        for j in range(1, count):
            angle, rate = qs[b, index[j]], vs[b, index[j]]
            parent = parents[j]
            _place(j, parent, rotations[j], translations[j], axes[j], revolute[j], angle, R, p, S)
            _move(j, parent, rate, S, Vw, Cw)
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
    globals().update({f.__name__: jit(f) for f in (_local, _place, _move)})
    return jit(_kernel)
