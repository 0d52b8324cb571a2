r"""Projected transition in redundant coordinates, the paper's eq. (cond1).

With the M-weighted pseudoinverse J1M+ = M^-1 J1^T (J1 M^-1 J1^T)^-1 and the null-space
projector of the persistent constraints N = I - J1M+ J1:

.. math::
    \begin{pmatrix} M & N^T J_2^T \\ J_2 N & 0 \end{pmatrix}
    \begin{pmatrix} \Delta\dot q \\ \Lambda_2 \end{pmatrix} =
    \begin{pmatrix} 0 \\ -J_2 \dot q_- \end{pmatrix}

One (n + m2)-square solve plus an m1 x m1 inverse for the projector.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from ...exceptions import TransitionError
from .base import TransitionResult, finish, solve_saddle_point


def compute_null_space_projector(M: np.ndarray, J1: np.ndarray) -> np.ndarray:
    """M-weighted projector N_{J1,M} = I - M^-1 J1^T (J1 M^-1 J1^T)^-1 J1 onto ker J1.

    Args:
        M: Mass matrix [kg m^2], shape (n, n), symmetric positive definite.
        J1: Constraint Jacobian, shape (m1, n).

    Returns:
        N, shape (n, n); the identity when m1 = 0.
    """
    n = M.shape[0]
    if J1.shape[0] == 0:
        return np.eye(n)
    Minv_J1T = scipy.linalg.cho_solve(scipy.linalg.cho_factor(M), J1.T)
    A = J1 @ Minv_J1T
    return np.eye(n) - Minv_J1T @ np.linalg.solve(A, J1)


def compute_transition(
    M: np.ndarray, J1: np.ndarray, J2: np.ndarray, v_minus: np.ndarray
) -> TransitionResult:
    """Velocity jump from the projected momentum balance of eq. (cond1).

    Args:
        M: Mass matrix at the event configuration [kg m^2], shape (n, n).
        J1: Jacobian of the persistent constraints, shape (m1, n).
        J2: Jacobian of the constraints activated at the event, shape (m2, n).
        v_minus: Generalized velocity just before the event, shape (n,).

    Returns:
        The transition; Lambda2 from the solve, Lambda1 recovered from M dv.

    Raises:
        TransitionError: M is not positive definite or the system is singular.
    """
    try:
        N = compute_null_space_projector(M, J1)
    except np.linalg.LinAlgError as exc:
        raise TransitionError(f"Projected transition: {exc}") from exc
    dv, _ = solve_saddle_point(M, J2 @ N, -J2 @ v_minus, "Projected transition")
    return finish(M, J1, J2, v_minus, v_minus + dv)
