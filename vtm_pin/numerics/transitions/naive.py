"""Naive lock: zero the newly locked velocities and keep the others.

This is what Drake's ``Joint::Lock`` and Gazebo's halt do, and the paper's counter-example
(its fig. 3): the momentum of the joints that stay free is not conserved.
"""

from __future__ import annotations

import numpy as np

from .base import TransitionResult, finish


def compute_transition(
    M: np.ndarray, J1: np.ndarray, J2: np.ndarray, v_minus: np.ndarray
) -> TransitionResult:
    """Velocity after zeroing the coordinates that J2 locks; everything else unchanged.

    Args:
        M: Mass matrix at the event configuration [kg m^2], shape (n, n).
        J1: Jacobian of the persistent locks, shape (m1, n).
        J2: Jacobian of the locks activated at the event (unit rows), shape (m2, n).
        v_minus: Generalized velocity just before the event, shape (n,).

    Returns:
        The transition; Lambda is the least-squares fit of M dv = -J+^T Lambda.
    """
    v_plus = np.array(v_minus, dtype=float)
    v_plus[np.flatnonzero(np.any(J2 != 0.0, axis=0))] = 0.0
    return finish(M, J1, J2, v_minus, v_plus)
