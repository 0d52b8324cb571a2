r"""What every transition formulation returns, and the bookkeeping they share.

Notation of the paper: J1 (m1 x n) holds the persistent constraints, already active before the
event; J2 (m2 x n) the constraints activated at the event; J+ = [J1; J2]. The impulsive
constraint forces Lambda enter the momentum balance as M dv + J+^T Lambda = 0, so the
generalized impulse acting on the mechanism through the constraints is -J+^T Lambda.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ...exceptions import TransitionError
from ..constraints import orthogonal_complement

#: Largest accepted |J+ v+| of a solve, relative to |v-| (beyond it the result is garbage).
MAX_RESIDUAL = 1e-6


@dataclass(frozen=True)
class TransitionResult:
    """Outcome of one constraint activation.

    Attributes:
        v_plus: Generalized velocity after the event [rad/s or m/s], shape (n,).
        Lambda: Impulsive constraint forces of J+ = ``[J1; J2]`` [N m s or N s], shape (m1 + m2,),
            with the paper's sign (M dv + J+^T Lambda = 0).
        m1: Number of persistent constraints (the first m1 entries of ``Lambda``).
        energy_loss: Kinetic energy before minus after, T(v-) - T(v+) [J].
        p_free_minus: Momentum of the coordinates still free after the event, F+^T M v-
            [N m s], shape (n - m1 - m2,).
        p_free_plus: The same after the event, F+^T M v+ [N m s].
        residual: max |J+ v+| of the solver's v+ before locked velocities are zeroed [rad/s].
    """

    v_plus: np.ndarray
    Lambda: np.ndarray
    m1: int
    energy_loss: float
    p_free_minus: np.ndarray
    p_free_plus: np.ndarray
    residual: float

    @property
    def Lambda1(self) -> np.ndarray:
        """Impulsive forces on the persistent constraints [N m s]."""
        return self.Lambda[: self.m1]

    @property
    def Lambda2(self) -> np.ndarray:
        """Impulsive forces on the constraints activated at the event [N m s]."""
        return self.Lambda[self.m1 :]


class Transition(Protocol):
    """Signature shared by the formulations: ``(M, J1, J2, v_minus) -> TransitionResult``."""

    def __call__(
        self, M: np.ndarray, J1: np.ndarray, J2: np.ndarray, v_minus: np.ndarray
    ) -> TransitionResult:
        """Map v- to v+ when J2 is activated on top of J1 at the mass matrix M."""
        ...


def finish(
    M: np.ndarray,
    J1: np.ndarray,
    J2: np.ndarray,
    v_minus: np.ndarray,
    v_plus: np.ndarray,
    Lambda: np.ndarray | None = None,
) -> TransitionResult:
    """Assemble a :class:`TransitionResult` from a formulation's v+ (and Lambda if it has it).

    Rows of J+ that are unit rows (joint locks) get their coordinate of v+ set to exactly 0,
    removing the solver's round-off; ``residual`` keeps its size. Where a formulation does not
    produce all of Lambda, it is recovered from M dv = -J+^T Lambda by least squares (exact for
    a consistent jump, the best fit for the naive rule, which breaks that balance).

    Args:
        M: Mass matrix at the event configuration [kg m^2], shape (n, n).
        J1: Persistent constraint Jacobian, shape (m1, n).
        J2: Activated constraint Jacobian, shape (m2, n).
        v_minus: Velocity before the event, shape (n,).
        v_plus: Velocity after the event from the formulation, shape (n,).
        Lambda: Impulsive forces of [J1; J2] if the formulation computed them all.
    """
    J = np.vstack([J1, J2])
    v_plus = np.array(v_plus, dtype=float)
    residual = float(np.max(np.abs(J @ v_plus), initial=0.0))
    scale = float(np.max(np.abs(v_minus), initial=0.0))
    if not np.all(np.isfinite(v_plus)) or residual > MAX_RESIDUAL * max(scale, 1e-300):
        raise TransitionError(
            f"Transition is numerically unreliable: |J+ v+| = {residual:.3g} for |v-| = "
            f"{scale:.3g} (cond(M) = {np.linalg.cond(M):.3g}); the mass matrix is too "
            "ill-conditioned for this lock"
        )
    for row in J:
        nonzero = np.flatnonzero(row)
        if nonzero.size == 1 and row[nonzero[0]] == 1.0:
            v_plus[nonzero[0]] = 0.0
    dv = v_plus - v_minus
    if Lambda is None:
        Lambda = -np.linalg.lstsq(J.T, M @ dv, rcond=None)[0] if J.size else np.zeros(0)
    F, _ = orthogonal_complement(J)
    energy_loss = 0.5 * float(v_minus @ M @ v_minus - v_plus @ M @ v_plus)
    return TransitionResult(
        v_plus=v_plus,
        Lambda=np.asarray(Lambda, dtype=float),
        m1=J1.shape[0],
        energy_loss=energy_loss,
        p_free_minus=F.T @ M @ v_minus,
        p_free_plus=F.T @ M @ v_plus,
        residual=residual,
    )


def solve_saddle_point(
    A: np.ndarray,
    G: np.ndarray,
    c: np.ndarray,
    name: str,
    *,
    f: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    r"""Solve a balance under linear constraints: the one saddle-point solve of the package.

    .. math:: \begin{pmatrix} A & G^T \\ G & 0 \end{pmatrix}
              \begin{pmatrix} x \\ \Lambda \end{pmatrix} =
              \begin{pmatrix} f \\ c \end{pmatrix}

    The transition formulations solve it for the velocity jump (f = 0); the constrained
    dynamics of a phase for the accelerations (f = tau - b).

    Args:
        A: Mass matrix of the formulation (M, M_ff or F1^T M F1), shape (k, k).
        G: Constraint rows (J+, J2 N, J2 F1 or J_f), shape (m, k).
        c: Right-hand side of the constraint rows, shape (m,).
        name: What is solved, for the error message (``"KKT transition"``).
        f: Right-hand side of the balance, shape (k,); zero if None.

    Returns:
        ``(x, Lambda)``: the solution in the formulation's coordinates and the multipliers
        (impulses or forces).

    Raises:
        TransitionError: The matrix is singular (redundant constraints).
    """
    k, m = A.shape[0], G.shape[0]
    K = np.zeros((k + m, k + m))
    K[:k, :k] = A
    K[:k, k:] = G.T
    K[k:, :k] = G
    top = np.zeros(k) if f is None else f
    try:
        x = np.linalg.solve(K, np.concatenate([top, c]))
    except np.linalg.LinAlgError as exc:
        raise TransitionError(f"{name}: singular system, the constraints are redundant") from exc
    return x[:k], x[k:]
