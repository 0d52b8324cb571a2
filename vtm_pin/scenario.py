"""Scenario files: the YAML schema, its validation, and the validated :class:`Scenario`."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from .annex_b import Conditions, TestState, compute_test_state, describe_conditions
from .bounds import BoundSpec, Uncertainty, parse_bounds
from .brakes import Brake
from .exceptions import (
    BrakeError,
    ConditionsError,
    ConstraintError,
    ConstraintNotMet,
    JointNotFound,
    PayloadError,
    ProblemError,
    ScenarioError,
    StepLimitError,
    VtmError,
    excerpt,
)
from .friction import Coulomb, FrictionLaw, IdealLock, Stribeck, Viscous
from .holonomic import FrameConstraint
from .inputs import MAX_MASS, MAX_RATE, MAX_TIME, MAX_TORQUE, check_schema, number, read_yaml
from .integrators import DEFAULT_MAX_STEPS, DOP853, FIXED_STEP, INTEGRATORS, Integrator
from .integrators.base import steps_text
from .payload import Payload, attach_payload, describe_payload, inertia_matrix
from .problem import LockEvent, Problem, check_transition
from .results import SimulationResult
from .robot import BRAKE_SCHEMA, DRIVES_SCHEMA, Drive, Robot, load_robot, robot_data
from .separation import Separation, parse_separation
from .simulation import simulate
from .stop import DEFAULT_GAIN, DEFAULT_REST_SPEED, Stop
from .transitions import TRANSITIONS

#: Bounds of scenario values besides those of :mod:`vtm_pin.inputs` (MAX_TIME, MAX_RATE,
#: MAX_TORQUE): generous but finite, a value outside them is a typo and refused with its key.
MAX_POSITION = 1.0e3  # [rad or m] joint positions
MAX_GAIN = 1.0e4  # [1/s] velocity feedback gain of a category-1 stop
#: [1/s] Baumgarte gains: a correction faster than 1 ms is faster than any event of a stop,
#: and above it the term beta^2 h amplifies round-off so that a tight dop853 run stalls.
MAX_BAUMGARTE = 1.0e3
MAX_DISTANCE = 100.0  # [m] docking target positions
MAX_ANGLE = 10.0  # [rad] docking target roll, pitch, yaw
MIN_RTOL, MIN_ATOL = 1.0e-13, 1.0e-15  # [-], [state units]: below them DOP853 meets round-off
MAX_STEPS_LIMIT = 1_000_000_000  # largest integrator.max_steps accepted

_VECTOR3_M = {
    "type": "array",
    "items": number(-MAX_DISTANCE, MAX_DISTANCE, "Coordinate [m]."),
    "minItems": 3,
    "maxItems": 3,
}
_VECTOR3_RAD = {**_VECTOR3_M, "items": number(-MAX_ANGLE, MAX_ANGLE, "Angle [rad].")}
_CONSTRAINT = {
    "type": "object",
    "additionalProperties": False,
    "required": ["type", "frame_a"],
    "properties": {
        "name": {"type": "string", "description": "Name in reports. Default: <type><index>."},
        "type": {
            "enum": ["dock", "loop"],
            "description": "loop: frame_a meets frame_b; dock: frame_a is fixed in the world.",
        },
        "frame_a": {"type": "string", "description": "Frame of the robot."},
        "frame_b": {"type": "string", "description": "loop only: the second frame."},
        "mode": {
            "enum": ["point", "pose"],
            "description": "point (3 rows) or pose (6 rows). Default: point.",
        },
        "axes": {
            "type": "array",
            "items": {"enum": ["x", "y", "z", "rx", "ry", "rz"]},
            "minItems": 1,
            "description": "Rows kept, world axes. Default: all of the mode's.",
        },
        "target": {
            "type": "object",
            "additionalProperties": False,
            "description": "dock only: world pose of the fixture. Default: where frame_a is "
            "when the constraint activates.",
            "properties": {
                "xyz": {**_VECTOR3_M, "description": "Position [m], each within ±100."},
                "rpy": {
                    **_VECTOR3_RAD,
                    "description": "Roll, pitch, yaw [rad], each within ±10. Default: [0, 0, 0].",
                },
            },
        },
    },
}


def _joint_values(item: dict[str, Any], description: str) -> dict[str, Any]:
    """A value per joint: a list in model order, or a mapping {joint name: value}."""
    return {
        "oneOf": [
            {"type": "array", "items": item},
            {"type": "object", "additionalProperties": item},
        ],
        "description": description,
    }


def _time(description: str, *, positive: bool = False) -> dict[str, Any]:
    """A time in [0, MAX_TIME] s, or (0, MAX_TIME] s if ``positive``."""
    return number(0.0, MAX_TIME, description, exclusive_low=positive)


#: A calibration's figures and covariance, as vtm-pin calibrate writes them into a fragment.
CALIBRATION_SCHEMA: dict[str, Any] = {
    "type": "object",
    "additionalProperties": False,
    "required": ["figures", "covariance"],
    "description": "The calibrated figures' covariance (written by vtm-pin calibrate into its "
    "fragment), which bounds propagate. Default: none.",
    "properties": {
        "source": {"type": "string", "description": "The published data fitted to."},
        "figures": {
            "type": "array",
            "description": "Each fitted figure: name, value (SI), unit, the key paths it sets.",
            "items": {
                "type": "object",
                "additionalProperties": False,
                "required": ["name", "value", "keys"],
                "properties": {
                    "name": {"type": "string", "description": "Figure name."},
                    "value": number(0.0, 1.0e9, "Fitted value (SI), > 0.", exclusive_low=True),
                    "unit": {"type": "string", "description": "Its unit."},
                    "keys": {
                        "type": "array",
                        "items": {"type": "string"},
                        "minItems": 1,
                        "description": "Scenario key paths it sets.",
                    },
                },
            },
        },
        "covariance": {
            "type": "array",
            "items": {"type": "array", "items": number(-1.0e18, 1.0e18, "Covariance (SI).")},
            "description": "Covariance of the figures (SI, square units), one row per figure.",
        },
        "inflation": number(1.0, 1.0e9, "Factor chi^2/dof the covariance was inflated by [-]."),
        "fixed": {
            "type": "array",
            "items": {"type": "string"},
            "description": "Figures held at a bound of their search (no uncertainty).",
        },
        "undetermined": {
            "type": "array",
            "items": {"type": "string"},
            "description": "Figures the table does not determine (no bound can cover them).",
        },
        "bias": {
            "type": "object",
            "additionalProperties": False,
            "description": "Mean relative residual of the calibration's times and distances.",
            "properties": {
                "stop_time": number(-10.0, 10.0, "Of the times [-]."),
                "stop_distance": number(-10.0, 10.0, "Of the distances [-]."),
            },
        },
        "shortfall": {
            "type": "object",
            "additionalProperties": False,
            "description": "Most negative relative residual of the calibration's times and "
            "distances (0 if none is negative): bounds add it back.",
            "properties": {
                "stop_time": number(-10.0, 0.0, "Of the times [-], <= 0."),
                "stop_distance": number(-10.0, 0.0, "Of the distances [-], <= 0."),
            },
        },
    },
}
#: JSON schema of a scenario file. Each key's ``description`` gives its unit and default.
SCHEMA: dict[str, Any] = {
    "type": "object",
    "additionalProperties": False,
    "required": ["robot", "duration"],
    "properties": {
        "description": {"type": "string", "description": "Free text shown in the summary."},
        "robot": {
            "type": "string",
            "description": "Name of a file in robots/, a URDF or xacro path (relative to the "
            "scenario file) or an example-robot-data name.",
        },
        "robot_packages": {
            "type": "object",
            "additionalProperties": {"type": "string", "minLength": 1},
            "description": "ROS package name -> its folder (relative to the scenario file), for "
            "a xacro robot's $(find pkg) and package:// paths; a package holding the xacro "
            "file is found without it. Default: none.",
        },
        "drives": DRIVES_SCHEMA,
        "initial": {
            "type": "object",
            "additionalProperties": False,
            "required": ["q"],
            "description": "Initial state.",
            "properties": {
                "q": _joint_values(
                    number(-MAX_POSITION, MAX_POSITION, "Joint position [rad or m]."),
                    "Joint positions [rad or m], each within ±1000: a list in model order, or "
                    "{joint_name: value} with 0 for joints not named.",
                ),
                "v": _joint_values(
                    number(-MAX_RATE, MAX_RATE, "Joint rate [rad/s or m/s]."),
                    "Joint velocities [rad/s or m/s], each within ±1000, same forms. Default: 0.",
                ),
            },
        },
        "duration": _time("Simulated time [s], > 0 and at most 3600.", positive=True),
        "payload": {
            "type": "object",
            "additionalProperties": False,
            "required": ["mass"],
            "description": "A rigid payload (gripper and part) attached to a frame. Default: none.",
            "properties": {
                "mass": number(0.0, MAX_MASS, "Mass [kg], >= 0."),
                "com": {
                    **_VECTOR3_M,
                    "description": "Centre of mass [m] in the frame. Default: [0, 0, 0].",
                },
                "inertia": {
                    "type": "object",
                    "additionalProperties": False,
                    "description": "Rotational inertia about the centre of mass, frame axes "
                    "[kg m^2]: ixx, iyy, izz, and ixy, ixz, iyz (default 0). Default: a point "
                    "mass.",
                    "properties": {
                        k: number(-1.0e5, 1.0e5, f"{k} [kg m²].")
                        for k in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")
                    },
                    "required": ["ixx", "iyy", "izz"],
                },
                "frame": {
                    "type": "string",
                    "description": "Frame it is attached to. Default: the tool frame.",
                },
            },
        },
        "annex_b": {
            "type": "object",
            "additionalProperties": False,
            "required": ["joint"],
            "description": "ISO 10218-1 Annex-B test conditions: the initial state is computed "
            "(only this joint moves; see the README). Replaces initial.v; initial.q is the "
            "guess for the pose. Default: none.",
            "properties": {
                "joint": {"type": "string", "description": "Joint under test."},
                "speed": number(
                    0.0,
                    1.0,
                    "Fraction of the joint's maximum speed [-], (0, 1]. Default: 1.",
                    exclusive_low=True,
                ),
                "max_speed": number(
                    0.0,
                    MAX_RATE,
                    "Maximum speed [rad/s or m/s]. Default: the URDF velocity limit.",
                    exclusive_low=True,
                ),
                "extension": number(
                    0.0,
                    1.0,
                    "Fraction of the arm's maximum reach [-], (0, 1]. Default: 1.",
                    exclusive_low=True,
                ),
                "direction": {
                    "enum": ["down", "up", "positive", "negative"],
                    "description": "Sign of the joint's rate: down moves the tool along "
                    "gravity (positive when it moves the tool horizontally). Default: down.",
                },
            },
        },
        "integrator": {
            "type": "object",
            "additionalProperties": False,
            "description": "Time integration. Default: {method: rk4, dt: 1.0e-4}.",
            "properties": {
                "method": {"enum": sorted(INTEGRATORS), "description": "Integrator name."},
                "dt": _time(
                    "Step of rk4 / euler [s], <= duration. Default: 1.0e-4.", positive=True
                ),
                "rtol": number(
                    MIN_RTOL, 1.0, "dop853 relative tolerance [-], 1e-13 to 1. Default: 1.0e-8."
                ),
                "atol": number(
                    MIN_ATOL,
                    1.0,
                    "dop853 absolute tolerance [state units], 1e-15 to 1. Default: 1.0e-10.",
                ),
                "max_steps": {
                    "type": "number",
                    "multipleOf": 1,
                    "minimum": 1,
                    "maximum": MAX_STEPS_LIMIT,
                    "description": "Most steps: rk4 / euler refuse a run of more than this "
                    "(duration / dt) up front, dop853 stops when the steps between two events "
                    "pass it. Default: 1000000.",
                },
                "output_dt": _time(
                    "dop853 output period [s], <= duration, at most max_steps samples: its dense "
                    "output at the times k output_dt (k whole) instead of its steps. Default: "
                    "none: the accepted steps.",
                    positive=True,
                ),
            },
        },
        "transition": {
            "enum": sorted(TRANSITIONS),
            "description": "Rule applied at a lock. Default: kkt.",
        },
        "tool_frame": {
            "type": "string",
            "description": "Frame followed by the stopping report. Default: the robot's "
            "(tool0 or its last frame).",
        },
        "assumptions": {
            "type": "array",
            "items": {"type": "string"},
            "description": "Stated assumptions of this scenario, quoted by the report.",
        },
        "include": {
            "type": "array",
            "items": {"type": "string"},
            "description": "Fragment files (relative to the scenario file) whose drives, "
            "brakes and assumptions are merged in, such as vtm-pin calibrate's "
            "calibrated.yaml; the scenario's own values win. Default: [].",
        },
        "stop": {
            "type": "object",
            "additionalProperties": False,
            "description": "Emergency stop. Default: none (no drives, no brakes).",
            "properties": {
                "t": _time("Signal time [s]."),
                "category": {"enum": [0, 1], "description": "Stop category. Default: 0."},
                "ramp_time": _time(
                    "Category 1: time to ramp the rates to zero [s].", positive=True
                ),
                "torque_limit": {
                    "oneOf": [
                        number(0.0, MAX_TORQUE, "Torque limit [N m].", exclusive_low=True),
                        {
                            "type": "array",
                            "items": number(
                                0.0, MAX_TORQUE, "Torque limit [N m].", exclusive_low=True
                            ),
                        },
                        {
                            "type": "object",
                            "additionalProperties": number(
                                0.0, MAX_TORQUE, "[N m]", exclusive_low=True
                            ),
                        },
                    ],
                    "description": "Category 1: drive torque limit, joint side [N m], > 0 and "
                    "at most 1e6: one number for all joints, a list, or {joint: value}.",
                },
                "time_limit": _time(
                    "Category 1: latest brake signal after t [s]. Default: ramp_time.",
                    positive=True,
                ),
                "gain": number(
                    0.0,
                    MAX_GAIN,
                    "Category 1: velocity feedback gain [1/s], at most 1e4. Default: 50.",
                    exclusive_low=True,
                ),
                "rest_speed": number(
                    0.0,
                    MAX_RATE,
                    "A joint has stopped once its speed stays below this [rad/s]; the stopping "
                    "time runs from the signal until then. Default: 0.001.",
                    exclusive_low=True,
                ),
            },
        },
        "brakes": {
            "type": "object",
            "description": "Brake per joint name; acts after the stop signal; null gives the "
            "joint no brake. Default: the robot data file's brakes (with a stop).",
            "additionalProperties": {**BRAKE_SCHEMA, "type": ["object", "null"]},
        },
        "safeguard": {
            "type": "object",
            "additionalProperties": False,
            "required": ["detection_time", "response_time", "latency"],
            "description": "The stopping chain before the robot's own stop, for ISO 13855's "
            "overall T and the separation distances. Default: none (T, S, S_p not computed).",
            "properties": {
                "detection_time": _time("The protective device's detection time [s]."),
                "response_time": _time("The safety controller's response time [s]."),
                "latency": _time("Latency of the stop signal to the robot [s]."),
            },
        },
        "separation": {
            "type": "object",
            "additionalProperties": False,
            "description": "Inputs of the separation distances (needs safeguard). Default: none.",
            "properties": {
                "iso13855": {
                    "type": "object",
                    "additionalProperties": False,
                    "required": ["approach_speed", "intrusion_distance", "supplement"],
                    "description": "ISO 13855:2024: S = K T + D_DS + Z; none defaulted.",
                    "properties": {
                        "approach_speed": number(
                            0.0, 10.0, "K, approach speed [m/s], > 0.", exclusive_low=True
                        ),
                        "intrusion_distance": number(
                            0.0, MAX_DISTANCE, "D_DS, intrusion distance of the detection zone [m]."
                        ),
                        "supplement": number(0.0, MAX_DISTANCE, "Z, supplemental distance [m]."),
                    },
                },
                "iso_ts_15066": {
                    "type": "object",
                    "additionalProperties": False,
                    "required": ["intrusion_distance", "human_uncertainty", "robot_uncertainty"],
                    "description": "ISO/TS 15066 speed and separation monitoring: "
                    "S_p = S_h + S_r + S_s + C + Z_d + Z_r.",
                    "properties": {
                        "human_speed": number(
                            0.0, 10.0, "v_h [m/s], > 0. Default: 1.6.", exclusive_low=True
                        ),
                        "intrusion_distance": number(0.0, MAX_DISTANCE, "C [m]."),
                        "human_uncertainty": number(0.0, MAX_DISTANCE, "Z_d [m]."),
                        "robot_uncertainty": number(0.0, MAX_DISTANCE, "Z_r [m]."),
                    },
                },
            },
        },
        "bounds": {
            "type": "object",
            "additionalProperties": False,
            "description": "One-sided upper bounds of the stopping figures (see the bounds "
            "section of the README). Default: none (nominal figures only).",
            "properties": {
                "confidence": number(
                    0.5, 0.9999, "One-sided confidence [-], 0.5 to 0.9999. Default: 0.95."
                ),
                "brake_wear": number(
                    0.0, 0.9, "Brake torques lower by this fraction [-], 0 to 0.9. Default: 0."
                ),
            },
        },
        "calibration": CALIBRATION_SCHEMA,
        "constraints": {
            "type": "array",
            "items": _CONSTRAINT,
            "description": "Loop closures and dockings active from t = 0. Default: [].",
        },
        "stabilisation": {
            "type": "object",
            "additionalProperties": False,
            "description": "Baumgarte gains of the frame constraints. Default: {alpha: 10, beta: "
            "10}.",
            "properties": {
                "alpha": number(0.0, MAX_BAUMGARTE, "Velocity gain [1/s], at most 1e3."),
                "beta": number(0.0, MAX_BAUMGARTE, "Position gain [1/s], at most 1e3."),
            },
        },
        "events": {
            "type": "array",
            "description": "Ideal activations, each {t: time [s], lock: [joint names], "
            "activate: [constraints]}. Default: [].",
            "items": {
                "type": "object",
                "additionalProperties": False,
                "required": ["t"],
                "properties": {
                    "t": _time("Event time [s], in [0, duration]."),
                    "lock": {
                        "type": "array",
                        "items": {"type": "string"},
                        "minItems": 1,
                        "description": "Joints that lock at t.",
                    },
                    "activate": {
                        "type": "array",
                        "items": _CONSTRAINT,
                        "minItems": 1,
                        "description": "Loop closures or dockings that activate at t.",
                    },
                },
            },
        },
    },
}

DEFAULT_DT = 1.0e-4  # [s]
DEFAULT_TRANSITION = "kkt"
#: Folder of the scenarios shipped with the project: ``scenarios/`` at the top of the source
#: tree, installed as the package data ``vtm_pin.scenarios`` (so an installed wheel has it too).
SCENARIOS_DIR = Path(str(resources.files("vtm_pin.scenarios")))


@dataclass(frozen=True)
class Scenario:
    """A validated scenario: the problem to simulate, how to run it, and what to report.

    Attributes:
        source: The file it was read from ("" when built from a mapping).
        name: File stem, used to name outputs.
        description: Free text.
        problem: What to simulate (robot, initial state, duration, locks, brakes, stop,
            frame constraints); its fields are also readable here (``scenario.robot``...).
        integrator: Integrator object (RK4, SemiImplicitEuler or DOP853).
        transition: Transition rule name.
        tool_frame: Frame followed by the stopping report.
        assumptions: Stated assumptions, quoted by reports.
        constraint_keys: Key in the file of each frame constraint, by name (for messages).
        payload: The payload attached to the robot (already in ``robot``'s model), if any.
        test_state: The Annex-B test state the initial state was computed from, if any.
        separation: The stopping chain before the robot and the separation distances' inputs
            (``safeguard``, ``separation``), each part None where not given.
        bounds: The upper bounds asked for (``bounds``), if any.
        uncertainty: The calibrated figures' covariance (``calibration``, from a calibrated
            fragment), if any.
        raw: The scenario as parsed, fragments and robot data merged (bounds rebuild it).
        base_dir: The folder its relative paths are resolved against.
    """

    source: str
    name: str
    description: str
    problem: Problem
    integrator: Integrator
    transition: str
    tool_frame: str = ""
    assumptions: tuple[str, ...] = ()
    constraint_keys: Mapping[str, str] = field(default_factory=dict)
    payload: Payload | None = None
    test_state: TestState | None = None
    separation: Separation = field(default_factory=Separation)
    bounds: BoundSpec | None = None
    uncertainty: Uncertainty | None = None
    raw: Mapping[str, Any] = field(default_factory=dict, repr=False, compare=False)
    base_dir: Path | None = None

    @property
    def robot(self) -> Robot:
        """The loaded robot, drives applied."""
        return self.problem.robot

    @property
    def q0(self) -> np.ndarray:
        """Initial joint positions [rad], shape (n,)."""
        return self.problem.q0

    @property
    def v0(self) -> np.ndarray:
        """Initial joint velocities [rad/s], shape (n,)."""
        return self.problem.v0

    @property
    def duration(self) -> float:
        """End time [s]."""
        return self.problem.duration

    @property
    def events(self) -> tuple[LockEvent, ...]:
        """Lock events, in the file's order."""
        return self.problem.events

    @property
    def brakes(self) -> tuple[Brake, ...]:
        """Brakes, acting after the stop signal."""
        return self.problem.brakes

    @property
    def stop(self) -> Stop | None:
        """The emergency stop, if any."""
        return self.problem.stop

    @property
    def constraints(self) -> tuple[FrameConstraint, ...]:
        """Frame constraints active from t = 0."""
        return self.problem.constraints

    @property
    def baumgarte(self) -> tuple[float, float]:
        """Baumgarte gains (alpha, beta) [1/s]."""
        return self.problem.baumgarte


