"""Classical fourth-order Runge-Kutta with a fixed step, shortened to land on the interval end.

State events are located on the step's own continuous extension: the RK4 step of length
tau from the step's start, y(tau), is a fourth-order accurate function of tau, and g(t + tau,
y(tau)) is solved for its root with Brent's method to ``event_tol`` seconds. The event state
is therefore a point of the numerical solution itself, of the integrator's order.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.optimize

from .base import Rhs, Segment, StateEvent

#: Relative slack when counting steps, so that t1 - t0 = k dt up to round-off gives k steps.
_GRID_SLACK = 1e-9


@dataclass(frozen=True)
class RK4:
    """Classical RK4, global error O(dt^4).

    Attributes:
        dt: Step size [s]. The last step of an interval is shortened so that it ends exactly on
            the interval's end (the next time event); the grid restarts at every event.
        event_tol: Absolute tolerance of state-event times [s].
    """

    dt: float
    event_tol: float = 1e-14
    name: str = "rk4"

    def integrate(
        self,
        f: Rhs,
        t0: float,
        y0: np.ndarray,
        t1: float,
        events: Sequence[StateEvent] = (),
    ) -> Segment:
        """Integrate y' = f(t, y) from ``t0`` to ``t1`` [s], stopping at the first state event."""
        span = t1 - t0
        steps = max(math.ceil(span / self.dt - _GRID_SLACK), 0) if span > 0 else 0
        t = np.empty(steps + 1)
        y = np.empty((steps + 1, y0.size))
        t[0] = t0
        y[0] = y0
        evals = 0
        g_prev = [e.g(t0, y0) for e in events]
        for k in range(steps):
            tk = t[k]
            t_next = t1 if k == steps - 1 else t0 + (k + 1) * self.dt
            yk = y[k]
            k1 = f(tk, yk)
            y[k + 1] = _step(f, tk, yk, k1, t_next - tk)
            t[k + 1] = t_next
            evals += 4
            if not events:
                continue
            g_next = [e.g(t_next, y[k + 1]) for e in events]
            fired = [i for i, e in enumerate(events) if e.crossed(g_prev[i], g_next[i])]
            if fired:
                tau, index, located = self._locate(f, events, fired, tk, yk, k1, t_next - tk)
                evals += located
                t[k + 1] = tk + tau
                y[k + 1] = _step(f, tk, yk, k1, tau)
                return Segment(t=t[: k + 2], y=y[: k + 2], rhs_evals=evals, event=index)
            g_prev = g_next
        return Segment(t=t, y=y, rhs_evals=evals)

    def _locate(
        self,
        f: Rhs,
        events: Sequence[StateEvent],
        fired: list[int],
        tk: float,
        yk: np.ndarray,
        k1: np.ndarray,
        h: float,
    ) -> tuple[float, int, int]:
        """Earliest root among the fired events: (step length to it, event index, rhs evals)."""
        calls = 0
        best: tuple[float, int] | None = None
        for i in fired:
            event = events[i]

            def phi(tau: float, event: StateEvent = event) -> float:
                nonlocal calls
                calls += 3
                return event.g(tk + tau, _step(f, tk, yk, k1, tau))

            g0 = event.g(tk, yk)
            g1 = phi(h)
            if g1 == 0.0 or g0 == 0.0:
                tau = h if g1 == 0.0 else 0.0
            else:
                tau = scipy.optimize.brentq(phi, 0.0, h, xtol=self.event_tol, rtol=1e-15)
                # Take the side of the bracket where the crossing has happened.
                while not event.crossed(g0, phi(tau)) and tau < h:
                    tau = min(h, tau + self.event_tol)
            if best is None or tau < best[0]:
                best = (tau, i)
        assert best is not None
        return best[0], best[1], calls


def _step(f: Rhs, t: float, y: np.ndarray, k1: np.ndarray, h: float) -> np.ndarray:
    """One classical RK4 step of length h from (t, y), with k1 = f(t, y) given."""
    k2 = f(t + 0.5 * h, y + 0.5 * h * k1)
    k3 = f(t + 0.5 * h, y + 0.5 * h * k2)
    k4 = f(t + h, y + h * k3)
    return y + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
