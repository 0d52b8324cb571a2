"""The interface every integrator follows, and the trajectory piece it returns."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

#: Right-hand side of y' = f(t, y).
Rhs = Callable[[float, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Segment:
    """Solution of y' = f(t, y) on one interval between events.

    Attributes:
        t: Times of the accepted steps, t[0] = start and t[-1] = end exactly [s], shape (k,).
        y: States at those times, shape (k, len(y0)).
        rhs_evals: Number of evaluations of f.
    """

    t: np.ndarray
    y: np.ndarray
    rhs_evals: int


class Integrator(Protocol):
    """An integrator that lands exactly on the end of the interval it is given."""

    @property
    def name(self) -> str:
        """Name used in scenarios and reports."""
        ...

    def integrate(self, f: Rhs, t0: float, y0: np.ndarray, t1: float) -> Segment:
        """Integrate from ``t0`` to exactly ``t1`` [s]."""
        ...