def load_scenario(path: str | Path) -> Scenario:
    """Read, validate and resolve a scenario file.

    Raises:
        ScenarioError: The file is missing, is not YAML, or breaks the schema; the message
            names the file, the key path and what is allowed.
    """
    path = Path(path)
    raw = _read_yaml(path)
    return build_scenario(raw, source=str(path), base_dir=path.parent, name=path.stem)


@dataclass(frozen=True)
class ScenarioEntry:
    """One scenario file of a folder, as listed (checked against the schema, not run).

    Attributes:
        name: File stem, the scenario's name.
        path: The file.
        robot: Its ``robot`` key ("" if the file is invalid).
        duration: Its ``duration`` [s] (NaN if invalid).
        description: Its ``description``, or the reason it is invalid.
        valid: Whether it passed the schema check.
    """

    name: str
    path: Path
    robot: str
    duration: float
    description: str
    valid: bool


def list_scenarios(folder: str | Path = SCENARIOS_DIR) -> list[ScenarioEntry]:
    """The ``*.yaml`` scenarios of ``folder`` (the project's ``scenarios/`` by default).

    Each file is parsed and checked against the schema; robots are not loaded, so a listed
    scenario may still name an unknown robot or joint.

    Raises:
        ScenarioError: ``folder`` is not a folder.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ScenarioError(str(folder), "", "is not a folder")
    entries = []
    for path in sorted(folder.glob("*.yaml")):
        try:
            raw = _read_yaml(path)
            if not isinstance(raw, Mapping):
                raise ScenarioError(str(path), "", "a scenario must be a mapping")
            _check_schema(raw, str(path))
        except ScenarioError as exc:
            problem = f"'{exc.key}': {exc.problem}" if exc.key else exc.problem
            entries.append(ScenarioEntry(path.stem, path, "", math.nan, problem, False))
            continue
        description = " ".join(str(raw.get("description", "")).split())
        entries.append(
            ScenarioEntry(
                path.stem, path, str(raw["robot"]), float(raw["duration"]), description, True
            )
        )
    return entries


def _read_yaml(path: Path) -> Any:
    """The parsed YAML of a scenario file, read within :mod:`vtm_pin.inputs`' limits."""
    return read_yaml(path, ScenarioError)


