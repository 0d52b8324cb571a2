"""Classical fourth-order Runge-Kutta with a fixed step, shortened to land on the interval end."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .base import Rhs, Segment

#: Relative slack when counting steps, so that t1 - t0 = k dt up to round-off gives k steps.
_GRID_SLACK = 1e-9


@dataclass(frozen=True)
class RK4:
    """Classical RK4, global error O(dt^4).

    Attributes:
        dt: Step size [s]. The last step of an interval is shortened so that it ends exactly on
            the interval's end (the next event); the grid restarts at every event.
    """

    dt: float
    name: str = "rk4"

    def integrate(self, f: Rhs, t0: float, y0: np.ndarray, t1: float) -> Segment:
        """Integrate y' = f(t, y) from ``t0`` to exactly ``t1`` [s]."""
        span = t1 - t0
        steps = max(math.ceil(span / self.dt - _GRID_SLACK), 0) if span > 0 else 0
        t = np.empty(steps + 1)
        y = np.empty((steps + 1, y0.size))
        t[0] = t0
        y[0] = y0
        dt = self.dt
        for k in range(steps):
            tk = t[k]
            t_next = t1 if k == steps - 1 else t0 + (k + 1) * dt
            h = t_next - tk
            yk = y[k]
            k1 = f(tk, yk)
            k2 = f(tk + 0.5 * h, yk + 0.5 * h * k1)
            k3 = f(tk + 0.5 * h, yk + 0.5 * h * k2)
            k4 = f(t_next, yk + h * k3)
            y[k + 1] = yk + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            t[k + 1] = t_next
        return Segment(t=t, y=y, rhs_evals=4 * steps)
