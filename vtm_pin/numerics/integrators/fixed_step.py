"""Fixed-step driver: a step grid landing on the interval end, state events on the step itself.

A one-step method's step of length tau from (t_k, y_k) is a continuous function y(tau) of the
method's own order, so g(t_k + tau, y(tau)) = 0 is solved for tau with Brent's method to
``event_tol`` seconds. The event state is a point of the numerical solution itself.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import scipy.optimize

from ...exceptions import StepLimitError
from .base import DEFAULT_MAX_STEPS, Rhs, Segment, StateEvent, steps_text

#: Relative slack when counting steps, so that t1 - t0 = k dt up to round-off gives k steps.
_GRID_SLACK = 1e-9

#: One step: (f, t, y, f(t, y), h) -> y after a step of length h.
Step = Callable[[Rhs, float, np.ndarray, np.ndarray, float], np.ndarray]


def integrate_fixed(
    step: Step,
    dt: float,
    event_tol: float,
    f: Rhs,
    t0: float,
    y0: np.ndarray,
    t1: float,
    events: Sequence[StateEvent],
    evals_per_step: int,
    max_steps: int = DEFAULT_MAX_STEPS,
    name: str = "fixed-step",
) -> Segment:
    """Integrate with a fixed step ``dt`` from ``t0`` to exactly ``t1`` or the first event.

    Raises:
        StepLimitError: The interval needs more than ``max_steps`` steps (refused up front).
    """
    span = t1 - t0
    if y0.size == 0:  # everything locked: the state is frozen
        return Segment(t=np.array([t0, t1]), y=np.zeros((2, 0)), rhs_evals=0)
    needed = span / dt - _GRID_SLACK if span > 0 else 0.0
    if needed > max_steps:
        raise StepLimitError(
            f"{name} with dt = {dt:g} s would take {steps_text(needed)} steps from t = {t0:g} s to "
            f"{t1:g} s; the limit is {max_steps}: set integrator.max_steps, or a larger dt",
            needed,
            max_steps,
        )
    steps = max(math.ceil(needed), 1) if span > 0 else 0  # an interval shorter than dt: 1 step
    t = np.empty(steps + 1)
    y = np.empty((steps + 1, y0.size))
    t[0] = t0
    y[0] = y0
    evals = 0
    g_prev = [e.g(t0, y0) for e in events]
    for k in range(steps):
        tk = t[k]
        t_next = t1 if k == steps - 1 else t0 + (k + 1) * dt
        yk = y[k]
        fk = f(tk, yk)
        y[k + 1] = step(f, tk, yk, fk, t_next - tk)
        t[k + 1] = t_next
        evals += evals_per_step
        if not events:
            continue
        g_next = [e.g(t_next, y[k + 1]) for e in events]
        fired = [i for i, e in enumerate(events) if e.crossed(g_prev[i], g_next[i])]
        if fired:

            def along(
                tau: float, tk: float = tk, yk: np.ndarray = yk, fk: np.ndarray = fk
            ) -> np.ndarray:
                nonlocal evals
                evals += evals_per_step - 1
                return step(f, tk, yk, fk, tau)

            tau, index = locate(events, fired, tk, yk, along, t_next - tk, event_tol)
            t[k + 1] = tk + tau
            y[k + 1] = along(tau)
            return Segment(t=t[: k + 2], y=y[: k + 2], rhs_evals=evals, event=index)
        g_prev = g_next
    return Segment(t=t, y=y, rhs_evals=evals)


def locate(
    events: Sequence[StateEvent],
    fired: list[int],
    tk: float,
    yk: np.ndarray,
    along: Callable[[float], np.ndarray],
    h: float,
    event_tol: float,
) -> tuple[float, int]:
    """Earliest root in (0, h] among the events, on the continuous solution ``along``.

    The fired events (crossed between the step's ends) are located first. Then every event
    is checked at the earliest root found: one that has already crossed there (it crossed
    and came back within the step, say a stuck joint whose load spikes while another joint
    comes to rest) has an earlier root, which is located in turn.

    Returns:
        ``(tau, index)``: the offset from ``tk`` [s], on the side where the crossing has
        happened, and the event's index.
    """
    g0 = [event.g(tk, yk) for event in events]
    best = min((_root(events[i], g0[i], tk, along, h, event_tol), i) for i in fired)
    for _ in range(len(events)):
        y_best = along(best[0])
        earlier = [
            i
            for i, event in enumerate(events)
            if i != best[1] and event.crossed(g0[i], event.g(tk + best[0], y_best))
        ]
        if not earlier:
            return best
        best = min(
            [best, *((_root(events[i], g0[i], tk, along, best[0], event_tol), i) for i in earlier)]
        )
    return best


def _root(
    event: StateEvent,
    g0: float,
    tk: float,
    along: Callable[[float], np.ndarray],
    h: float,
    event_tol: float,
) -> float:
    """The offset [s] in (0, h] where ``event`` crosses, on the side after the crossing."""

    def phi(tau: float) -> float:
        return event.g(tk + tau, along(tau))

    g1 = phi(h)
    start = _departure(event, phi, h) if g0 == 0.0 else 0.0
    if g1 == 0.0:
        return h
    if start is None:
        # It left zero straight for the far side: the handler's state disagrees with the
        # motion from the start, so take the event at once (the smallest step that still
        # advances t), not after a whole step of wrong motion.
        return min(h, max(event_tol, 8.0 * float(np.spacing(abs(tk) + h))))
    tau = float(scipy.optimize.brentq(phi, start, h, xtol=event_tol, rtol=1e-15))
    while not event.crossed(g0, phi(tau)) and tau < h:
        tau = min(h, tau + event_tol)
    return tau


def _departure(event: StateEvent, phi: Callable[[float], float], h: float) -> float | None:
    """A point where ``phi``, 0 at the start, is before the crossing; None if none is found.

    Searched at h / 2, h / 4, ... down to 2^-60 h: a function that leaves zero with a
    non-zero slope is on its side at some of them.
    """
    for k in range(1, 61):
        tau = h * 0.5**k
        if event.before(phi(tau)):
            return tau
    return None
