"""Study files: one base scenario, what varies, and the cases that come out of it.

A study file names a base scenario and the settings that vary::

    scenario: ../scenarios/ur10_annex_b.yaml   # relative to the study file, or a shipped name
    vary:
      joint: [shoulder_pan_joint, shoulder_lift_joint, elbow_joint]
      speed: [0.33, 0.66, 1.0]
      payload: [0.0, 5.0, 10.0]

Without ``samples`` the cases are the full grid of the lists, in the file's axis order (the
last axis varies fastest). With ``samples: N`` (and ``seed``) each case draws every axis: a
range ``{min, max}`` quasi-randomly (a scrambled Halton sequence, :mod:`scipy.stats.qmc`), a
list uniformly from its entries.

An axis is a named axis of :data:`NAMED_AXES` or a scenario key path (``stop.t``,
``brakes.elbow_joint.sliding_torque``, ``brakes.*.delay`` for every brake). Each case's
scenario is the base scenario with its values set (:func:`resolve_case`); running it is
:mod:`vtm_pin.study_runner`'s job.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import numpy as np

from .exceptions import StudyError, excerpt
from .inputs import check_schema, find_shipped, read_yaml

#: Folder of the studies shipped with the project: ``studies/`` at the top of the source tree,
#: installed as the package data ``vtm_pin.studies``.
STUDIES_DIR = Path(str(resources.files("vtm_pin.studies")))
#: Most cases one study may have.
MAX_CASES = 1_000_000
#: Axis values: a finite number, a string (a joint name), or null (``failed_brake: none``).
_VALUE = {
    "oneOf": [
        {"type": "number", "minimum": -1.0e9, "maximum": 1.0e9},
        {"type": "string"},
        {"type": "null"},
    ]
}
_RANGE = {
    "type": "object",
    "additionalProperties": False,
    "required": ["min", "max"],
    "properties": {
        "min": {"type": "number", "minimum": -1.0e9, "maximum": 1.0e9},
        "max": {"type": "number", "minimum": -1.0e9, "maximum": 1.0e9},
    },
    "description": "A range drawn quasi-randomly in sampled studies.",
}
#: JSON schema of a study file.
STUDY_SCHEMA: dict[str, Any] = {
    "type": "object",
    "additionalProperties": False,
    "required": ["scenario", "vary"],
    "properties": {
        "description": {"type": "string", "description": "Free text shown in the report."},
        "scenario": {
            "type": "string",
            "description": "Base scenario: a path relative to the study file, or the name of "
            "a shipped scenario.",
        },
        "vary": {
            "type": "object",
            "minProperties": 1,
            "description": "Axis name or scenario key path -> list of values, or {min, max} "
            "(sampled studies only).",
            "additionalProperties": {
                "oneOf": [{"type": "array", "items": _VALUE, "minItems": 1}, _RANGE]
            },
        },
        "samples": {
            "type": "integer",
            "minimum": 1,
            "maximum": MAX_CASES,
            "description": "Number of cases drawn. Default: the full grid of the lists.",
        },
        "seed": {
            "type": "integer",
            "minimum": 0,
            "maximum": 2**32 - 1,
            "description": "Seed of the sampled draws. Default: 0.",
        },
    },
}


def _set_annex_b(key: str) -> Callable[[dict[str, Any], Any], None]:
    def setter(raw: dict[str, Any], value: Any) -> None:
        raw.setdefault("annex_b", {})[key] = value

    return setter


def _set_payload(raw: dict[str, Any], value: Any) -> None:
    raw.setdefault("payload", {})["mass"] = value


def _set_category(raw: dict[str, Any], value: Any) -> None:
    raw.setdefault("stop", {})["category"] = value


def _scale_brakes(raw: dict[str, Any], value: Any) -> None:
    for spec in raw.get("brakes", {}).values():
        for key in ("sliding_torque", "static_torque"):
            if spec is not None and key in spec:
                spec[key] = spec[key] * value
    raw.setdefault("assumptions", []).append(
        f"Worn brakes (study axis brake_scale): every brake torque stated above is scaled by "
        f"{value:g} in this case."
    )


def _fail_brake(raw: dict[str, Any], value: Any) -> None:
    if value is not None and value != "none":
        raw.setdefault("brakes", {})[value] = None  # no brake, not even the robot data's
        raw.setdefault("assumptions", []).append(
            f"Single fault (study axis failed_brake): the brake of {value} gives no torque in "
            "this case."
        )


#: The named axes: how each sets its value into a case's scenario, and its description.
NAMED_AXES: dict[str, tuple[Callable[[dict[str, Any], Any], None], str]] = {
    "joint": (_set_annex_b("joint"), "joint under test (annex_b.joint)"),
    "speed": (_set_annex_b("speed"), "fraction of the tested joint's maximum speed [-]"),
    "extension": (_set_annex_b("extension"), "fraction of the arm's maximum reach [-]"),
    "payload": (_set_payload, "payload mass at the tool frame [kg] (payload.mass)"),
    "category": (_set_category, "stop category, 0 or 1 (stop.category)"),
    "brake_scale": (
        _scale_brakes,
        "worn brakes: every brake's sliding and static torque times this [-]",
    ),
    "failed_brake": (
        _fail_brake,
        "single fault: this joint's brake gives no torque (none: every brake works)",
    ),
}


@dataclass(frozen=True)
class Case:
    """One case of a study.

    Attributes:
        id: Stable id: a hash of the axis values (and, in sampled studies, the draw's index).
        index: Position in the study.
        values: Axis name -> value, in the study's axis order.
    """

    id: str
    index: int
    values: Mapping[str, Any]


@dataclass(frozen=True)
class Study:
    """A validated study file.

    Attributes:
        source: The study file.
        name: Its stem, used to name outputs.
        description: Free text.
        scenario: The base scenario file.
        base: The base scenario as parsed (never modified: cases copy it).
        axes: Axis name -> list of values, or (min, max) for a sampled range.
        samples: Number of sampled cases, or None for the full grid.
        seed: Seed of the draws.
        fingerprint: Hash of the study and its base scenario: a folder of results holds one
            fingerprint, so that a changed study is not mixed with old results.
    """

    source: str
    name: str
    description: str
    scenario: Path
    base: Mapping[str, Any]
    axes: Mapping[str, list[Any] | tuple[float, float]]
    samples: int | None
    seed: int
    fingerprint: str

    @property
    def mode(self) -> str:
        """``grid`` or ``sampled``."""
        return "grid" if self.samples is None else "sampled"

    @property
    def size(self) -> int:
        """How many cases the study has."""
        if self.samples is not None:
            return self.samples
        return math.prod(len(values) for values in self.axes.values())

    def cases(self) -> list[Case]:
        """The study's cases, in order (see the module docstring)."""
        return _grid(self) if self.samples is None else _sampled(self)

    def describe_axes(self) -> dict[str, Any]:
        """The axes as JSON-ready data: lists, or {min, max} for ranges."""
        return {
            name: {"min": values[0], "max": values[1]} if isinstance(values, tuple) else values
            for name, values in self.axes.items()
        }


def find_study(spec: str | Path) -> Path:
    """The study file ``spec`` names: an existing path, else a shipped study's name.

    Raises:
        StudyError: ``spec`` is a bare name that is neither a file nor a shipped study.
    """
    return find_shipped(spec, STUDIES_DIR, "study", StudyError)


def load_study(path: str | Path) -> Study:
    """Read and validate a study file, and its base scenario (fragments it includes merged).

    Each case's scenario is validated when it runs (a case that breaks the scenario rules is
    recorded as failed with its message); the axes and their values are checked here.

    Raises:
        StudyError: The study file is missing, malformed, or its scenario cannot be read;
            an axis is not a named axis nor a key path of the base scenario; a value of the
            wrong kind for its axis, or listed twice; a range in a grid study; more than
            :data:`MAX_CASES` cases.
    """
    path = Path(path)
    source = str(path)
    raw = read_yaml(path, StudyError)
    if not isinstance(raw, Mapping):
        raise StudyError(source, "", "a study must be a mapping of keys to values")
    check_schema(raw, STUDY_SCHEMA, source, StudyError)
    scenario, base = _read_base(path, str(raw["scenario"]))
    samples = raw.get("samples")
    axes = {
        name: _axis(name, values, base, source, samples) for name, values in raw["vary"].items()
    }
    count = samples or int(np.prod([len(v) for v in axes.values()], dtype=float))
    if count > MAX_CASES:
        raise StudyError(source, "vary", f"{count} cases; a study may have at most {MAX_CASES}")
    fingerprint = _hash(
        {
            "study": raw,
            "scenario": base,
            "robot": _robot_digest(base, scenario.parent),
            "vtm_pin": _version(),
        }
    )
    return Study(
        source=source,
        name=path.stem,
        description=str(raw.get("description", "")),
        scenario=scenario,
        base=base,
        axes=axes,
        samples=samples,
        seed=int(raw.get("seed", 0)),
        fingerprint=fingerprint,
    )


def _read_base(path: Path, spec: str) -> tuple[Path, Mapping[str, Any]]:
    """The base scenario's file and its parsed YAML, with the fragments it includes merged."""
    from .pipeline import find_scenario  # the pipeline imports the scenario machinery
    from .scenario import ScenarioError, merge_includes

    source = str(path)
    local = path.parent / spec
    scenario = local
    try:
        scenario = local if local.is_file() else find_scenario(spec)
        base = read_yaml(scenario, StudyError)
        if not isinstance(base, Mapping):
            raise StudyError(source, "scenario", f"{scenario} is not a scenario (not a mapping)")
        return scenario, merge_includes(base, str(scenario), scenario.parent)
    except ScenarioError as exc:
        where = f"'{exc.key}': " if exc.key else ""
        raise StudyError(source, "scenario", f"{where}{exc.problem}") from exc
    except StudyError as exc:
        if exc.source == source:
            raise
        raise StudyError(source, "scenario", f"{scenario}: {exc.problem}") from exc


#: The kind of value each named axis takes: a test on one value, and what is allowed.
_KINDS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "joint": (lambda v: isinstance(v, str), "a joint name"),
    "failed_brake": (lambda v: isinstance(v, str), "a joint name, or none"),
    "category": (lambda v: v in (0, 1) and not isinstance(v, bool), "0 or 1"),
    "speed": (lambda v: _number(v) and 0.0 < v <= 1.0, "a fraction in (0, 1]"),
    "extension": (lambda v: _number(v) and 0.0 < v <= 1.0, "a fraction in (0, 1]"),
    "payload": (lambda v: _number(v) and v >= 0.0, "a mass >= 0 kg"),
    "brake_scale": (lambda v: _number(v) and v > 0.0, "a factor > 0"),
}


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _axis(
    name: str, values: Any, base: Mapping[str, Any], source: str, samples: int | None
) -> list[Any] | tuple[float, float]:
    """One checked axis: its list of values, or its (min, max) range."""
    from .scenario import SCHEMA

    _check_axis(name, base, SCHEMA, source)
    key = f"vary.{excerpt(name)}"
    check, allowed = _KINDS.get(name, (lambda v: True, ""))
    if isinstance(values, Mapping):
        if samples is None:
            raise StudyError(
                source, key, "a range {min, max} needs samples: N (a grid study takes lists)"
            )
        if not values["min"] <= values["max"]:
            raise StudyError(source, key, "min must be <= max")
        if not (check(values["min"]) and check(values["max"])):
            raise StudyError(source, key, f"the range must hold {allowed}")
        return (float(values["min"]), float(values["max"]))
    for value in values:
        if not check(value):
            raise StudyError(source, key, f"{_shown(value)} is not {allowed}")
    repeated = [v for i, v in enumerate(values) if v in values[:i]]
    if repeated:
        raise StudyError(source, key, f"{_shown(repeated[0])} is listed twice")
    if name == "failed_brake":
        _check_failed_brakes(list(values), base, source)
    return list(values)


