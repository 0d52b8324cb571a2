"""The arm's largest displacement and fastest point over many states, compiled (Numba).

:func:`vtm_pin.physics.arm_points.max_displacements` finds, for each of a study's stops, the
point of the arm that travels farthest from where it was at the signal. Its NumPy path forms
a bound for every joint at every sample, then the points of the joints and samples that may
hold the largest: array operations over all the stops' samples at once, but each a pass over
arrays of (samples x joints x 3 x 3) temporaries (~0.12 ms a UR10 study case, the largest
single item of its report). This is the same search, trajectory by trajectory, compiled by
Numba (the ``fast`` extra), without temporaries:

- for each sample t and joint g that carries points, the bound
  |(R_t - R_0) c_g + o_t - o_0| + ||R_t - R_0||_F / sqrt(2) r_g of its points' displacements
  (c_g, r_g: the centre and radius of the joint's points);
- the points of the joint and sample of the largest bound: the largest squared displacement
  there is a bar;
- the points of every joint and sample whose bound reaches the bar: the largest, the first
  sample and then the first point on a tie.

A second kernel, :func:`fastest_speeds`, gives
:func:`vtm_pin.physics.arm_points.fastest_point_speeds` the fastest point at each state,
point by point (0.0035 against NumPy's 0.027 ms a UR10 case).

Both give the NumPy paths' results to round-off (``tests/test_arm_points.py``,
``tests/test_kinematics.py``). They run where
the other kernels run (:func:`vtm_pin.physics.body_kernel.AVAILABLE`); the first call of a
process compiles each (~2 s) unless Numba's cache beside this file holds it.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from . import body_kernel


def runs() -> bool:
    """Whether the kernel may run (:data:`vtm_pin.physics.body_kernel.AVAILABLE`)."""
    return body_kernel.AVAILABLE


def largest_displacements(
    R: np.ndarray,
    o: np.ndarray,
    firsts: np.ndarray,
    counts: np.ndarray,
    groups: Any,
    points: np.ndarray,
    slack: float,
    floor: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each trajectory's largest squared displacement [m^2], its point and its sample.

    Args:
        R: Rotations of the joints that carry points, every trajectory's samples stacked,
            shape (S, m, 3, 3).
        o: Their origins [m], shape (S, m, 3).
        firsts: Each trajectory's first row of R and o, shape (C,).
        counts: Its number of samples (>= 1), shape (C,).
        groups: The points by joint (:attr:`vtm_pin.physics.arm_points.ArmPoints.groups`).
        points: The points in their joints' frames [m], shape (k, 3), ordered by joint.
        slack: Relative slack of the bounds [-].
        floor: Absolute slack of the bounds [m].

    Returns:
        ``(squared, point, sample)``, shapes (C,): the point is a row of ``points``, the
        sample a row of the trajectory (both 0 where nothing moves).
    """
    count = len(firsts)
    squared = np.zeros(count)
    point = np.zeros(count, dtype=np.int64)
    sample = np.zeros(count, dtype=np.int64)
    _compiled()(
        *(_array(x, float) for x in (R, o)),
        *(_array(x, np.int64) for x in (firsts, counts)),
        *(_array(x, float) for x in (groups.centers, groups.radii)),
        *(_array(x, np.int64) for x in (groups.starts, groups.stops)),
        _array(points, float),
        float(slack),
        float(floor),
        squared,
        point,
        sample,
    )
    return squared, point, sample


def _array(x: np.ndarray, dtype: Any) -> np.ndarray:
    """``x`` contiguous and writable (a copy if read-only): one compiled signature for all."""
    return np.require(x, dtype, ["C", "W"])


def _bound(
    R: np.ndarray,
    o: np.ndarray,
    t: int,
    first: int,
    g: int,
    center: np.ndarray,
    radius: float,
    slack: float,
    floor: float,
) -> float:
    """The bound [m] of joint g's points' displacements at row t against row ``first``."""
    middle = 0.0
    frobenius = 0.0
    for a in range(3):
        m = o[t, g, a] - o[first, g, a]
        for b in range(3):
            turn = R[t, g, a, b] - R[first, g, a, b]
            m += turn * center[b]
            frobenius += turn * turn
        middle += m * m
    return (np.sqrt(middle) + np.sqrt(frobenius / 2.0) * radius) * (1.0 + slack) + floor


