"""One Dormand-Prince 8(5,3) step with its step-size control and dense output, over lanes.

The one copy of the method that both engines step with: the scalar engine
(:class:`~vtm_pin.numerics.integrators.DOP853`) and the batched one (:mod:`vtm_pin.core.batch`),
which advances many runs (lanes) at once, each with its own time, step size and error. The
functions take either one lane, a state vector of shape (n,) with times and steps [s] as
Python floats, or many, states of shape (lanes, n) with times and steps of shape (lanes,).
The formulas are written once; what differs is only how an array operation is spelled for
each (:class:`_OneLane`, :class:`_Lanes`), so that one lane pays no NumPy call for a float.

The method and its controller are Hairer's DOP853 (scipy's ``solve_ivp(method="DOP853")``):
tables from :mod:`.dop853_coefficients`, the error norm of the 5th- and 3rd-order estimates,
the step factor 0.9 err^(-1/8) between 0.2 and 10 (at most 1 right after a rejection), and
the 7th-order continuous extension of a step from 3 more evaluations of the right-hand side.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from . import dop853_coefficients as coef

SAFETY, MIN_FACTOR, MAX_FACTOR = 0.9, 0.2, 10.0
EXPONENT = -1.0 / 8.0
S = coef.N_STAGES  # 12 stages; K[12] is f at the step end (first same as last)
A, B, C = coef.A[:S, :S], coef.B, coef.C[:S]
E3, E5, D = coef.E3, coef.E5, coef.D
#: The stages' weights, then the solution's, one row each (h times them per step).
AB = np.vstack((A, B))
A_EXTRA, C_EXTRA = coef.A[S + 1 :], coef.C[S + 1 :]
N_EXTRA = A_EXTRA.shape[0]  # 3 more evaluations of f for the dense output of a step
#: Floor of the error norm's denominator and of an error raised to the -1/8: a zero error
#: (a step with nothing to estimate) then gives a zero norm and the largest factor, as a
#: branch would, with the same formula for one lane and many.
_TINY = float(np.finfo(float).tiny)

#: y' = f(t, y) writing f into its third argument: (t, y, out) -> None, one lane or many.
Into = Callable[[Any, np.ndarray, np.ndarray], None]


class _OneLane:
    """One lane: a state vector (n,), times, steps and norms as Python floats."""

    minimum = staticmethod(min)
    maximum = staticmethod(max)
    sqrt = staticmethod(math.sqrt)
    isfinite = staticmethod(math.isfinite)

    @staticmethod
    def where(condition: bool, a: float, b: float) -> float:
        return a if condition else b

    @staticmethod
    def col(h: float, dims: int = 1) -> float:
        """``h`` to multiply a state (or ``dims`` trailing axes of them)."""
        return h

    @staticmethod
    def weigh(w: np.ndarray, K: np.ndarray) -> np.ndarray:
        """sum_s w[s] K[s]: weights of the stages K, shape (s, n)."""
        return w.dot(K)

    @staticmethod
    def sumsq(x: np.ndarray, active: np.ndarray | None) -> float:
        """The dot product x . x over the whole state."""
        return float(x.dot(x))

    @staticmethod
    def combine(w: np.ndarray, F: np.ndarray) -> np.ndarray:
        """The product w @ F: weights (j,) of the rows of F (j, n)."""
        return w.dot(F)


class _Lanes:
    """Many lanes: states (lanes, n), times, steps and norms (lanes,)."""

    minimum = staticmethod(np.minimum)
    maximum = staticmethod(np.maximum)
    sqrt = staticmethod(np.sqrt)
    isfinite = staticmethod(np.isfinite)
    where = staticmethod(np.where)

    @staticmethod
    def col(h: np.ndarray, dims: int = 1) -> np.ndarray:
        return h.reshape((-1,) + (1,) * dims)

    @staticmethod
    def weigh(w: np.ndarray, K: np.ndarray) -> np.ndarray:
        """Per lane sum_s w[s] K[lane, s]: K of shape (lanes, s, n)."""
        return np.matmul(w, K)

    @staticmethod
    def sumsq(x: np.ndarray, active: np.ndarray | None) -> np.ndarray:
        """Per lane x . x over its ``active`` entries (all without)."""
        if active is not None:
            x = np.where(active, x, 0.0)
        return np.einsum("bi,bi->b", x, x)

    @staticmethod
    def combine(w: np.ndarray, F: np.ndarray) -> np.ndarray:
        """Per lane w[lane] @ F[lane]: weights (lanes, j), rows F (lanes, j, n)."""
        return np.einsum("bj,bji->bi", w, F)


ONE_LANE, LANES = _OneLane(), _Lanes()
#: :data:`ONE_LANE` or :data:`LANES` (their members, builtins or NumPy functions, are typed
#: differently, so the functions below take either as Any).
Ops = Any


class _LaneRows:
    """Per lane the product of a row (lanes, 1, k) with its rows (lanes, k, n): (lanes, n)."""

    def __init__(self, row: np.ndarray) -> None:
        self.row = row

    def __call__(self, rows: np.ndarray) -> np.ndarray:
        return np.matmul(self.row, rows)[:, 0]


class Stages:
    """The buffers of one step of one lane or many, with each stage's operands sliced once.

    Args:
        size: Length of a state.
        lanes: Number of lanes; None for one lane of plain vectors (the scalar engine).

    Attributes:
        ops: How an operation is spelled for these lanes (:data:`ONE_LANE` or :data:`LANES`).
        Y: The step's start y, then its stages K, shape (2 + 12 + 3, size) per lane.
        K: The stages: f at the step's start first, at its end in K[12], then the dense ones.
        f_new: K[12], f at the step's end.
    """

    def __init__(self, size: int, lanes: int | None = None) -> None:
        Y = np.empty((lanes or 1, 2 + S + N_EXTRA, size))
        hAB = np.ones((lanes or 1, S + 1, S + 1))
        if lanes is None:
            Y, hAB = Y[0], hAB[0]
        self.ops: Ops = ONE_LANE if lanes is None else LANES
        self.Y = Y
        self.start = Y[..., 0, :]
        self.K = Y[..., 1:, :]
        self.f_new = self.K[..., S, :]
        #: h times the stages' weights, then the solution's (written each step), after a
        #: column of ones that takes y into each product.
        self.hAB = hAB[..., 1:]
        #: Per stage s: the product with (1, h A[s]), the rows (y, K[:s]) it weighs, K[s] and
        #: c[s]; then the new state's product with (1, h B) and its rows (y, K[:12]).
        self.stages = [
            (self._product(hAB, s), Y[..., : s + 1, :], self.K[..., s, :], float(C[s]))
            for s in range(1, S)
        ]
        self.solution = (self._product(hAB, S), Y[..., : S + 1, :])

    @staticmethod
    def _product(hAB: np.ndarray, s: int) -> Callable[[np.ndarray], np.ndarray]:
        if hAB.ndim == 2:  # one lane: one dot of the row (1, h A[s]) with (y, K[:s])
            return hAB[s, : s + 1].dot
        return _LaneRows(hAB[:, s : s + 1, : s + 1])


def step(into: Into, t: Any, y: np.ndarray, h: Any, work: Stages) -> np.ndarray:
    """One step from y, with f(t, y) in ``work.K[..., 0, :]``: the new state.

    f at the new state is left in ``work.f_new`` (first same as last).

    Args:
        into: The right-hand side, writing into its last argument.
        t: Start time(s) [s].
        y: Start state(s).
        h: Step(s) [s].
        work: The step's buffers.
    """
    # Each stage state is one product y + (h A[s]) @ K = (1, h A[s]) @ (y, K), with the
    # rows (1, h A[s]) scaled once per step (work.hAB), and the right-hand side writes
    # the stage's slope into K[s] itself: per stage one NumPy call and f. scipy groups
    # the same sum as y + (A[s] @ K) h (three calls); the two agree to round-off, but the
    # error estimate is a difference of stages, so at tight tolerances that round-off
    # moves the step sizes in their last few digits (tests/test_integrators.py).
    work.start[...] = y
    np.multiply(AB, work.ops.col(h, 2), out=work.hAB)
    for product, rows, k, c in work.stages:
        into(t + c * h, product(rows), k)
    product, rows = work.solution
    y_new = product(rows)
    into(t + h, y_new, work.f_new)
    return y_new


def error_norm(
    y: np.ndarray,
    y_new: np.ndarray,
    h: Any,
    K: np.ndarray,
    rtol: float,
    atol: float,
    ops: Ops,
    count: Any,
    active: np.ndarray | None = None,
) -> Any:
    """The step's scaled error norm: <= 1 to accept it (NaN for non-finite stages).

    Args:
        y: Start state(s).
        y_new: New state(s).
        h: Step(s) [s].
        K: The step's stages, at least the 13 of the step (f at its end last).
        rtol: Relative tolerance [-].
        atol: Absolute tolerance [state units].
        ops: :data:`ONE_LANE` or :data:`LANES`.
        count: Entries of the state(s) the norm is over.
        active: Per lane, the entries the norm is over (None: all).
    """
    scale = atol + rtol * np.maximum(np.abs(y), np.abs(y_new))
    Kn = K[..., : S + 1, :]
    e5 = ops.sumsq(ops.weigh(E5, Kn) / scale, active)
    e3 = ops.sumsq(ops.weigh(E3, Kn) / scale, active)
    return abs(h) * e5 / ops.sqrt(ops.maximum((e5 + 0.01 * e3) * count, _TINY))


def clamp(t: Any, t1: Any, h: Any, max_step: float, ops: Ops) -> tuple[Any, Any]:
    """The step(s) to try from t [s] towards t1 [s], and whether each is the last one.

    A step that would end within round-off of t1 (or past it) ends exactly on t1.
    """
    h = ops.minimum(h, max_step)
    last = t + h >= t1 - 1e-14 * ops.maximum(1.0, abs(t1))
    return ops.where(last, t1 - t, h), last


def shrink(err: Any, ops: Ops) -> Any:
    """The factor of a rejected step (error norm > 1, or not finite: the smallest)."""
    return ops.where(ops.isfinite(err), ops.maximum(MIN_FACTOR, SAFETY * err**EXPONENT), MIN_FACTOR)


def grow(err: Any, rejected: Any, ops: Ops) -> Any:
    """The factor of the next step after an accepted one (at most 1 right after a rejection)."""
    largest = ops.where(rejected, 1.0, MAX_FACTOR)
    return ops.minimum(largest, SAFETY * ops.maximum(err, _TINY) ** EXPONENT)


def too_small(t: Any, h: Any) -> Any:
    """Whether a step h [s] is below the round-off of t [s] (where scipy gives up)."""
    return h < 10.0 * np.abs(np.nextafter(t, math.inf) - t)


def first_step(
    f: Callable[[Any, np.ndarray], np.ndarray],
    t: Any,
    y: np.ndarray,
    fy: np.ndarray,
    span: Any,
    tolerances: tuple[float, float, float],
    ops: Ops,
    count: Any,
    active: np.ndarray | None = None,
) -> Any:
    """Hairer's initial step guess [s] (one more evaluation of f).

    Args:
        f: The right-hand side, returning f(t, y).
        t: Start time(s) [s].
        y: Start state(s).
        fy: f(t, y).
        span: Length(s) of the interval(s) [s].
        tolerances: (rtol [-], atol [state units], max_step [s]).
        ops: :data:`ONE_LANE` or :data:`LANES`.
        count: Entries of the state(s) the norms are over.
        active: Per lane, the entries the norms are over (None: all).
    """
    rtol, atol, max_step = tolerances
    scale = atol + rtol * np.abs(y)

    def rms(x: np.ndarray) -> Any:
        return ops.sqrt(ops.sumsq(x, active)) / ops.sqrt(count)

    d0 = rms(y / scale)
    d1 = rms(fy / scale)
    h0 = ops.where((d0 < 1e-5) | (d1 < 1e-5), 1e-6, 0.01 * d0 / ops.maximum(d1, 1e-5))
    h0 = ops.minimum(h0, span)
    f1 = f(t + h0, y + ops.col(h0) * fy)
    d2 = rms((f1 - fy) / scale) / h0
    h1 = ops.where(
        (d1 <= 1e-15) & (d2 <= 1e-15),
        ops.maximum(1e-6, h0 * 1e-3),
        (0.01 / ops.maximum(ops.maximum(d1, d2), 1e-15)) ** (1.0 / 8.0),
    )
    return ops.minimum(ops.minimum(ops.minimum(100.0 * h0, h1), span), max_step)


def dense_coefficients(
    into: Into, t: Any, y: np.ndarray, y_new: np.ndarray, h: Any, K: np.ndarray, ops: Ops
) -> np.ndarray:
    """The coefficients F of the step's 7th-order continuous extension (3 more f).

    K holds the step's stages, f at its start in K[0] and at its end in K[12]; the 3 extra
    stages are written into K[13:16].

    Returns:
        F, shape (7, n) per lane: the state at the fraction x of the step is
        y + :func:`dense_weights` (x) @ F.
    """
    for s, (a, c) in enumerate(zip(A_EXTRA, C_EXTRA, strict=True), start=S + 1):
        into(t + c * h, y + ops.col(h) * ops.weigh(a[:s], K[..., :s, :]), K[..., s, :])
    hc = ops.col(h)
    delta = y_new - y
    F = np.empty((*y.shape[:-1], coef.INTERPOLATOR_POWER, y.shape[-1]))
    F[..., 0, :] = delta
    F[..., 1, :] = hc * K[..., 0, :] - delta
    F[..., 2, :] = 2.0 * delta - hc * (K[..., S, :] + K[..., 0, :])
    F[..., 3:, :] = ops.col(h, 2) * (D @ K)
    return F


def dense_weights(x: Any) -> np.ndarray:
    """Weights w of a step's dense output y + w @ F at the fraction x = tau / h of the step.

    The 7th-order interpolant is y + x (F0 + (1 - x) (F1 + x (F2 + (1 - x) (F3 + ...)))):
    w = (x, x (1 - x), x^2 (1 - x), x^2 (1 - x)^2, ...), products of floats, then one product
    with F instead of seven array operations. For an array of fractions, one row of weights
    per fraction.
    """
    w, acc = [], 1.0
    for j in range(coef.INTERPOLATOR_POWER):
        acc = acc * (x if j % 2 == 0 else 1.0 - x)
        w.append(acc)
    return np.array(w).T


def dense_value(F: np.ndarray, x: Any, y: np.ndarray, ops: Ops) -> np.ndarray:
    """The dense output at fraction(s) x of the step(s) from y, coefficients F."""
    return y + ops.combine(dense_weights(x), F)
