r"""Transition in minimal coordinates (Voronets form), the paper's eq. (cond2).

With the orthogonal complement F1 of the persistent constraints (J1 F1 = 0, v = F1 s_dot) and
the projected mass matrix Mbar = F1^T M F1:

.. math::
    \begin{pmatrix} \bar M & F_1^T J_2^T \\ J_2 F_1 & 0 \end{pmatrix}
    \begin{pmatrix} \Delta\dot s \\ \Lambda_2 \end{pmatrix} =
    \begin{pmatrix} 0 \\ -J_2 F_1 \dot s_- \end{pmatrix}, \qquad \Delta\dot q = F_1 \Delta\dot s

One (n - m1 + m2)-square solve plus an m1 x m1 inverse for F1.
"""

from __future__ import annotations

import numpy as np

from ..constraints import orthogonal_complement
from .base import TransitionResult, finish, solve_saddle_point


def compute_transition(
    M: np.ndarray, J1: np.ndarray, J2: np.ndarray, v_minus: np.ndarray
) -> TransitionResult:
    """Velocity jump from the constrained Voronets momentum balance of eq. (cond2).

    Args:
        M: Mass matrix at the event configuration [kg m^2], shape (n, n).
        J1: Jacobian of the persistent constraints, shape (m1, n).
        J2: Jacobian of the constraints activated at the event, shape (m2, n).
        v_minus: Generalized velocity just before the event, shape (n,); J1 v_minus = 0.

    Returns:
        The transition; Lambda2 from the solve, Lambda1 recovered from M dv.

    Raises:
        TransitionError: J1 is redundant or the reduced system is singular.
    """
    F1, s = orthogonal_complement(J1)
    G = J2 @ F1
    ds, _ = solve_saddle_point(F1.T @ M @ F1, G, -G @ v_minus[s], "Minimal-coordinate transition")
    return finish(M, J1, J2, v_minus, v_minus + F1 @ ds)