def _shown(value: Any) -> str:
    """A value for a message: text in quotes, others as they are."""
    return f"'{excerpt(value)}'" if isinstance(value, str) else excerpt(value)


def _robot_digest(base: Mapping[str, Any], folder: Path) -> str:
    """A digest of the robot's files (URDF and data file), or the package it comes from."""
    from .robot import ROBOTS_DIR, robot_data_file

    spec = str(base.get("robot", ""))
    side = robot_data_file(spec)
    extra = side.read_bytes() if side is not None else b""
    for candidate in (folder / spec, ROBOTS_DIR / f"{spec}.urdf"):
        try:
            if candidate.is_file():
                data = candidate.read_bytes()
                side = candidate.with_suffix(".yaml")
                data += side.read_bytes() if side.is_file() else extra
                return hashlib.sha256(data).hexdigest()
        except (OSError, ValueError):
            continue
    try:
        package = f"example-robot-data {version('example-robot-data')}"
    except PackageNotFoundError:
        package = "unknown"
    return package + (f", {hashlib.sha256(extra).hexdigest()}" if extra else "")


def _version() -> str:
    try:
        return version("vtm_pin")
    except PackageNotFoundError:
        return "unknown"


def _check_axis(name: str, base: Mapping[str, Any], schema: Mapping[str, Any], source: str) -> None:
    """Refuse an axis that is neither named nor a key path the scenario schema allows."""
    if name in NAMED_AXES:
        return
    parts = name.split(".")
    node: Any = schema
    for part in parts:
        properties = node.get("properties", {}) if isinstance(node, Mapping) else {}
        if part in properties:
            node = properties[part]
        elif isinstance(node, Mapping) and isinstance(node.get("additionalProperties"), Mapping):
            node = node["additionalProperties"]
        else:
            named = ", ".join(NAMED_AXES)
            raise StudyError(
                source,
                f"vary.{excerpt(name)}",
                f"not a named axis ({named}) nor a scenario key path (e.g. stop.t, "
                "brakes.elbow_joint.sliding_torque, brakes.*.delay)",
            )
    if parts[0] == "brakes" and len(parts) > 1 and parts[1] != "*":
        if base.get("brakes", {}).get(parts[1]) is None:
            raise StudyError(
                source,
                f"vary.{excerpt(name)}",
                f"the base scenario has no brake on '{excerpt(parts[1])}'",
            )


