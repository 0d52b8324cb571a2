r"""Constraint Jacobians of joint locks and their orthogonal complements.

A lock of coordinate i is the holonomic constraint h(q) = q_i - q_i(t_event) = 0, whose
Jacobian is the unit row e_i^T. The orthogonal complement F of a Jacobian J (J F = 0) is the
paper's eq. (F): with q split into dependent p and independent s coordinates,

.. math:: F = \begin{pmatrix} -J_p^{-1} J_s \\ I_{n-m} \end{pmatrix}, \qquad \dot q = F \dot s.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.linalg

from ..exceptions import ConstraintError, TransitionError

#: Largest condition number of J_p accepted when choosing independent coordinates.
MAX_CONDITION = 1e12


def lock_jacobian(nv: int, indices: Sequence[int]) -> np.ndarray:
    """Jacobian of locks of the coordinates ``indices``: one unit row e_i^T per lock.

    Args:
        nv: Number of generalized velocities n.
        indices: Locked coordinates, in row order.

    Returns:
        J, shape (len(indices), nv).
    """
    J = np.zeros((len(indices), nv))
    J[np.arange(len(indices)), list(indices)] = 1.0
    return J


def orthogonal_complement(J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthogonal complement F of J and the independent coordinates s it is expressed in.

    The dependent coordinates p are the first m column pivots of a pivoted QR of J (the best
    conditioned choice); the remaining n - m columns, in increasing order, are s.

    Args:
        J: Constraint Jacobian, shape (m, n), full row rank.

    Returns:
        ``(F, s)``: F of shape (n, n - m) with J F = 0 and F[s] = I, and the indices s.

    Raises:
        TransitionError: J is rank-deficient (redundant constraints) or J_p is ill-conditioned.
    """
    m, n = J.shape
    if m == 0:
        return np.eye(n), np.arange(n)
    rows, cols = np.nonzero(J)
    if rows.size == m and np.array_equal(rows, np.arange(m)) and np.all(J[rows, cols] == 1.0):
        if np.unique(cols).size < m:
            raise TransitionError("Constraint Jacobian locks a joint twice: redundant constraints")
        s = np.setdiff1d(np.arange(n), cols)  # joint locks: F selects the free joints
        return np.eye(n)[:, s], s
    _, _, piv = scipy.linalg.qr(J, pivoting=True, mode="economic")
    p = np.sort(piv[:m])
    s = np.sort(piv[m:])
    Jp = J[:, p]
    cond = np.linalg.cond(Jp) if m > 0 else 1.0
    if not np.isfinite(cond) or cond > MAX_CONDITION:
        raise TransitionError(
            f"Constraint Jacobian is rank-deficient or ill-conditioned (cond(J_p) = {cond:.3g} "
            f"> {MAX_CONDITION:.0e}): the constraints are redundant"
        )
    F = np.zeros((n, n - m))
    F[s, np.arange(n - m)] = 1.0
    F[p, :] = -np.linalg.solve(Jp, J[:, s])
    return F, s


def check_independent(J: np.ndarray, labels: Sequence[str]) -> None:
    """Raise if the rows of J are linearly dependent, naming the redundant rows.

    Args:
        J: Stacked constraint Jacobian, shape (m, n).
        labels: One name per row (``"lock joint2"``, ``"loop.y"``).

    Raises:
        ConstraintError: Some rows depend on the ones before them (the paper assumes
            non-redundant constraints).
    """
    if J.shape[0] == 0:
        return
    scale = max(1.0, float(np.max(np.abs(J))))
    kept: list[np.ndarray] = []
    redundant = []
    for row, label in zip(J, labels, strict=True):
        trial = np.vstack([*kept, row])
        if np.linalg.matrix_rank(trial, tol=1e-9 * scale) == len(kept) + 1:
            kept.append(row)
        else:
            redundant.append(label)
    if redundant:
        raise ConstraintError(
            f"Constraints are redundant: {', '.join(repr(r) for r in redundant)} "
            f"depend{'s' if len(redundant) == 1 else ''} on the others (rank {len(kept)} of "
            f"{J.shape[0]} rows); drop them (a planar loop keeps axes [x, z])"
        )
