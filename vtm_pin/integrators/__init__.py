"""Time integrators, one per module, one interface (:class:`Integrator`)."""

from __future__ import annotations

from .base import Integrator, Rhs, Segment, StateEvent
from .rk4 import RK4

#: Integrators by the name used in scenarios.
INTEGRATORS = {"rk4": RK4}

__all__ = ["INTEGRATORS", "RK4", "Integrator", "Rhs", "Segment", "StateEvent"]
