r"""Full KKT transition, the paper's eqs. (sys1) / (trans1).

.. math::
    \begin{pmatrix} M & J_1^T & J_2^T \\ J_1 & 0 & 0 \\ J_2 & 0 & 0 \end{pmatrix}
    \begin{pmatrix} \Delta\dot q \\ \Lambda_1 \\ \Lambda_2 \end{pmatrix} =
    \begin{pmatrix} 0 \\ -J_1 \dot q_- \\ -J_2 \dot q_- \end{pmatrix}

One (n + m1 + m2)-square solve; no impulsive applied force (U = 0).
"""

from __future__ import annotations

import numpy as np

from .base import TransitionResult, finish, solve_saddle_point


def compute_transition(
    M: np.ndarray, J1: np.ndarray, J2: np.ndarray, v_minus: np.ndarray
) -> TransitionResult:
    """Velocity jump from the KKT system of all constraints after the event.

    Args:
        M: Mass matrix at the event configuration [kg m^2], shape (n, n).
        J1: Jacobian of the persistent constraints, shape (m1, n).
        J2: Jacobian of the constraints activated at the event, shape (m2, n).
        v_minus: Generalized velocity just before the event, shape (n,).

    Returns:
        The transition, with Lambda = (Lambda1, Lambda2) from the solve.

    Raises:
        TransitionError: The KKT matrix is singular (redundant constraints).
    """
    J = np.vstack([J1, J2])
    dv, Lambda = solve_saddle_point(M, J, -J @ v_minus, "KKT transition")
    return finish(M, J1, J2, v_minus, v_minus + dv, Lambda)