def build_scenario(
    raw: Any,
    source: str = "",
    base_dir: Path | None = None,
    name: str = "scenario",
    loader: Callable[..., Robot] = load_robot,
    valid: Mapping[str, Any] | None = None,
) -> Scenario:
    """Validate a scenario given as a mapping (the parsed YAML) and resolve it.

    Args:
        raw: The parsed scenario.
        source: File name used in error messages.
        base_dir: Folder that relative robot paths are resolved against.
        name: Name used for outputs.
        loader: Loads the robot, with :func:`vtm_pin.robot.load_robot`'s arguments (studies
            pass a cached one; the robot it returns is never modified).
        valid: A scenario known to pass the schema (:func:`passes_schema`), such as a study's
            base: top-level keys of ``raw`` equal to its own are not checked again.

    Raises:
        ScenarioError: The mapping breaks the schema or names unknown robots or joints.
    """
    if not isinstance(raw, Mapping):
        raise ScenarioError(source, "", "a scenario must be a mapping of keys to values")
    _check_schema(raw, source, valid)
    raw = merge_includes(raw, source, base_dir)
    duration = float(raw["duration"])

    drives = _drives(raw.get("drives", {}), source)
    try:
        packages = raw.get("robot_packages", {})
        robot = loader(raw["robot"], drives=drives, base_dir=base_dir, packages=packages)
    except JointNotFound as exc:
        raise ScenarioError(
            source,
            f"drives.{excerpt(exc.name)}",
            f"unknown joint; the joints are: {', '.join(exc.joints)}",
        ) from exc
    except VtmError as exc:
        raise ScenarioError(source, "robot", str(exc)) from exc

    tool_frame = raw.get("tool_frame", robot.tool_frame)
    if not robot.model.existFrame(tool_frame):
        frames = ", ".join(f.name for f in robot.model.frames)
        raise ScenarioError(
            source, "tool_frame", f"no frame '{excerpt(tool_frame)}'; frames: {frames}"
        )
    assumptions = list(raw.get("assumptions", ()))
    payload = None
    if "payload" in raw:
        payload = _payload(raw["payload"], tool_frame, source)
        robot = _attach(robot, payload, source)
        assumptions.append(describe_payload(payload, payload.frame))
    q0, v0, test_state = _initial_state(raw, robot, tool_frame, source, assumptions)

    integrator = _integrator(raw.get("integrator", {}), duration, source)  # schema checked

    names: dict[str, str] = {}
    constraints = tuple(
        _constraint(robot, spec, source, f"constraints[{i}]", names)
        for i, spec in enumerate(raw.get("constraints", []))
    )
    events = tuple(
        LockEvent(
            t=float(ev["t"]),
            lock=tuple(ev.get("lock", [])),
            activate=tuple(
                _constraint(robot, spec, source, f"events[{k}].activate[{i}]", names)
                for i, spec in enumerate(ev.get("activate", []))
            ),
        )
        for k, ev in enumerate(raw.get("events", []))
    )

    stab = raw.get("stabilisation", {})
    transition = raw.get("transition", DEFAULT_TRANSITION)
    bounds, uncertainty = parse_bounds(raw, source)
    try:
        problem = Problem(
            robot=robot,
            q0=q0,
            v0=v0,
            duration=duration,
            events=events,
            brakes=_brakes(raw.get("brakes", {}), source),
            stop=_stop(robot, raw.get("stop"), source, assumptions),
            constraints=constraints,
            baumgarte=(float(stab.get("alpha", 10.0)), float(stab.get("beta", 10.0))),
        )
        check_transition(problem, transition)
    except ProblemError as exc:
        raise ScenarioError(source, exc.key, exc.problem) from exc

    return Scenario(
        source=source,
        name=name,
        description=str(raw.get("description", "")),
        problem=problem,
        integrator=integrator,
        transition=transition,
        tool_frame=tool_frame,
        assumptions=tuple(assumptions),
        constraint_keys=names,
        payload=payload,
        test_state=test_state,
        separation=_separation(raw, source),
        bounds=bounds,
        uncertainty=uncertainty,
        raw=raw,
        base_dir=base_dir,
    )


