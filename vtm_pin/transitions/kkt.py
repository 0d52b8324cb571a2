r"""Full KKT transition, the paper's eqs. (sys1) / (trans1).

.. math::
    \begin{pmatrix} M & J_1^T & J_2^T \\ J_1 & 0 & 0 \\ J_2 & 0 & 0 \end{pmatrix}
    \begin{pmatrix} \Delta\dot q \\ \Lambda_1 \\ \Lambda_2 \end{pmatrix} =
    \begin{pmatrix} 0 \\ -J_1 \dot q_- \\ -J_2 \dot q_- \end{pmatrix}

One (n + m1 + m2)-square solve; no impulsive applied force (U = 0).
"""

from __future__ import annotations

import numpy as np

from ..exceptions import TransitionError
from .base import TransitionResult, finish


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
    n = M.shape[0]
    J = np.vstack([J1, J2])
    m = J.shape[0]
    K = np.zeros((n + m, n + m))
    K[:n, :n] = M
    K[:n, n:] = J.T
    K[n:, :n] = J
    rhs = np.concatenate([np.zeros(n), -J @ v_minus])
    try:
        x = np.linalg.solve(K, rhs)
    except np.linalg.LinAlgError as exc:
        raise TransitionError("KKT matrix is singular: the constraints are redundant") from exc
    return finish(M, J1, J2, v_minus, v_minus + x[:n], x[n:])
