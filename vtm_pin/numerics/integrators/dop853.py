"""Adaptive Dormand-Prince 8(5,3) with error control and dense output (Hairer's DOP853).

A lean driver around the Dormand-Prince step of :mod:`.dormand_prince` (one lane of it; the
batched engine steps many with the same code): the same method as scipy's
``solve_ivp(method="DOP853")`` without the per-step bookkeeping of its solver objects, and
with the 7th-order dense output built only for steps that need it: those in which a state
event fires and, with ``output_dt``, those that contain an output time. Every interval
ends exactly on its end time (the next time event); a state event is located on the dense
output with Brent's method and the next interval restarts from it.

With ``output_dt`` the samples of an interval are its start, the dense output at the global
grid times k output_dt (k whole, from t = 0, so that intervals restarted at events share one
grid) strictly inside it, and its end: the accepted steps are left out, the step choice (hence
the solution) is the same as without it, and the last sample is still the state reached.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ...exceptions import SimulationError, StepLimitError
from . import dormand_prince as dp
from .base import DEFAULT_MAX_STEPS, Rhs, RhsInto, Segment, StateEvent, writer
from .dormand_prince import dense_weights as dense_weights  # (re-exported)
from .fixed_step import locate

_ONE = dp.ONE_LANE

#: Per thread, the free stage buffers of each state size (:func:`_free`).
_FREE = threading.local()

#: Output times closer than this fraction of ``output_dt`` to an interval's start or end are
#: that start or end (a grid time that is an event time up to round-off, 0.08 vs 80 x 0.001).
GRID_SLACK = 1e-9

#: The continuous solution of one step as a function of the offset tau [s] from its start.
Dense = Callable[[float], np.ndarray]


@dataclass(frozen=True)
class DOP853:
    """Adaptive 8th-order Runge-Kutta, local error kept below atol + rtol |y|.

    Attributes:
        rtol: Relative tolerance [-].
        atol: Absolute tolerance [rad, rad/s, J, N m s: state units].
        max_step: Largest step [s].
        event_tol: Absolute tolerance of state-event times [s].
        max_steps: Most steps (accepted and rejected) of one interval: past it the
            integration stops with :class:`~vtm_pin.exceptions.StepLimitError`.
        output_dt: Sampling period of the output [s]: each segment holds the dense output
            at the times k output_dt (k whole) strictly inside it, plus its start and end,
            instead of the accepted steps. None: the accepted steps.
    """

    rtol: float = 1e-8
    atol: float = 1e-10
    max_step: float = math.inf
    event_tol: float = 1e-14
    max_steps: int = DEFAULT_MAX_STEPS
    output_dt: float | None = None
    name: str = "dop853"

    def __post_init__(self) -> None:
        """Refuse an output period that is not a finite positive time.

        Raises:
            ValueError: ``output_dt`` is zero, negative or not finite.
        """
        if self.output_dt is not None and not 0.0 < self.output_dt < math.inf:
            raise ValueError(f"output_dt = {self.output_dt} must be a finite time > 0 s")

    def integrate(
        self,
        f: Rhs,
        t0: float,
        y0: np.ndarray,
        t1: float,
        events: Sequence[StateEvent] = (),
        n_q: int = 0,
    ) -> Segment:
        """Integrate y' = f(t, y) from ``t0`` to ``t1`` [s], stopping at the first state event.

        Raises:
            StepLimitError: More than ``max_steps`` steps were needed.
            SimulationError: The step fell below the round-off of t (the derivatives are not
                finite, or the tolerances cannot be met).
        """
        grid = None if self.output_dt is None else _Grid(self.output_dt, t0, t1)
        if y0.size == 0 or t1 <= t0:  # nothing moves: counted as one step, as ever
            times = [t0, *(grid.remaining() if grid is not None else ()), max(t0, t1)]
            return Segment(
                t=np.array(times), y=np.zeros((len(times), y0.size)) + y0, rhs_evals=0, n_steps=1
            )
        # This thread's free stage buffers for the state size, held until the interval ends,
        # so that an integration nested in a right-hand side or an event gets its own.
        free = _free(y0.size)
        work = free.pop() if free else dp.Stages(y0.size)
        try:
            return self._integrate(f, t0, y0, t1, events, grid, work)
        finally:
            free.append(work)

    def _integrate(
        self,
        f: Rhs,
        t0: float,
        y0: np.ndarray,
        t1: float,
        events: Sequence[StateEvent],
        grid: _Grid | None,
        work: dp.Stages,
    ) -> Segment:
        """:meth:`integrate` of an interval in which something moves, with its buffers."""
        K, into = work.K, writer(f)
        ts, ys = [t0], [y0]
        t, y = t0, y0
        fy = K[0]  # f at the step's start, kept in the first stage
        into(t, y, fy)
        h, extra = self._first_step(f, t, y, fy, t1 - t0)
        evals = 1 + extra
        g_prev = [e.g(t, y) for e in events]
        rejected = False
        steps = accepted = 0
        while t < t1:
            steps += 1
            self._check_steps(steps, t0, t, t1)
            h, last = dp.clamp(t, t1, h, self.max_step, _ONE)
            y_new = dp.step(into, t, y, h, work)
            err = dp.error_norm(y, y_new, h, K, self.rtol, self.atol, _ONE, y.size)
            evals += dp.S
            if not err <= 1.0:  # also a NaN error: a step through non-finite derivatives
                h *= dp.shrink(err, _ONE)
                self._check_round_off(t, h, fy)
                rejected = True
                continue
            accepted += 1
            t_new = t1 if last else t + h
            if events:
                g_new = [e.g(t_new, y_new) for e in events]
                fired = [i for i, e in enumerate(events) if e.crossed(g_prev[i], g_new[i])]
                if fired:
                    dense = self._dense(into, t, y, y_new, h, K)
                    tau, index = locate(events, fired, t, y, dense, h, self.event_tol)
                    if grid is not None:
                        grid.sample(dense, t, t + tau - grid.slack, ts, ys)
                    ts.append(t + tau)
                    ys.append(dense(tau))
                    return Segment(np.array(ts), np.array(ys), evals + dp.N_EXTRA, index, accepted)
                g_prev = g_new
            if grid is not None and grid.due(t_new):
                grid.sample(self._dense(into, t, y, y_new, h, K), t, t_new, ts, ys)
                evals += dp.N_EXTRA
            factor = dp.grow(err, rejected, _ONE)
            rejected = False
            t, y = t_new, y_new
            fy[:] = work.f_new
            if grid is None or last:
                ts.append(t)
                ys.append(y)
            h *= factor
        return Segment(np.array(ts), np.array(ys), evals, n_steps=accepted)

    def _check_steps(self, steps: int, t0: float, t: float, t1: float) -> None:
        """Stop an interval that needs more than ``max_steps`` steps."""
        if steps > self.max_steps:
            raise StepLimitError(
                f"dop853 took {self.max_steps} steps from t = {t0:g} s and reached only "
                f"t = {t:.6g} s of {t1:g} s; the limit is {self.max_steps}: set "
                "integrator.max_steps, or loosen rtol / atol",
                steps,
                self.max_steps,
            )

    def _check_round_off(self, t: float, h: float, fy: np.ndarray) -> None:
        """Stop when a rejected step shrinks below the round-off of t (as scipy does)."""
        if dp.too_small(t, h):
            reason = (
                "the derivatives are not finite there"
                if not np.all(np.isfinite(fy))
                else f"rtol = {self.rtol:g}, atol = {self.atol:g} cannot be met there"
            )
            raise SimulationError(
                f"dop853: the step fell to {h:.3g} s at t = {t:.6g} s, below the round-off of "
                f"t; {reason} (a singular or extremely stiff motion)"
            )

    def _first_step(
        self, f: Rhs, t: float, y: np.ndarray, fy: np.ndarray, span: float
    ) -> tuple[float, int]:
        """Hairer's initial step guess (1 more evaluation of f)."""
        tolerances = (self.rtol, self.atol, self.max_step)
        return dp.first_step(f, t, y, fy, span, tolerances, _ONE, y.size), 1

    def _dense(
        self,
        into: RhsInto,
        t: float,
        y: np.ndarray,
        y_new: np.ndarray,
        h: float,
        K: np.ndarray,
    ) -> Dense:
        """The step's 7th-order continuous extension, as a function of the offset tau [s].

        K holds the step's stages, f at its start in K[0] and at its end in K[12].
        """
        F = dp.dense_coefficients(into, t, y, y_new, h, K, _ONE)

        def dense(tau: float) -> np.ndarray:
            return dp.dense_value(F, tau / h, y, _ONE)

        return dense