def _separation(raw: Mapping[str, Any], source: str) -> Separation:
    """The stopping chain and separation inputs; the distances need the safeguard's times."""
    if "separation" in raw and "safeguard" not in raw:
        raise ScenarioError(
            source,
            "separation",
            "the separation distances need the stopping chain before the robot: give safeguard "
            "(detection_time, response_time, latency [s])",
        )
    return parse_separation(raw)


def _drives(raw: Mapping[str, Any], source: str) -> dict[str, Drive]:
    """The drives of a scenario's ``drives`` mapping (schema checked)."""
    drives = {}
    for joint, spec in raw.items():
        try:
            drives[joint] = Drive.from_spec(spec)
        except ValueError as exc:
            raise ScenarioError(source, f"drives.{excerpt(joint)}", str(exc)) from exc
    return drives


def _payload(raw: Mapping[str, Any], tool_frame: str, source: str) -> Payload:
    """The payload of a scenario's ``payload`` mapping (attached to the tool frame by default)."""
    try:
        inertia = inertia_matrix(raw["inertia"]) if "inertia" in raw else None
        return Payload(
            mass=float(raw["mass"]),
            com=tuple(float(x) for x in raw.get("com", (0.0, 0.0, 0.0))),  # type: ignore[arg-type]
            inertia=inertia,
            frame=str(raw.get("frame", tool_frame)),
        )
    except PayloadError as exc:
        raise ScenarioError(source, f"payload.{exc.key}", exc.problem) from exc


