"""The interface every integrator follows: segments between events, and state events."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

#: Right-hand side of y' = f(t, y).
Rhs = Callable[[float, np.ndarray], np.ndarray]
#: f(t, y) written into the third argument, allocating nothing: ``into(t, y, out)``, where
#: ``out`` never overlaps ``y``. A right-hand side offers one as its attribute named ``into``
#: (see :func:`writer`); integrators use it when present.
RhsInto = Callable[[float, np.ndarray, np.ndarray], None]


def writer(f: Rhs) -> RhsInto:
    """``f.into`` if the right-hand side has one, else a copy of f(t, y) into ``out``."""
    into: RhsInto | None = getattr(f, "into", None)
    if into is not None:
        return into

    def copy(t: float, y: np.ndarray, out: np.ndarray) -> None:
        out[:] = f(t, y)

    return copy


#: Default ``max_steps`` of every integrator, as diffrax's: a safety net against a run that
#: would never end, not a budget. 1e6 steps take 15 s (3R pendulum) to 7 min (five-bar loop).
DEFAULT_MAX_STEPS = 1_000_000


def steps_text(steps: float) -> str:
    """A step count for a message: ``2000``, ``3.6e+10``, or ``more than 1e308``."""
    if not math.isfinite(steps):
        return "more than 1e308"
    return str(math.ceil(steps)) if steps < 1e12 else f"{steps:.3g}"


@dataclass(frozen=True)
class StateEvent:
    """A state event g(t, y) = 0, with scipy ``solve_ivp`` semantics.

    Attributes:
        g: Event function; the event is a zero crossing of g.
        direction: +1 for crossings from negative to positive, -1 for positive to negative,
            0 for either.
    """

    g: Callable[[float, np.ndarray], float]
    direction: int = 0

    def crossed(self, g0: float, g1: float) -> bool:
        """Whether g went from ``g0`` to ``g1`` across zero in this event's direction.

        A crossing starts strictly on one side: an event function that starts at exactly 0
        (the state an event handler left behind) does not fire again at once. If it ends
        strictly past zero, though, a directional event counts as crossed: g must have
        left zero for the side before the crossing and come back within the interval (a
        joint that starts sliding from rest and is stopped again by its rising friction);
        :func:`~vtm_pin.numerics.integrators.fixed_step.locate` finds the return.
        """
        if self.direction >= 0 and g0 < 0.0 <= g1:
            return True
        if self.direction <= 0 and g0 > 0.0 >= g1:
            return True
        return g0 == 0.0 and self.direction * g1 > 0.0

    def before(self, g: float) -> bool:
        """Whether ``g`` is strictly on the side before a crossing in this event's direction."""
        return self.direction * g < 0.0 if self.direction else g != 0.0


@dataclass(frozen=True)
class Segment:
    """Solution of y' = f(t, y) on one interval, ended by its end time or a state event.

    Attributes:
        t: Sample times, t[0] = start and t[-1] = end or event time [s]: the accepted steps,
            or with a dense output (dop853's ``output_dt``) the output times between.
        y: States at those times, shape (k, len(y0)); y[-1] is the state reached.
        rhs_evals: Number of evaluations of f (event location and dense output included).
        event: Index of the state event that ended the segment, or None.
        n_steps: Accepted steps, when the samples are not the steps; None: one per sample
            after the first.
        holding: Holding torques of the locked joints at the samples [N m], shape
            (k, n), when the integrator computed them on the way (the batched engine);
            None: the hybrid loop computes them.
    """

    t: np.ndarray
    y: np.ndarray
    rhs_evals: int
    event: int | None = None
    n_steps: int | None = None
    holding: np.ndarray | None = None

    @property
    def steps(self) -> int:
        """Accepted steps of the interval (the last one cut at the event, if any)."""
        return self.t.size - 1 if self.n_steps is None else self.n_steps


class Integrator(Protocol):
    """An integrator that lands exactly on the end of its interval and locates state events."""

    @property
    def name(self) -> str:
        """Name used in scenarios and reports."""
        ...

    def integrate(
        self,
        f: Rhs,
        t0: float,
        y0: np.ndarray,
        t1: float,
        events: Sequence[StateEvent] = (),
        n_q: int = 0,
    ) -> Segment:
        """Integrate from ``t0`` to exactly ``t1`` [s], or to the first state event before it.

        ``n_q`` tells second-order-aware methods that y[:n_q] are positions whose rates are
        y[n_q:2 n_q]; the others ignore it. An empty ``y0`` is a frozen state (every joint
        locked): nothing moves, the integrators here watch no event there, and the hybrid loop
        passes none.
        """
        ...
