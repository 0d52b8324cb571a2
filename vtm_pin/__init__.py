"""vtm_pin: momentum-consistent joint locking for robot emergency stops, on Pinocchio."""

from __future__ import annotations

from .analysis import EnergyMomentum, compute_energy_momentum
from .dynamics import (
    compute_bias,
    compute_energy,
    compute_forward_dynamics,
    compute_gravity,
    compute_M,
)
from .exceptions import (
    BrakeError,
    ConstraintError,
    JointNotFound,
    RobotLoadError,
    RobotNotFound,
    ScenarioError,
    SimulationError,
    TransitionError,
    UnsupportedJoint,
    VtmError,
    VtmWarning,
)
from .holonomic import FrameConstraint
from .integrators import RK4
from .robot import Drive, Robot, load_robot
from .scenario import Scenario, build_scenario, load_scenario, run_scenario
from .simulation import EventRecord, LockEvent, SimulationResult, simulate
from .topology import Topology
from .transitions import TRANSITIONS, TransitionResult

__all__ = [
    "RK4",
    "TRANSITIONS",
    "BrakeError",
    "ConstraintError",
    "Drive",
    "EnergyMomentum",
    "EventRecord",
    "FrameConstraint",
    "JointNotFound",
    "LockEvent",
    "Robot",
    "RobotLoadError",
    "RobotNotFound",
    "Scenario",
    "ScenarioError",
    "SimulationError",
    "SimulationResult",
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