def _attach(robot: Robot, payload: Payload, source: str) -> Robot:
    try:
        return attach_payload(robot, payload)
    except PayloadError as exc:
        raise ScenarioError(source, f"payload.{exc.key}", exc.problem) from exc


def _initial_state(
    raw: Mapping[str, Any], robot: Robot, tool_frame: str, source: str, assumptions: list[str]
) -> tuple[np.ndarray, np.ndarray, TestState | None]:
    """q0, v0 from ``initial``, or computed from ``annex_b`` (``initial.q`` as the guess)."""
    initial = raw.get("initial")
    spec = raw.get("annex_b")
    if initial is None and spec is None:
        raise ScenarioError(source, "initial", "is required (or annex_b, which computes it)")
    if spec is None:
        assert initial is not None
        q0 = _joint_vector(robot, initial["q"], source, "initial.q")
        v0 = _joint_vector(robot, initial.get("v", [0.0] * robot.nv), source, "initial.v")
        return q0, v0, None
    guess = (
        _joint_vector(robot, initial["q"], source, "initial.q")
        if initial is not None
        else pin.neutral(robot.model)
    )
    try:
        conditions = Conditions(
            joint=str(spec["joint"]),
            speed=float(spec.get("speed", 1.0)),
            extension=float(spec.get("extension", 1.0)),
            max_speed=None if "max_speed" not in spec else float(spec["max_speed"]),
            direction=str(spec.get("direction", "down")),
        )
        state = compute_test_state(robot, tool_frame, conditions, guess)
    except ConditionsError as exc:
        raise ScenarioError(source, f"annex_b.{exc.key}", exc.problem) from exc
    assumptions.extend(describe_conditions(conditions, state, tool_frame))
    return state.q, state.v, state


