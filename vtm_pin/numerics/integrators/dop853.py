"""Adaptive Dormand-Prince 8(5,3) with error control and dense output (Hairer's DOP853).

A lean driver around the Dormand-Prince tables of :mod:`.dop853_coefficients`: the same
method as scipy's ``solve_ivp(method="DOP853")`` without the per-step bookkeeping of its solver
objects, and with the 7th-order dense output built only for steps that need it: those in which
a state event fires and, with ``output_dt``, those that contain an output time. Every interval
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
from . import dop853_coefficients as coef
from .base import DEFAULT_MAX_STEPS, Rhs, RhsInto, Segment, StateEvent, writer
from .fixed_step import locate

_SAFETY, _MIN_FACTOR, _MAX_FACTOR = 0.9, 0.2, 10.0
_EXPONENT = -1.0 / 8.0
_S = coef.N_STAGES  # 12 stages; K[12] is f at the step end (first same as last)
_A, _B, _C = coef.A[:_S, :_S], coef.B, coef.C[:_S]
_E3, _E5, _D = coef.E3, coef.E5, coef.D
#: The stages' weights, then the solution's, one row each (h times them per step).
_AB = np.vstack((_A, _B))
_A_EXTRA, _C_EXTRA = coef.A[_S + 1 :], coef.C[_S + 1 :]
_N_EXTRA = _A_EXTRA.shape[0]  # 3 more evaluations of f for the dense output of a step

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
        work = free.pop() if free else _Work(y0.size)
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
        work: _Work,
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
            h = min(h, self.max_step)
            last = t + h >= t1 - 1e-14 * max(1.0, abs(t1))
            if last:
                h = t1 - t
            y_new, err = self._step(into, t, y, h, work)
            f_new = K[_S]
            evals += _S
            if not err <= 1.0:  # also a NaN error: a step through non-finite derivatives
                h *= max(_MIN_FACTOR, _SAFETY * err**_EXPONENT) if math.isfinite(err) else 0.2
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
                    return Segment(np.array(ts), np.array(ys), evals + _N_EXTRA, index, accepted)
                g_prev = g_new
            if grid is not None and grid.due(t_new):
                grid.sample(self._dense(into, t, y, y_new, h, K), t, t_new, ts, ys)
                evals += _N_EXTRA
            factor = _MAX_FACTOR if err == 0.0 else min(_MAX_FACTOR, _SAFETY * err**_EXPONENT)
            if rejected:
                factor = min(1.0, factor)
            rejected = False
            t, y = t_new, y_new
            fy[:] = f_new
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
        if h < 10.0 * abs(np.nextafter(t, math.inf) - t):
            reason = (
                "the derivatives are not finite there"
                if not np.all(np.isfinite(fy))
                else f"rtol = {self.rtol:g}, atol = {self.atol:g} cannot be met there"
            )
            raise SimulationError(
                f"dop853: the step fell to {h:.3g} s at t = {t:.6g} s, below the round-off of "
                f"t; {reason} (a singular or extremely stiff motion)"
            )

    def _scale(self, y: np.ndarray, y_new: np.ndarray) -> np.ndarray:
        return self.atol + self.rtol * np.maximum(np.abs(y), np.abs(y_new))

    def _first_step(
        self, f: Rhs, t: float, y: np.ndarray, fy: np.ndarray, span: float
    ) -> tuple[float, int]:
        """Hairer's initial step guess (2 evaluations of f on the way)."""
        scale = self.atol + self.rtol * np.abs(y)
        d0 = _rms(y / scale)
        d1 = _rms(fy / scale)
        h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
        h0 = min(h0, span)
        f1 = f(t + h0, y + h0 * fy)
        d2 = _rms((f1 - fy) / scale) / h0
        if d1 <= 1e-15 and d2 <= 1e-15:
            h1 = max(1e-6, h0 * 1e-3)
        else:
            h1 = (0.01 / max(d1, d2)) ** (1.0 / 8.0)
        return min(100.0 * h0, h1, span, self.max_step), 1

    def _step(
        self, into: RhsInto, t: float, y: np.ndarray, h: float, work: _Work
    ) -> tuple[np.ndarray, float]:
        """One step from y, with f(t, y) in K[0]: the new state and the scaled error norm.

        f at the new state is left in K[12] (first same as last); the error norm is <= 1 to
        accept the step.
        """
        # Each stage state is one product y + (h A[s]) @ K = (1, h A[s]) @ (y, K), with the
        # rows (1, h A[s]) scaled once per step (work.hAB), and the right-hand side writes
        # the stage's slope into K[s] itself: per stage one NumPy call and f. scipy groups
        # the same sum as y + (A[s] @ K) h (three calls); the two agree to round-off, but the
        # error estimate below is a difference of stages, so at tight tolerances that
        # round-off moves the step sizes in their last few digits (tests/test_integrators.py).
        K = work.K
        work.Y[0] = y
        np.multiply(_AB, h, out=work.hAB)
        for row, before, k, c in work.stages:
            into(t + c * h, row.dot(before), k)
        y_new = work.solution.dot(work.Y[: _S + 1])
        into(t + h, y_new, K[_S])
        scale = self._scale(y, y_new)
        Kn = K[: _S + 1]
        err5 = _E5.dot(Kn) / scale
        err3 = _E3.dot(Kn) / scale
        e5, e3 = float(err5.dot(err5)), float(err3.dot(err3))
        if e5 == 0.0 and e3 == 0.0:
            return y_new, 0.0
        return y_new, abs(h) * e5 / math.sqrt((e5 + 0.01 * e3) * y.size)

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
        for s, (a, c) in enumerate(zip(_A_EXTRA, _C_EXTRA, strict=True), start=_S + 1):
            into(t + c * h, y + h * (a[:s] @ K[:s]), K[s])
        delta = y_new - y
        F = np.empty((coef.INTERPOLATOR_POWER, y.size))
        F[0] = delta
        F[1] = h * K[0] - delta
        F[2] = 2.0 * delta - h * (K[_S] + K[0])
        F[3:] = h * (_D @ K)

        def dense(tau: float) -> np.ndarray:
            return y + dense_weights(tau / h).dot(F)

        return dense


