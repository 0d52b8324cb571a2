"""vtm_pin: momentum-consistent joint locking for robot emergency stops, on Pinocchio.

The names below are imported on first use (PEP 562), so that ``import vtm_pin`` and the
``vtm-pin`` command start without loading Pinocchio until they need it.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .core.holonomic import FrameConstraint
    from .core.problem import LockEvent, Problem
    from .core.results import EventRecord, SimulationResult
    from .core.simulation import simulate
    from .core.topology import Topology
    from .exceptions import (
        BrakeError,
        ConstraintError,
        ConstraintNotMet,
        InputError,
        JointNotFound,
        ProblemError,
        RobotDataError,
        RobotLoadError,
        RobotNotFound,
        ScenarioError,
        SimulationError,
        StepLimitError,
        TransitionError,
        UnsupportedJoint,
        VtmError,
        VtmWarning,
    )
    from .numerics.dynamics import (
        compute_bias,
        compute_energy,
        compute_forward_dynamics,
        compute_gravity,
        compute_M,
    )
    from .numerics.integrators import RK4
    from .numerics.transitions import TRANSITIONS, TransitionResult
    from .outputs.analysis import EnergyMomentum, compute_energy_momentum
    from .physics.brakes import BrakeEvent
    from .physics.robot import Drive, Robot, load_robot
    from .scene.scenario import Scenario, build_scenario, load_scenario, run_scenario

#: Module that defines each public name.
_SOURCES = {
    "outputs.analysis": ["EnergyMomentum", "compute_energy_momentum"],
    "numerics.dynamics": [
        "compute_M",
        "compute_bias",
        "compute_energy",
        "compute_forward_dynamics",
        "compute_gravity",
    ],
    "exceptions": [
        "BrakeError",
        "ConstraintError",
        "ConstraintNotMet",
        "InputError",
        "JointNotFound",
        "ProblemError",
        "RobotDataError",
        "RobotLoadError",
        "RobotNotFound",
        "ScenarioError",
        "SimulationError",
        "StepLimitError",
        "TransitionError",
        "UnsupportedJoint",
        "VtmError",
        "VtmWarning",
    ],
    "core.holonomic": ["FrameConstraint"],
    "numerics.integrators": ["RK4"],
    "physics.robot": ["Drive", "Robot", "load_robot"],
    "scene.scenario": ["Scenario", "build_scenario", "load_scenario", "run_scenario"],
    "core.results": ["EventRecord", "SimulationResult"],
    "physics.brakes": ["BrakeEvent"],
    "core.problem": ["LockEvent", "Problem"],
    "core.simulation": ["simulate"],
    "core.topology": ["Topology"],
    "numerics.transitions": ["TRANSITIONS", "TransitionResult"],
}
_MODULE_OF = {name: module for module, names in _SOURCES.items() for name in names}
#: Public submodules under a short name: ``from vtm_pin import pipeline`` (what ``vtm-pin run``
#: does, as a library call).
_SUBMODULES = {"pipeline": "outputs.pipeline"}

__all__ = [
    "RK4",
    "TRANSITIONS",
    "BrakeError",
    "BrakeEvent",
    "ConstraintError",
    "ConstraintNotMet",
    "Drive",
    "EnergyMomentum",
    "EventRecord",
    "FrameConstraint",
    "InputError",
    "JointNotFound",
    "LockEvent",
    "Problem",
    "ProblemError",
    "Robot",
    "RobotDataError",
    "RobotLoadError",
    "RobotNotFound",
    "Scenario",
    "ScenarioError",
    "SimulationError",
    "SimulationResult",
    "StepLimitError",
    "Topology",
    "TransitionError",
    "TransitionResult",
    "UnsupportedJoint",
    "VtmError",
    "VtmWarning",
    "build_scenario",
    "compute_M",
    "compute_bias",
    "compute_energy",
    "compute_energy_momentum",
    "compute_forward_dynamics",
    "compute_gravity",
    "load_robot",
    "load_scenario",
    "run_scenario",
    "simulate",
]


def __getattr__(name: str) -> Any:
    """A public name (or a submodule, ``vtm_pin.scene.scenario``), imported on first use."""
    if name in _SUBMODULES:
        return importlib.import_module(f".{_SUBMODULES[name]}", __name__)
    module = _MODULE_OF.get(name)
    if module is None:
        try:
            return importlib.import_module(f".{name}", __name__)
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise  # the submodule exists but lacks a dependency
            raise AttributeError(f"module 'vtm_pin' has no attribute '{name}'") from None
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