def _free(size: int) -> list[dp.Stages]:
    """This thread's free stage buffers for states of ``size`` (a stack)."""
    free: dict[int, list[dp.Stages]] = _FREE.__dict__.setdefault("by_size", {})
    return free.setdefault(size, [])


class _Grid:
    """The output times k ``dt`` strictly inside one interval [t0, t1], taken in order.

    Attributes:
        dt: Output period [s].
        slack: Times this close to t0 or t1 [s] are left to the interval's own samples.
        k: Index of the next output time.
        end: Latest output time [s]: t1 - slack.
    """

    def __init__(self, dt: float, t0: float, t1: float) -> None:
        self.dt = dt
        self.slack = GRID_SLACK * dt
        start = t0 + self.slack
        k = math.floor(start / dt) + 1
        while (k - 1) * dt > start:  # floor of a quotient rounded up past a whole number
            k -= 1
        while k * dt <= start:
            k += 1
        self.k = k
        self.end = t1 - self.slack

    def due(self, t_new: float) -> bool:
        """Whether an output time falls in a step ending at ``t_new`` [s]."""
        return self.k * self.dt <= min(t_new, self.end)

    def sample(
        self, dense: Dense, t: float, until: float, ts: list[float], ys: list[np.ndarray]
    ) -> None:
        """Append the output times up to ``until`` [s] and ``dense`` there (a step from t)."""
        limit = min(until, self.end)
        while (time := self.k * self.dt) <= limit:
            ts.append(time)
            ys.append(dense(time - t))
            self.k += 1

    def remaining(self) -> list[float]:
        """All the output times left [s] (an interval in which nothing moves)."""
        times = []
        while (time := self.k * self.dt) <= self.end:
            times.append(time)
            self.k += 1
        return times