def _check_failed_brakes(values: list[Any], base: Mapping[str, Any], source: str) -> None:
    brakes = [joint for joint, spec in base.get("brakes", {}).items() if spec is not None]
    for value in values:
        if value not in (None, "none") and value not in brakes:
            raise StudyError(
                source,
                "vary.failed_brake",
                f"'{excerpt(value)}' has no brake in the base scenario; brakes: "
                f"{', '.join(brakes) or 'none'} (or none: no brake fails)",
            )


def _grid(study: Study) -> list[Case]:
    names = list(study.axes)
    lists = [study.axes[name] for name in names]
    cases = []
    for index, combo in enumerate(itertools.product(*lists)):
        values = dict(zip(names, combo, strict=True))
        cases.append(Case(_hash(values)[:12], index, values))
    return cases


def _sampled(study: Study) -> list[Case]:
    from scipy.stats import qmc

    names = list(study.axes)
    assert study.samples is not None
    u = qmc.Halton(d=len(names), scramble=True, seed=study.seed).random(study.samples)
    cases = []
    for index in range(study.samples):
        values: dict[str, Any] = {}
        for k, name in enumerate(names):
            axis = study.axes[name]
            if isinstance(axis, tuple):
                values[name] = float(axis[0] + u[index, k] * (axis[1] - axis[0]))
            else:
                values[name] = axis[min(int(u[index, k] * len(axis)), len(axis) - 1)]
        cases.append(Case(_hash({"sample": index, **values})[:12], index, values))
    return cases


def resolve_case(base: Mapping[str, Any], values: Mapping[str, Any]) -> dict[str, Any]:
    """The base scenario (parsed YAML) with a case's values set; the base is not modified.

    Named axes are set as :data:`NAMED_AXES` says; a key path sets that key, creating the
    mappings on its way; ``*`` in a path stands for every key of the mapping there.
    """
    raw = copy.deepcopy(dict(base))
    for name, value in values.items():
        if name in NAMED_AXES:
            NAMED_AXES[name][0](raw, value)
        else:
            _set_path(raw, name.split("."), value)
    return raw


def _set_path(node: dict[str, Any], parts: Sequence[str], value: Any) -> None:
    head, rest = parts[0], parts[1:]
    targets = list(node) if head == "*" else [head]
    for key in targets:
        if not rest:
            node[key] = value
            continue
        child = node.setdefault(key, {})
        if isinstance(child, dict):
            _set_path(child, rest, value)


def _hash(data: Any) -> str:
    """A stable hex digest of JSON-ready ``data`` (keys sorted, floats by their repr)."""
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()
