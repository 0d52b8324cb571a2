"""Semi-implicit (symplectic) Euler with a fixed step: v first, then q with the new v.

For y = (q, v, w) with q' = v, v' = a(t, q, v) and extra quadratures w' = c(t, q, v):
v+ = v + h a, q+ = q + h v+, w+ = w + h c. First order; for a conservative system it keeps the
energy error bounded (O(h), oscillating) over long horizons instead of drifting.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .base import DEFAULT_MAX_STEPS, Rhs, Segment, StateEvent
from .fixed_step import integrate_fixed


@dataclass(frozen=True)
class SemiImplicitEuler:
    """Symplectic Euler, global error O(dt); 1 right-hand side per step.

    Attributes:
        dt: Step size [s], shortened before each event as for RK4.
        event_tol: Absolute tolerance of state-event times [s].
        max_steps: Most steps of one interval; a longer one is refused before it starts.
    """

    dt: float
    event_tol: float = 1e-14
    max_steps: int = DEFAULT_MAX_STEPS
    name: str = "euler"

    def integrate(
        self,
        f: Rhs,
        t0: float,
        y0: np.ndarray,
        t1: float,
        events: Sequence[StateEvent] = (),
        n_q: int = 0,
    ) -> Segment:
        """Integrate from ``t0`` to ``t1`` [s]; y[:n_q] are positions, y[n_q:2 n_q] their rates."""

        def step(f: Rhs, t: float, y: np.ndarray, fy: np.ndarray, h: float) -> np.ndarray:
            out = y + h * fy
            out[:n_q] = y[:n_q] + h * out[n_q : 2 * n_q]
            return out

        return integrate_fixed(
            step, self.dt, self.event_tol, f, t0, y0, t1, events, 1, self.max_steps, self.name
        )
