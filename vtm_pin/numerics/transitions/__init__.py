"""Transition formulations at a constraint activation, one per module, one interface."""

from __future__ import annotations

from . import kkt, minimal, naive, projected
from .base import Transition, TransitionResult, finish, solve_saddle_point

#: Formulations by name; the consistent ones (kkt, projected, minimal) give the same v+.
TRANSITIONS: dict[str, Transition] = {
    "kkt": kkt.compute_transition,
    "minimal": minimal.compute_transition,
    "naive": naive.compute_transition,
    "projected": projected.compute_transition,
}

__all__ = ["TRANSITIONS", "Transition", "TransitionResult", "finish", "solve_saddle_point"]
