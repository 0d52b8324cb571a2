"""Time integrators, one per module, one interface (:class:`Integrator`)."""

from __future__ import annotations

from .base import DEFAULT_MAX_STEPS, Integrator, Rhs, Segment, StateEvent
from .dop853 import DOP853
from .euler import SemiImplicitEuler
from .rk4 import RK4

#: Integrators by the name used in scenarios.
INTEGRATORS = {"dop853": DOP853, "euler": SemiImplicitEuler, "rk4": RK4}

#: Which integrators step with a fixed dt (the others take rtol / atol).
FIXED_STEP = ("euler", "rk4")

__all__ = [
    "DEFAULT_MAX_STEPS",
    "DOP853",
    "FIXED_STEP",
    "INTEGRATORS",
    "RK4",
    "Integrator",
    "Rhs",
    "Segment",
    "SemiImplicitEuler",
    "StateEvent",
]
