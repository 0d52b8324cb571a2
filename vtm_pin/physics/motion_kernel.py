"""The joints' placements and a frame's path and speed over many samples, compiled (Numba).

A stopping report reads the motion from the stop signal on: every joint's world placement at
every sample (the arm's points are placed from them) and the tool frame's origin and speed
(:func:`vtm_pin.physics.kinematics.frame_motion`). The NumPy path forms them joint by joint,
each step a few array operations over all samples (a study's report makes those of ~32 stops
of ~80 samples at once), most of its time passes over small temporaries. This is the same
arithmetic, sample by sample, compiled by Numba (the ``fast`` extra), written out in scalars
(views of work arrays, which Numba keeps in memory, made an earlier kernel of the placements
only 1.3 times faster than NumPy). 2,560 UR10 samples, the two alternated 15 times in one
process: 0.73 against 2.40 us a sample (issue 27; 0.53 against 1.94 in a quieter minute):

- each joint's placement from its parent's: R_j = R_parent F_j Rot(a_j, q_j),
  p_j = p_parent + R_parent t_j (+ the axis in the world times q_j for a sliding joint), as
  :func:`vtm_pin.physics.kinematics.joint_placements`;
- the frame's origin o = p_J + R_J f on its joint J, at offset f;
- its velocity, the sum from J to the root of (R_j a_j) x (o - p_j) v_j for a turning joint
  and (R_j a_j) v_j for a sliding one, and its norm.

It agrees with the NumPy path and Pinocchio to round-off (``tests/test_kinematics.py``); it
runs where the other kernels run (:data:`vtm_pin.physics.body_kernel.AVAILABLE`), and the first
call of a process compiles it (~1 s) unless Numba's cache beside this file holds it.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

from . import body_kernel


def runs() -> bool:
    """Whether the kernel may run (:data:`vtm_pin.physics.body_kernel.AVAILABLE`)."""
    return body_kernel.AVAILABLE


def frame_motion(
    chain: Any, qs: np.ndarray, vs: np.ndarray, joint: int, offset: np.ndarray
) -> tuple[tuple[np.ndarray, np.ndarray], np.ndarray, np.ndarray]:
    """Every joint's placement and a frame's origin and speed at T samples (q, v).

    Args:
        chain: The model's joints (:func:`vtm_pin.physics.kinematics.joint_chain`).
        qs: Joint positions [rad or m], shape (T, nq).
        vs: Joint rates [rad/s or m/s], shape (T, nv).
        joint: The frame's parent joint.
        offset: The frame's origin in its joint's frame [m], shape (3,).

    Returns:
        ``((R, p), path, speed)``: rotations, shape (T, njoints, 3, 3), and origins [m],
        shape (T, njoints, 3), of the joints' frames; the frame's origin [m], shape (T, 3),
        and its speed [m/s], shape (T,).
    """
    count = len(chain.parents)
    support = []
    j = joint
    while j > 0:  # the joints that move the frame, from its own to the root
        support.append(j)
        j = chain.parents[j]
    qs = np.ascontiguousarray(qs, dtype=float)
    R = np.empty((len(qs), count, 3, 3))
    p = np.empty((len(qs), count, 3))
    path = np.empty((len(qs), 3))
    speed = np.empty(len(qs))
    _compiled()(
        *body_kernel.chain_arrays(chain),
        qs,
        np.ascontiguousarray(vs, dtype=float),
        np.array(support, dtype=np.int64),
        np.ascontiguousarray(offset, dtype=float),
        R,
        p,
        path,
        speed,
    )
    return (R, p), path, speed


def _kernel(
    parents: np.ndarray,
    rotations: np.ndarray,
    translations: np.ndarray,
    axes: np.ndarray,
    revolute: np.ndarray,
    index: np.ndarray,
    qs: np.ndarray,
    vs: np.ndarray,
    support: np.ndarray,
    offset: np.ndarray,
    R: np.ndarray,
    p: np.ndarray,
    path: np.ndarray,
    speed: np.ndarray,
) -> None:
    """Fill R, p, path and speed sample by sample (see :func:`frame_motion`)."""
    count = parents.size
    for b in range(qs.shape[0]):
        for r in range(3):
            for c in range(3):
                R[b, 0, r, c] = 1.0 if r == c else 0.0
            p[b, 0, r] = 0.0
        for j in range(1, count):
            _place(
                b, j, parents[j], rotations, translations, axes, revolute[j], qs[b, index[j]], R, p
            )
        _frame(b, support, axes, revolute, index, vs, offset, R, p, path, speed)


def _place(
    b: int,
    j: int,
    parent: int,
    rotations: np.ndarray,
    translations: np.ndarray,
    axes: np.ndarray,
    revolute: bool,
    angle: float,
    R: np.ndarray,
    p: np.ndarray,
) -> None:
    """Joint j's placement at sample b from its parent's (Rodrigues for a turning joint)."""
    a0, a1, a2 = axes[j, 0], axes[j, 1], axes[j, 2]
    t0, t1, t2 = translations[j, 0], translations[j, 1], translations[j, 2]
    cos, sin = (math.cos(angle), math.sin(angle)) if revolute else (1.0, 0.0)
    for r in range(3):  # row r of fixed = R_parent rotation, then of R
        q0, q1, q2 = R[b, parent, r, 0], R[b, parent, r, 1], R[b, parent, r, 2]
        p[b, j, r] = ((p[b, parent, r] + q0 * t0) + q1 * t1) + q2 * t2
        f0 = ((q0 * rotations[j, 0, 0]) + q1 * rotations[j, 1, 0]) + q2 * rotations[j, 2, 0]
        f1 = ((q0 * rotations[j, 0, 1]) + q1 * rotations[j, 1, 1]) + q2 * rotations[j, 2, 1]
        f2 = ((q0 * rotations[j, 0, 2]) + q1 * rotations[j, 1, 2]) + q2 * rotations[j, 2, 2]
        w = f0 * a0 + f1 * a1 + f2 * a2  # the axis in the world
        if revolute:  # fixed (cos I + sin [a]x + (1 - cos) a a^T)
            x0, x1, x2 = f1 * a2 - f2 * a1, f2 * a0 - f0 * a2, f0 * a1 - f1 * a0
            one = (1.0 - cos) * w
            R[b, j, r, 0] = cos * f0 + sin * x0 + one * a0
            R[b, j, r, 1] = cos * f1 + sin * x1 + one * a1
            R[b, j, r, 2] = cos * f2 + sin * x2 + one * a2
        else:
            R[b, j, r, 0], R[b, j, r, 1], R[b, j, r, 2] = f0, f1, f2
            p[b, j, r] += w * angle


def _frame(
    b: int,
    support: np.ndarray,
    axes: np.ndarray,
    revolute: np.ndarray,
    index: np.ndarray,
    vs: np.ndarray,
    offset: np.ndarray,
    R: np.ndarray,
    p: np.ndarray,
    path: np.ndarray,
    speed: np.ndarray,
) -> None:
    """The frame's origin and speed at sample b, from the joints' placements there."""
    if support.size == 0:  # on the world: at its offset, still
        path[b, 0], path[b, 1], path[b, 2] = offset[0], offset[1], offset[2]
        speed[b] = 0.0
        return
    J = support[0]
    o0 = p[b, J, 0] + (
        R[b, J, 0, 0] * offset[0] + R[b, J, 0, 1] * offset[1] + R[b, J, 0, 2] * offset[2]
    )
    o1 = p[b, J, 1] + (
        R[b, J, 1, 0] * offset[0] + R[b, J, 1, 1] * offset[1] + R[b, J, 1, 2] * offset[2]
    )
    o2 = p[b, J, 2] + (
        R[b, J, 2, 0] * offset[0] + R[b, J, 2, 1] * offset[1] + R[b, J, 2, 2] * offset[2]
    )
    path[b, 0], path[b, 1], path[b, 2] = o0, o1, o2
    v0 = v1 = v2 = 0.0
    for k in range(support.size):
        j = support[k]
        a0, a1, a2 = axes[j, 0], axes[j, 1], axes[j, 2]
        w0 = R[b, j, 0, 0] * a0 + R[b, j, 0, 1] * a1 + R[b, j, 0, 2] * a2
        w1 = R[b, j, 1, 0] * a0 + R[b, j, 1, 1] * a1 + R[b, j, 1, 2] * a2
        w2 = R[b, j, 2, 0] * a0 + R[b, j, 2, 1] * a1 + R[b, j, 2, 2] * a2
        rate = vs[b, index[j]]
        if revolute[j]:
            d0, d1, d2 = o0 - p[b, j, 0], o1 - p[b, j, 1], o2 - p[b, j, 2]
            v0 += (w1 * d2 - w2 * d1) * rate
            v1 += (w2 * d0 - w0 * d2) * rate
            v2 += (w0 * d1 - w1 * d0) * rate
        else:
            v0 += w0 * rate
            v1 += w1 * rate
            v2 += w2 * rate
    speed[b] = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)


@functools.cache
def _compiled() -> Any:
    """The kernel, compiled at the first call of a process (its helpers first), or loaded."""
    import numba

    jit = numba.njit(cache=True)
    globals().update({f.__name__: jit(f) for f in (_place, _frame)})
    return jit(_kernel)