#: Schema of a fragment a scenario includes: drives, brakes and the assumptions behind them.
FRAGMENT_SCHEMA: dict[str, Any] = {
    "type": "object",
    "additionalProperties": False,
    "properties": {
        key: SCHEMA["properties"][key]
        for key in ("description", "drives", "brakes", "assumptions", "calibration")
    },
}


def merge_includes(raw: Mapping[str, Any], source: str, base_dir: Path | None) -> Mapping[str, Any]:
    """``raw`` with its included fragments and its robot's brakes merged in.

    Fragments are merged per joint and key (the scenario's keys win). With a ``stop``, the
    brakes of the robot data file (:func:`vtm_pin.robot.robot_data`) then fill in every joint
    the scenario and its fragments give no brake (a joint given ``null`` keeps none). The
    result has no ``include`` key and names every brake: merging it again changes nothing.

    Raises:
        ScenarioError: A fragment or the robot data file cannot be read or breaks its schema;
            ``include``, ``drives``, ``brakes`` or ``assumptions`` of ``raw`` break theirs, or
            a scenario includes itself.
    """
    # the keys merged must have their form first (the rest of raw is checked when it is built)
    check_schema({k: raw[k] for k in _MERGED if k in raw}, _MERGED_SCHEMA, source, ScenarioError)
    return _merge_robot_brakes(_merge_fragments(raw, source, base_dir), source, base_dir)


def _merge_robot_brakes(
    raw: Mapping[str, Any], source: str, base_dir: Path | None
) -> Mapping[str, Any]:
    """``raw`` with the robot data file's brakes for the joints it gives none (with a stop)."""
    if "stop" not in raw or not isinstance(raw.get("robot"), str):
        return raw
    try:
        data = robot_data(raw["robot"], base_dir)
    except VtmError as exc:
        raise ScenarioError(source, "robot", str(exc)) from exc
    missing = {
        j: dict(b) for j, b in data.get("brakes", {}).items() if j not in raw.get("brakes", {})
    }
    if not missing:
        return raw
    return {**raw, "brakes": {**missing, **raw.get("brakes", {})}}


def _merge_fragments(
    raw: Mapping[str, Any], source: str, base_dir: Path | None
) -> Mapping[str, Any]:
    """``raw`` with its included fragments merged in (per joint; the scenario's keys win)."""
    if "include" not in raw:
        return raw
    merged = {key: value for key, value in raw.items() if key != "include"}
    assumptions: list[str] = []
    for i, name in enumerate(raw["include"]):
        path = Path(name) if base_dir is None else base_dir / name
        key = f"include[{i}]"
        if _same_file(path, source):
            raise ScenarioError(
                source,
                key,
                f"{excerpt(name)} is this scenario itself: an include cycle; include fragments "
                "(drives, brakes, assumptions, calibration) only",
            )
        try:
            fragment = read_yaml(path, ScenarioError)
        except ScenarioError as exc:
            where = f"'{exc.key}': " if exc.key else ""
            raise ScenarioError(source, key, f"{excerpt(name)}: {where}{exc.problem}") from exc
        if not isinstance(fragment, Mapping):
            raise ScenarioError(source, key, f"{excerpt(name)} is not a mapping")
        check_schema(fragment, FRAGMENT_SCHEMA, excerpt(str(path), 200), ScenarioError)
        for section in ("drives", "brakes"):
            joints = {**fragment.get(section, {})}
            for joint, spec in merged.get(section, {}).items():
                base = joints.get(joint) or {}
                joints[joint] = None if spec is None else {**base, **spec}
            if joints:
                merged[section] = joints
        assumptions += fragment.get("assumptions", [])
        if "calibration" in fragment:
            merged.setdefault("calibration", fragment["calibration"])
    merged["assumptions"] = assumptions + list(raw.get("assumptions", []))
    return merged


