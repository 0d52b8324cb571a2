"""Classical fourth-order Runge-Kutta with a fixed step, shortened to land on the interval end."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .base import DEFAULT_MAX_STEPS, Rhs, Segment, StateEvent
from .fixed_step import integrate_fixed


@dataclass(frozen=True)
class RK4:
    """Classical RK4, global error O(dt^4); 4 right-hand sides per step.

    Attributes:
        dt: Step size [s]. The last step of an interval is shortened so that it ends exactly on
            the interval's end (the next time event); the grid restarts at every event.
        event_tol: Absolute tolerance of state-event times [s].
        max_steps: Most steps of one interval; a longer one is refused before it starts.
    """

    dt: float
    event_tol: float = 1e-14
    max_steps: int = DEFAULT_MAX_STEPS
    name: str = "rk4"

    def integrate(
        self,
        f: Rhs,
        t0: float,
        y0: np.ndarray,
        t1: float,
        events: Sequence[StateEvent] = (),
        n_q: int = 0,
    ) -> Segment:
        """Integrate y' = f(t, y) from ``t0`` to ``t1`` [s], stopping at the first state event."""
        return integrate_fixed(
            _step, self.dt, self.event_tol, f, t0, y0, t1, events, 4, self.max_steps, self.name
        )


def _step(f: Rhs, t: float, y: np.ndarray, k1: np.ndarray, h: float) -> np.ndarray:
    """One classical RK4 step of length h from (t, y), with k1 = f(t, y) given."""
    k2 = f(t + 0.5 * h, y + 0.5 * h * k1)
    k3 = f(t + 0.5 * h, y + 0.5 * h * k2)
    k4 = f(t + h, y + h * k3)
    return y + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