def _exact(
    R: np.ndarray, o: np.ndarray, t: int, first: int, g: int, points: np.ndarray, k: int
) -> float:
    """The squared displacement [m^2] of point k (joint g's) at row t against row ``first``."""
    out = 0.0
    for a in range(3):
        d = o[t, g, a] - o[first, g, a]
        for b in range(3):
            d += (R[t, g, a, b] - R[first, g, a, b]) * points[k, b]
        out += d * d
    return out


def _kernel(
    R: np.ndarray,
    o: np.ndarray,
    firsts: np.ndarray,
    counts: np.ndarray,
    centers: np.ndarray,
    radii: np.ndarray,
    starts: np.ndarray,
    stops: np.ndarray,
    points: np.ndarray,
    slack: float,
    floor: float,
    squared: np.ndarray,
    point: np.ndarray,
    sample: np.ndarray,
) -> None:
    """Fill squared, point and sample, trajectory by trajectory (:func:`largest_displacements`)."""
    m = centers.shape[0]
    for c in range(firsts.size):
        first, count = firsts[c], counts[c]
        bound = np.empty((count, m))
        top, top_t, top_g = -1.0, 0, 0
        for t in range(count):
            for g in range(m):
                x = _bound(R, o, first + t, first, g, centers[g], radii[g], slack, floor)
                bound[t, g] = x
                if x > top:
                    top, top_t, top_g = x, t, g
        bar = 0.0
        for k in range(starts[top_g], stops[top_g]):
            bar = max(bar, _exact(R, o, first + top_t, first, top_g, points, k))
        reach = np.sqrt(bar)
        best, best_k, best_t = -1.0, 0, 0
        for t in range(count):  # samples in order, then points in order: the first of a tie
            for g in range(m):
                if not bound[t, g] >= reach:
                    continue
                for k in range(starts[g], stops[g]):
                    x = _exact(R, o, first + t, first, g, points, k)
                    if x > best:
                        best, best_k, best_t = x, k, t
        if best > 0.0:
            squared[c], point[c], sample[c] = best, best_k, best_t


@functools.cache
def _compiled() -> Any:
    """The kernel, compiled at the first call of a process (its helpers first)."""
    import numba

    jit = numba.njit(cache=True)
    globals().update({f.__name__: jit(f) for f in (_bound, _exact)})
    return jit(_kernel)


def fastest_speeds(
    R: np.ndarray, omega: np.ndarray, velocity: np.ndarray, groups: Any, points: np.ndarray
) -> np.ndarray:
    """The fastest point's speed [m/s] at each of T states, shape (T,).

    Args:
        R: Rotations of every joint at the states, shape (T, njoints, 3, 3).
        omega: The joints' bodies' angular velocities in the world [rad/s], shape (T, njoints, 3).
        velocity: Their linear velocities at the joints' origins [m/s], the same shape.
        groups: The points by joint (:attr:`vtm_pin.physics.arm_points.ArmPoints.groups`).
        points: The points in their joints' frames [m], shape (k, 3), ordered by joint.
    """
    out = np.zeros(len(R))
    _compiled_speeds()(
        *(_array(x, float) for x in (R, omega, velocity)),
        *(_array(x, np.int64) for x in (groups.joints, groups.starts, groups.stops)),
        _array(points, float),
        out,
    )
    return out


def _speeds_kernel(
    R: np.ndarray,
    omega: np.ndarray,
    velocity: np.ndarray,
    joints: np.ndarray,
    starts: np.ndarray,
    stops: np.ndarray,
    points: np.ndarray,
    out: np.ndarray,
) -> None:
    """Fill out state by state: max over points of |v_j + omega_j x (R_j p_i)| (see there)."""
    arm = np.empty(3)
    for t in range(R.shape[0]):
        top = 0.0
        for g in range(joints.size):
            j = joints[g]
            w, v = omega[t, j], velocity[t, j]
            for k in range(starts[g], stops[g]):
                for a in range(3):
                    arm[a] = R[t, j, a, 0] * points[k, 0] + R[t, j, a, 1] * points[k, 1]
                    arm[a] += R[t, j, a, 2] * points[k, 2]
                x0 = v[0] + (w[1] * arm[2] - w[2] * arm[1])
                x1 = v[1] + (w[2] * arm[0] - w[0] * arm[2])
                x2 = v[2] + (w[0] * arm[1] - w[1] * arm[0])
                top = max(top, x0 * x0 + x1 * x1 + x2 * x2)
        out[t] = np.sqrt(top)


@functools.cache
def _compiled_speeds() -> Any:
    """:func:`_speeds_kernel`, compiled at its first call of a process (or loaded)."""
    import numba

    return numba.njit(cache=True)(_speeds_kernel)