#: The keys :func:`_merge_fragments` reads from the scenario, and their schema.
_MERGED = ("include", "drives", "brakes", "assumptions")
_MERGED_SCHEMA = {"type": "object", "properties": {k: SCHEMA["properties"][k] for k in _MERGED}}


def _same_file(path: Path, source: str) -> bool:
    """Whether ``path`` is the file ``source`` names (False if either cannot be looked at)."""
    try:
        return source != "" and path.exists() and path.samefile(source)
    except (OSError, ValueError):
        return False


def build_integrator(spec: Mapping[str, Any], duration: float, source: str = "") -> Integrator:
    """The integrator a scenario's ``integrator`` mapping asks for (defaults: rk4, 1e-4 s).

    Args:
        spec: The ``integrator`` mapping: method, dt or rtol / atol / output_dt, max_steps.
        duration: Simulated time [s].
        source: File name used in messages.

    Raises:
        ScenarioError: A value out of range, a key that does not apply to the method, a step
            or output period longer than the run, or a fixed-step run of more than
            ``max_steps`` steps (an output of more than ``max_steps`` samples).
    """
    check_schema(spec, SCHEMA["properties"]["integrator"], source, ScenarioError, "integrator")
    return _integrator(spec, duration, source)


def _integrator(spec: Mapping[str, Any], duration: float, source: str) -> Integrator:
    """:func:`build_integrator` of a ``spec`` that the schema check has passed."""
    method = spec.get("method", "rk4")
    max_steps = int(spec.get("max_steps", DEFAULT_MAX_STEPS))
    if method not in FIXED_STEP:
        if "dt" in spec:
            raise ScenarioError(
                source, "integrator.dt", f"{method} chooses its own steps: give rtol / atol instead"
            )
        rtol, atol = float(spec.get("rtol", 1e-8)), float(spec.get("atol", 1e-10))
        output_dt = float(spec["output_dt"]) if "output_dt" in spec else None  # [s]
        samples = duration / (output_dt or duration)  # more than max_steps of them: a typo
        if output_dt is not None and (output_dt > duration or samples > max_steps * (1 + 1e-9)):
            raise ScenarioError(
                source,
                "integrator.output_dt",
                f"{output_dt:g} s must be in (0, duration = {duration:g}] s, with duration / "
                f"output_dt = {steps_text(samples)} samples at most max_steps = {max_steps}",
            )
        return DOP853(rtol=rtol, atol=atol, max_steps=max_steps, output_dt=output_dt)
    if "output_dt" in spec:
        raise ScenarioError(
            source,
            "integrator.output_dt",
            f"applies to dop853 only: {method} is a fixed-step method and already samples every dt",
        )
    wrong = sorted({"rtol", "atol"} & set(spec))
    if wrong:
        raise ScenarioError(
            source, f"integrator.{wrong[0]}", f"applies to dop853 only, not to {method}"
        )
    dt = float(spec.get("dt", DEFAULT_DT))
    if dt > duration:
        raise ScenarioError(
            source, "integrator.dt", f"{dt} must be a finite step in (0, duration = {duration}] s"
        )
    steps = duration / dt
    if steps > max_steps * (1.0 + 1e-9):
        raise ScenarioError(
            source,
            "integrator.dt",
            f"{method} with dt = {dt:g} s would take {steps_text(steps)} steps for "
            f"{duration:g} s; the limit is {max_steps}: set integrator.max_steps, or a larger dt",
        )
    fixed: Integrator = INTEGRATORS[method](dt=dt, max_steps=max_steps)
    return fixed


def _constraint(
    robot: Robot, spec: Mapping[str, Any], source: str, key: str, names: dict[str, str]
) -> FrameConstraint:
    """The frame constraint of ``spec``; ``names`` maps the names taken to their keys."""
    kind = spec["type"]
    name = spec.get("name", f"{kind}{len(names)}")
    if name in names:
        raise ScenarioError(source, f"{key}.name", f"'{excerpt(name)}' is used twice")
    names[name] = f"{key}.target" if "target" in spec else key
    if kind == "loop" and "frame_b" not in spec:
        raise ScenarioError(source, key, "a loop closure needs frame_b")
    if kind == "dock" and "frame_b" in spec:
        raise ScenarioError(source, f"{key}.frame_b", "a docking has no frame_b (use target)")
    if kind == "loop" and "target" in spec:
        raise ScenarioError(source, f"{key}.target", "a loop closure has no target")
    target = None
    if "target" in spec:
        xyz = spec["target"].get("xyz")
        if xyz is None:
            raise ScenarioError(source, f"{key}.target", "needs xyz [m]")
        rpy = spec["target"].get("rpy", [0.0, 0.0, 0.0])
        target = pin.SE3(pin.rpy.rpyToMatrix(*map(float, rpy)), np.array(xyz, dtype=float))
    try:
        constraint = FrameConstraint(
            name=name,
            frame_a=spec["frame_a"],
            frame_b=spec.get("frame_b"),
            mode=spec.get("mode", "point"),
            axes=tuple(spec.get("axes", ())),
            target=target,
        )
        constraint.check(robot.model)
    except ConstraintError as exc:
        raise ScenarioError(source, key, str(exc)) from exc
    return constraint


def _brakes(raw: Mapping[str, Any], source: str) -> tuple[Brake, ...]:
    brakes = []
    for joint, spec in raw.items():
        if spec is None:  # this joint has no brake (not even the robot data file's)
            continue
        key = f"brakes.{excerpt(joint)}"
        try:
            brakes.append(
                Brake(
                    joint=joint,
                    delay=float(spec.get("delay", 0.0)),
                    friction=_friction(spec, source, key),
                )
            )
        except BrakeError as exc:
            raise ScenarioError(source, key, str(exc)) from exc
    return tuple(brakes)


