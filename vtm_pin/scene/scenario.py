"""Scenario files: the YAML schema, its validation, and the validated :class:`Scenario`."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from ..core.holonomic import FrameConstraint
from ..core.problem import LockEvent, Problem, check_transition
from ..core.results import SimulationResult
from ..core.simulation import simulate
from ..exceptions import (
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
from ..files.inputs import check_schema, read_yaml
from ..numerics.integrators import DEFAULT_MAX_STEPS, DOP853, FIXED_STEP, INTEGRATORS, Integrator
from ..numerics.integrators.base import steps_text
from ..physics.brakes import Brake
from ..physics.friction import Coulomb, FrictionLaw, IdealLock, Stribeck, Viscous
from ..physics.payload import Payload, attached, describe_payload, inertia_matrix
from ..physics.robot import Drive, Robot, load_robot, robot_data
from ..physics.stop import DEFAULT_GAIN, DEFAULT_REST_SPEED, Stop
from ..schemas import load_schema
from ..standards.bounds import BoundSpec, Uncertainty, parse_bounds
from ..standards.separation import Separation, parse_separation
from .annex_b import Conditions, TestState, compute_test_state, describe_conditions
from .annex_b_batch import solve_poses

#: JSON schema of a scenario file: ``vtm_pin/schemas/scenario.schema.json`` with its ``$ref``
#: inlined (:func:`vtm_pin.schemas.load_schema`). Each key's ``description`` gives its unit,
#: range and default; the method and transition names are those of INTEGRATORS and TRANSITIONS.
SCHEMA: dict[str, Any] = load_schema("scenario")

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
    """The parsed YAML of a scenario file, read within :mod:`vtm_pin.files.inputs`' limits."""
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
        loader: Loads the robot, with :func:`vtm_pin.physics.robot.load_robot`'s arguments (studies
            pass a cached one; the robot it returns is never modified).
        valid: A scenario known to pass the schema (:func:`passes_schema`), such as a study's
            base: top-level keys of ``raw`` equal to its own are not checked again.

    Raises:
        ScenarioError: The mapping breaks the schema or names unknown robots or joints.
    """
    if not isinstance(raw, Mapping):
        raise ScenarioError(source, "", "a scenario must be a mapping of keys to values")
    _check_schema(raw, source, valid)
    given, shared = raw, _BASE.find(raw, valid, base_dir)
    # the keys the merge reads were checked just above
    raw = _merge(raw, source, base_dir) if shared is None else shared.merged(raw)
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
            brakes=_brakes(raw.get("brakes", {}), source) if shared is None else shared.brakes,
            stop=_stop(robot, raw.get("stop"), source, assumptions),
            constraints=constraints,
            baumgarte=(float(stab.get("alpha", 10.0)), float(stab.get("beta", 10.0))),
        )
        check_transition(problem, transition)
    except ProblemError as exc:
        raise ScenarioError(source, exc.key, exc.problem) from exc
    if shared is None:
        _BASE.keep(given, valid, base_dir, raw, problem.brakes)

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


#: The scenario keys that decide its merge (:func:`_merge`) and so its brakes; those it writes.
_MERGE_INPUTS = ("include", "drives", "brakes", "assumptions", "calibration", "robot", "stop")
_MERGE_OUTPUTS = ("drives", "brakes", "assumptions", "calibration")
_ABSENT = object()


@dataclass(frozen=True)
class _Merged:
    """What a base's cases share when they do not change what its merge reads: see :class:`_Base`.

    Attributes:
        valid: The base (``build_scenario``'s ``valid``), kept so that it is found by identity.
        base_dir: The folder the merge read relative paths from.
        written: The values of the keys the merge writes, in the merged scenario's order.
        brakes: The brakes of the merged scenario.
    """

    valid: Mapping[str, Any]
    base_dir: Path | None
    written: Mapping[str, Any]
    brakes: tuple[Brake, ...]

    def merged(self, raw: Mapping[str, Any]) -> dict[str, Any]:
        """``raw`` merged: its values, less ``include``, with the merge's, as :func:`_merge`."""
        out = {key: value for key, value in raw.items() if key != "include"}
        out.update(self.written)
        return out


class _Base:
    """The merge and the brakes of the last base's cases, made once (by its first build).

    A study builds each case as a variant of a base known to pass the schema (``valid``, whose
    values its cases hold as the same objects where they do not change them, unchanged by
    that contract). A case that holds every value the merge reads (:data:`_MERGE_INPUTS`) as
    its base's own is merged and braked as the first such build was, without reading the
    included fragments or the robot data file again, nor parsing its brakes: measured (issue
    27, the UR10 envelope study), ~0.08 ms less a case's ~0.28 ms build. A robot data file
    edited during a study is read again by its next base, not its next case.
    """

    def __init__(self) -> None:
        self.last: _Merged | None = None

    def find(
        self, raw: Mapping[str, Any], valid: Mapping[str, Any] | None, base_dir: Path | None
    ) -> _Merged | None:
        """What ``raw``'s merge and brakes are, if they are the last base's; else None."""
        last = self.last
        if last is None or valid is None or last.valid is not valid or last.base_dir != base_dir:
            return None
        return last if _holds_inputs(raw, valid) else None

    def keep(
        self,
        raw: Mapping[str, Any],
        valid: Mapping[str, Any] | None,
        base_dir: Path | None,
        merged: Mapping[str, Any],
        brakes: tuple[Brake, ...],
    ) -> None:
        """Keep what a built case's merge gave, if its merge inputs are its base's own."""
        if valid is None or not _holds_inputs(raw, valid):
            return
        written = {key: value for key, value in merged.items() if key in _MERGE_OUTPUTS}
        self.last = _Merged(valid, base_dir, written, brakes)


def _holds_inputs(raw: Mapping[str, Any], valid: Mapping[str, Any]) -> bool:
    """Whether ``raw`` holds every value its merge reads as ``valid``'s own (or lacks it too)."""
    return all(raw.get(key, _ABSENT) is valid.get(key, _ABSENT) for key in _MERGE_INPUTS)


_BASE = _Base()


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
        return attached(robot, payload)
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


def solve_variant_poses(
    scenario: Scenario, raw: Mapping[str, Any], variants: Iterable[Mapping[str, Any]]
) -> int:
    """Solve the Annex-B poses of many variants of a built scenario at once (a study's cases).

    The variants with ``raw``'s robot and tool frame (``raw`` being what ``scenario`` was built
    from) and an ``annex_b`` key are grouped by their guess pose (``initial.q``), and each
    group's extensions are solved together (:func:`vtm_pin.scene.annex_b_batch.solve_poses`):
    their builds then find their poses in the pose cache. Nothing else of a variant is read or
    checked here: a variant this cannot read, or whose poses cannot be set up, is left to its
    own build, which solves its pose or reports the problem.

    Returns:
        The number of poses solved.
    """
    if scenario.test_state is None:
        return 0
    robot, frame = scenario.problem.robot, scenario.tool_frame
    groups: dict[bytes, tuple[np.ndarray, list[float]]] = {}
    for variant in variants:
        spec = variant.get("annex_b")
        if not isinstance(spec, Mapping) or any(
            variant.get(key) != raw.get(key) for key in ("robot", "tool_frame")
        ):
            continue
        initial = variant.get("initial")
        try:
            guess = (
                _joint_vector(robot, initial["q"], "", "initial.q")
                if initial is not None
                else pin.neutral(robot.model)
            )
            extension = float(spec.get("extension", 1.0))
        except (VtmError, KeyError, TypeError, ValueError):
            continue
        groups.setdefault(guess.tobytes(), (guess, []))[1].append(extension)
    solved = 0
    for guess, extensions in groups.values():
        try:
            solved += solve_poses(robot, frame, guess, extensions)
        except (VtmError, ValueError, np.linalg.LinAlgError):
            continue  # an optimisation only: the cases' own builds solve or report these
    return solved


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
    brakes of the robot data file (:func:`vtm_pin.physics.robot.robot_data`) then fill in every
    joint the scenario and its fragments give no brake (a joint given ``null`` keeps none). The
    result has no ``include`` key and names every brake: merging it again changes nothing.

    Raises:
        ScenarioError: A fragment or the robot data file cannot be read or breaks its schema;
            ``include``, ``drives``, ``brakes`` or ``assumptions`` of ``raw`` break theirs, or
            a scenario includes itself.
    """
    # the keys merged must have their form first (the rest of raw is checked when it is built)
    check_schema({k: raw[k] for k in _MERGED if k in raw}, _MERGED_SCHEMA, source, ScenarioError)
    return _merge(raw, source, base_dir)


def _merge(raw: Mapping[str, Any], source: str, base_dir: Path | None) -> Mapping[str, Any]:
    """:func:`merge_includes` of a scenario whose merged keys (``_MERGED``) passed the schema.

    A study case of a merged base (no ``include``) reads no fragment; the robot data file is
    read and checked once per process (:func:`vtm_pin.physics.robot.robot_data` keeps it, by
    modification time and size), so the merge costs a look-up.
    """
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
    category = raw.get("category", 0)
    if limit is None and category in (1, 2):
        limit = _effort_limits(robot, source)
        shown = ", ".join(f"{x:g}" for x in limit)
        assumptions.append(
            f"Category-{category} drive torque limits default to the URDF effort limits "
            f"[{shown}] N m (joint side)."
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
    """The URDF's effort limits [N m], the category-1/2 torque limits when none are given."""
    effort = [float(x) for x in robot.model.effortLimit]
    for joint, x in zip(robot.joints, effort, strict=True):
        if not (math.isfinite(x) and x > 0.0):
            raise ScenarioError(
                source,
                "stop.torque_limit",
                f"the URDF gives joint '{joint}' no effort limit to default to: give "
                "torque_limit [N m] for categories 1 and 2",
            )
    return effort


def run_scenario(
    scenario: Scenario,
    transition: str | None = None,
    progress: Callable[[float], None] | None = None,
) -> SimulationResult:
    """Simulate a scenario, optionally with another transition rule than its own.

    ``progress`` is called with the simulated time [s] as the run advances (see
    :func:`vtm_pin.core.simulation.simulate`).

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
    if not np.isfinite(out).all():
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