def dense_weights(x: float) -> np.ndarray:
    """Weights w of a step's dense output y + w @ F at the fraction x = tau / h of the step.

    The 7th-order interpolant is y + x (F0 + (1 - x) (F1 + x (F2 + (1 - x) (F3 + ...)))):
    w = (x, x (1 - x), x^2 (1 - x), x^2 (1 - x)^2, ...), products of floats, then one product
    with F instead of seven array operations.
    """
    w, acc = [], 1.0
    for j in range(coef.INTERPOLATOR_POWER):
        acc *= x if j % 2 == 0 else 1.0 - x
        w.append(acc)
    return np.array(w)


def _free(size: int) -> list[_Work]:
    """This thread's free stage buffers for states of ``size`` (a stack)."""
    free: dict[int, list[_Work]] = _FREE.__dict__.setdefault("by_size", {})
    return free.setdefault(size, [])


class _Work:
    """The stages of one interval's steps, with each stage's operands sliced once.

    Args:
        size: Length of the state.
    """

    def __init__(self, size: int) -> None:
        #: The step's start y, then its stages K.
        self.Y = np.empty((2 + _S + _N_EXTRA, size))
        #: The stages: f at the step's start first, at its end in K[12], then the dense ones.
        self.K = self.Y[1:]
        hAB = np.ones((_S + 1, _S + 1))
        #: h times the stages' weights, then the solution's (written each step), after a
        #: column of ones that takes y into each product.
        self.hAB = hAB[:, 1:]
        #: (1, h B): the new state from (y, K).
        self.solution = hAB[_S]
        #: Per stage s: (1, h A[s]), the rows (y, K[:s]) it weighs, K[s], and c[s].
        self.stages = [
            (hAB[s, : s + 1], self.Y[: s + 1], self.K[s], float(_C[s])) for s in range(1, _S)
        ]


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


def _rms(x: np.ndarray) -> float:
    # np.linalg.norm's own sqrt(x . x) for a vector, without its call overhead
    return math.sqrt(float(x.dot(x))) / math.sqrt(x.size)