def _friction(spec: Mapping[str, Any], source: str, key: str) -> FrictionLaw:
    """The friction law of one brake's mapping (motor side figures)."""
    law = spec.get("friction", "coulomb")
    figures = {
        "sliding_torque",
        "static_torque",
        "friction",
        "stribeck_velocity",
        "viscous_velocity",
    } & set(spec)
    if spec.get("ideal", False):
        if figures:
            raise ScenarioError(
                source,
                key,
                "an ideal brake locks at engagement: drop " + " and ".join(sorted(figures)),
            )
        return IdealLock()
    if "sliding_torque" not in spec:
        raise ScenarioError(source, key, "needs sliding_torque [N m] (or ideal: true)")
    for figure, owner in (("stribeck_velocity", "stribeck"), ("viscous_velocity", "viscous")):
        if (figure in spec) != (law == owner):
            raise ScenarioError(
                source, key, f"{figure} [rad/s] goes with friction: {owner}, and only there"
            )
    sliding, static = float(spec["sliding_torque"]), spec.get("static_torque")
    ramp = float(spec.get("ramp", 0.0))
    if law == "stribeck":
        velocity = float(spec["stribeck_velocity"])
        return Stribeck(sliding, static, ramp=ramp, stribeck_velocity=velocity)
    if law == "viscous":
        velocity = float(spec["viscous_velocity"])
        return Viscous(sliding, static, ramp=ramp, viscous_velocity=velocity)
    return Coulomb(sliding, static, ramp=ramp)


def _stop(robot: Robot, raw: Any, source: str, assumptions: list[str]) -> Stop | None:
    if raw is None:
        return None
    limit = raw.get("torque_limit")
    if isinstance(limit, (int, float)):
        limit = [float(limit)] * robot.nv
    if limit is None and raw.get("category", 0) == 1:
        limit = _effort_limits(robot, source)
        shown = ", ".join(f"{x:g}" for x in limit)
        assumptions.append(
            f"Category-1 drive torque limits default to the URDF effort limits [{shown}] N m "
            "(joint side)."
        )
    torque_limit = (
        None if limit is None else _joint_vector(robot, limit, source, "stop.torque_limit")
    )
    t = float(raw.get("t", 0.0))
    try:
        return Stop(
            t=t,
            category=int(raw.get("category", 0)),
            ramp_time=raw.get("ramp_time"),
            torque_limit=torque_limit,
            time_limit=raw.get("time_limit"),
            gain=float(raw.get("gain", DEFAULT_GAIN)),
            rest_speed=float(raw.get("rest_speed", DEFAULT_REST_SPEED)),
        )
    except BrakeError as exc:
        raise ScenarioError(source, "stop", str(exc)) from exc


def _effort_limits(robot: Robot, source: str) -> list[float]:
    """The URDF's effort limits [N m], the category-1 torque limits when none are given."""
    effort = [float(x) for x in robot.model.effortLimit]
    for joint, x in zip(robot.joints, effort, strict=True):
        if not (math.isfinite(x) and x > 0.0):
            raise ScenarioError(
                source,
                "stop.torque_limit",
                f"the URDF gives joint '{joint}' no effort limit to default to: give "
                "torque_limit [N m] for category 1",
            )
    return effort


def run_scenario(
    scenario: Scenario,
    transition: str | None = None,
    progress: Callable[[float], None] | None = None,
) -> SimulationResult:
    """Simulate a scenario, optionally with another transition rule than its own.

    ``progress`` is called with the simulated time [s] as the run advances (see
    :func:`vtm_pin.simulation.simulate`).

    Raises:
        ScenarioError: The integrator needed more than ``integrator.max_steps`` steps, a
            frame constraint activated away from where it holds (named by its key), or frame
            constraints turned out redundant in the configuration reached.
        SimulationError: The simulation diverged.
    """
    try:
        return simulate(
            scenario.problem,
            scenario.integrator,
            transition=transition or scenario.transition,
            progress=progress,
        )
    except (StepLimitError, ConstraintNotMet, ConstraintError) as exc:
        raise scenario_failure(scenario, exc) from exc


def scenario_failure(scenario: Scenario, exc: Exception) -> Exception:
    """The error to report for a run of ``scenario`` that ended with ``exc``.

    A step limit, a frame constraint activated away from where it holds, or redundant frame
    constraints become a :class:`ScenarioError` naming the key to change; anything else is
    returned as it is.
    """
    if isinstance(exc, StepLimitError):
        return ScenarioError(scenario.source, "integrator.max_steps", str(exc))
    if isinstance(exc, ConstraintNotMet):
        key = scenario.constraint_keys.get(exc.name, "events")
        return ScenarioError(scenario.source, key, str(exc))
    if isinstance(exc, ConstraintError):  # redundant rows in the configuration reached
        return ScenarioError(scenario.source, "", str(exc))
    return exc


def _check_joint(robot: Robot, joint: str, source: str, key: str) -> None:
    if joint not in robot.joints:
        raise ScenarioError(
            source,
            key,
            f"unknown joint '{excerpt(joint)}'; the joints are: {', '.join(robot.joints)}",
        )


def _joint_vector(robot: Robot, value: Any, source: str, key: str) -> np.ndarray:
    n = robot.nv
    if isinstance(value, Mapping):
        out = np.zeros(n)
        for joint, x in value.items():
            _check_joint(robot, str(joint), source, key)
            out[robot.joint_index(str(joint))] = float(x)
    else:
        if len(value) != n:
            raise ScenarioError(
                source,
                key,
                f"has {len(value)} values but the robot has {n} joints ({', '.join(robot.joints)})",
            )
        out = np.array(value, dtype=float)
    if not np.all(np.isfinite(out)):
        raise ScenarioError(source, key, "values must be finite numbers")
    return out


def _check_schema(
    raw: Mapping[str, Any], source: str, valid: Mapping[str, Any] | None = None
) -> None:
    check_schema(raw, SCHEMA, source, ScenarioError, valid=valid)


def passes_schema(raw: Any) -> bool:
    """Whether a parsed scenario passes the scenario schema (includes not merged)."""
    try:
        _check_schema(raw, "")
    except ScenarioError:
        return False
    return True
