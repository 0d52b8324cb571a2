r"""Rigid-body dynamics from Pinocchio: M (CRBA), bias C v + g (RNEA), gravity, energies.

The equations of motion of the unconstrained tree are M(q) a + b(q, v) = tau with
b = C(q, v) v + g(q). A set of locked coordinates L has v_L = 0 and a_L = 0; the free
coordinates f follow the reduced equations M_ff a_f = tau_f - b_f.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np
import pinocchio as pin
import scipy.linalg
from scipy.linalg.lapack import dgesv as _gesv


def compute_M(model: pin.Model, data: pin.Data, q: np.ndarray) -> np.ndarray:
    """Joint-space mass matrix, armature included [kg m^2], shape (nv, nv), symmetric."""
    M = np.array(pin.crba(model, data, q))  # CRBA fills the upper triangle
    lower = _lower_triangle(model.nv)
    M[lower] = M.T[lower]
    return M


def solve_small(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The solution x of A x = b for a small dense A.

    LAPACK's gesv (LU with partial pivoting), as ``np.linalg.solve`` calls it, without NumPy's
    Python wrapper: about 1 instead of 4 us at n = 6. For float64 A, shape (k, k), and b,
    shape (k,), k >= 1. SciPy and NumPy ship their own LAPACK builds, so the two can differ in
    the last bits (from k = 6 here); NaN in A or b gives NaN, as in NumPy.

    Raises:
        numpy.linalg.LinAlgError: A is singular (as ``np.linalg.solve`` raises).
    """
    x, info = _gesv(A, b)[2:]
    if info != 0:
        raise np.linalg.LinAlgError("Singular matrix")
    return np.asarray(x)


@functools.lru_cache(maxsize=32)
def _lower_triangle(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices below the diagonal of an n x n matrix."""
    return np.tril_indices(n, -1)


def compute_bias(model: pin.Model, data: pin.Data, q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Coriolis, centrifugal and gravity torques b = C(q, v) v + g(q) [N m], shape (nv,)."""
    return np.array(pin.nonLinearEffects(model, data, q, v))


def compute_gravity(model: pin.Model, data: pin.Data, q: np.ndarray) -> np.ndarray:
    """Generalized gravity torques g(q) [N m], shape (nv,)."""
    return np.array(pin.computeGeneralizedGravity(model, data, q))


def compute_energy(
    model: pin.Model, data: pin.Data, q: np.ndarray, v: np.ndarray
) -> tuple[float, float]:
    """Kinetic energy 1/2 v^T M v (armature included) and gravitational potential energy.

    Returns:
        ``(T, V)`` [J]; V is zero at the height of the world origin.
    """
    M = compute_M(model, data, q)
    return 0.5 * float(v @ M @ v), float(pin.computePotentialEnergy(model, data, q))


def compute_forward_dynamics(
    model: pin.Model,
    data: pin.Data,
    q: np.ndarray,
    v: np.ndarray,
    tau: np.ndarray,
    locked: Sequence[int] = (),
) -> np.ndarray:
    """Accelerations with the coordinates ``locked`` held fixed.

    Uses ABA when nothing is locked, otherwise M_ff a_f = tau_f - b_f with M from CRBA and b
    from RNEA (locked velocities are taken as zero).

    Args:
        model: Pinocchio model.
        data: Its data.
        q: Configuration [rad], shape (nv,).
        v: Velocity [rad/s], shape (nv,).
        tau: Applied joint torques [N m], shape (nv,).
        locked: Indices of locked coordinates.

    Returns:
        a [rad/s^2], shape (nv,), exactly zero at the locked coordinates.
    """
    if len(locked) == 0:
        return np.array(pin.aba(model, data, q, v, tau))
    free = np.setdiff1d(np.arange(model.nv), locked)
    v = np.array(v, dtype=float)
    v[list(locked)] = 0.0
    M = compute_M(model, data, q)
    b = compute_bias(model, data, q, v)
    a = np.zeros(model.nv)
    if free.size:
        a[free] = scipy.linalg.cho_solve(
            scipy.linalg.cho_factor(M[np.ix_(free, free)]), tau[free] - b[free]
        )
    return a
