"""Shared fixtures: robots are loaded once per session; numerics are strict."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from vtm_pin import Robot, load_robot

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ROOT / "scenarios"
sys.path.insert(0, str(Path(__file__).resolve().parent))

_CACHE: dict[str, Robot] = {}


def robot(name: str) -> Robot:
    """A robot loaded once per test session (tests must not modify it)."""
    if name not in _CACHE:
        _CACHE[name] = load_robot(name)
    return _CACHE[name]


@pytest.fixture(autouse=True)
def _strict_numpy():
    with np.errstate(divide="raise", over="raise", invalid="raise"):
        yield
