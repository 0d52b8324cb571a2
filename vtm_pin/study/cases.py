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
``brakes.elbow_joint.sliding_torque``, ``brakes.*.delay`` for every brake); no two axes may
set the same scenario key. Each case's scenario is the base scenario with its values set
(:func:`resolve_case`); running it is :mod:`vtm_pin.study.runner`'s job.

The whole file is checked before any case runs (:func:`load_study`): the base scenario must
pass the scenario rules and build on its own (with a stop to measure), and so must each axis
value set alone into it (each list entry, each range's min and max). Not checked up front:
values that are invalid only together (a ``stop.t`` axis after a ``duration`` axis's end),
and what depends on the motion (step limits, constraints met too far away): such cases fail
when they run, and are recorded with their message.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import numpy as np

from ..exceptions import InputError, StudyError, VtmError, excerpt
from ..files.inputs import check_schema, find_shipped, read_yaml
from ..schemas import load_schema

#: Folder of the studies shipped with the project: ``studies/`` at the top of the source tree,
#: installed as the package data ``vtm_pin.studies``.
STUDIES_DIR = Path(str(resources.files("vtm_pin.studies")))
#: JSON schema of a study file: ``vtm_pin/schemas/study.schema.json``.
STUDY_SCHEMA: dict[str, Any] = load_schema("study")
#: Most cases one study may have (the schema's largest ``samples``).
MAX_CASES: int = STUDY_SCHEMA["properties"]["samples"]["maximum"]


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


#: The named axes: how each sets its value into a case's scenario, its description, and the
#: scenario key paths it sets (``*``: every key there; two axes may not set the same key).
NAMED_AXES: dict[str, tuple[Callable[[dict[str, Any], Any], None], str, tuple[str, ...]]] = {
    "joint": (_set_annex_b("joint"), "joint under test (annex_b.joint)", ("annex_b.joint",)),
    "speed": (
        _set_annex_b("speed"),
        "fraction of the tested joint's maximum speed [-]",
        ("annex_b.speed",),
    ),
    "extension": (
        _set_annex_b("extension"),
        "fraction of the arm's maximum reach [-]",
        ("annex_b.extension",),
    ),
    "payload": (
        _set_payload,
        "payload mass at the tool frame [kg] (payload.mass)",
        ("payload.mass",),
    ),
    "category": (_set_category, "stop category, 0, 1 or 2 (stop.category)", ("stop.category",)),
    "brake_scale": (
        _scale_brakes,
        "worn brakes: every brake's sliding and static torque times this [-]",
        ("brakes.*.sliding_torque", "brakes.*.static_torque"),
    ),
    "failed_brake": (
        _fail_brake,
        "single fault: this joint's brake gives no torque (none: every brake works)",
        ("brakes.+",),
    ),
}


@dataclass(frozen=True)
class Case:
    """One case of a study.

    Attributes:
        id: Stable id: a hash of the axis values (and, in sampled studies, the draw's index).
        index: Position in the study.
        values: Axis name -> value, in the study's axis order.
        settings: Scenario key paths the case sets besides its axes (a program trigger's
            initial state). A case with settings sets only them: its values then label it
            (table columns), they set nothing.
    """

    id: str
    index: int
    values: Mapping[str, Any]
    settings: Mapping[str, Any] = field(default_factory=dict)


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
    """Read and validate a study file whole, before any case runs.

    Checked here: the study file against its schema; the base scenario (fragments merged)
    against the scenario schema, and built once (robot loaded, joints, Annex-B pose, a stop
    to measure); every axis (a named axis or a key path of the scenario schema, no two
    setting the same key); and every axis value (each list entry, each range's min and max)
    set alone into the base, which must pass the schema and build in turn: one build per
    distinct value, not per case. Not checked here: values of several axes that are invalid
    only together (``stop.t`` after a ``duration`` of another axis), and whatever depends on
    the motion (step limits, a constraint met too far away): such a case fails when it runs
    and is recorded as failed with its message.

    Raises:
        StudyError: The study file is missing, malformed, or its scenario cannot be read or
            built; an axis is not a named axis nor a key path of the base scenario, or sets a
            key another axis sets; a value of the wrong kind for its axis, listed twice, or
            that the scenario refuses; a range in a grid study; more than :data:`MAX_CASES`
            cases.
    """
    path = Path(path)
    source = str(path)
    raw = read_yaml(path, StudyError)
    if not isinstance(raw, Mapping):
        raise StudyError(source, "", "a study must be a mapping of keys to values")
    check_schema(raw, STUDY_SCHEMA, source, StudyError)
    scenario, base = _read_base(path, str(raw["scenario"]))
    samples = None if raw.get("samples") is None else int(raw["samples"])  # 3.0 is 3
    axes = {
        name: _axis(name, values, base, source, samples) for name, values in raw["vary"].items()
    }
    _check_overlaps(list(axes), source)
    count = samples or int(np.prod([len(v) for v in axes.values()], dtype=float))
    if count > MAX_CASES:
        raise StudyError(source, "vary", f"{count} cases; a study may have at most {MAX_CASES}")
    _check_values(source, scenario, base, axes)
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
    from ..outputs.pipeline import find_scenario  # the pipeline imports the scenario machinery
    from ..scene.scenario import ScenarioError, merge_includes

    source = str(path)
    local = path.parent / spec
    scenario = local
    try:
        # a file there (of any kind but a folder: reading refuses a pipe) wins over a shipped
        # name (is_file would send a pipe to the shipped scenarios)
        scenario = local if _exists(local) else find_scenario(spec)
        base = read_yaml(scenario, StudyError)
        if not isinstance(base, Mapping):
            raise StudyError(
                source, "scenario", f"{_name(scenario)} is not a scenario (not a mapping)"
            )
        return scenario, merge_includes(base, str(scenario), scenario.parent)
    except ScenarioError as exc:
        raise StudyError(source, "scenario", _complaint(exc)) from exc
    except StudyError as exc:
        if exc.source == source:
            raise
        raise StudyError(source, "scenario", _complaint(exc)) from exc


def _exists(path: Path) -> bool:
    """Whether ``path`` exists and is not a folder (False for a name too long, or with NUL)."""
    try:
        return path.exists() and not path.is_dir()
    except (OSError, ValueError):
        return False


def _name(path: Path | str) -> str:
    """A file's name for a message, cut to an excerpt (a path may be thousands of characters)."""
    return excerpt(str(path), 200)


def _complaint(exc: Exception) -> str:
    """What a scenario error says: its file, key and problem."""
    if not isinstance(exc, InputError):
        return str(exc)
    where = f"{_name(exc.source)}: " if exc.source else ""
    key = f"'{exc.key}': " if exc.key else ""
    return f"{where}{key}{exc.problem}"


def _check_overlaps(names: Sequence[str], source: str) -> None:
    """Refuse two axes that set the same scenario key (the table would show a value unused)."""
    for i, name in enumerate(names):
        for other in names[:i]:
            for mine, theirs in itertools.product(_writes(name), _writes(other)):
                if _overlap(mine, theirs):
                    raise StudyError(
                        source,
                        f"vary.{excerpt(name)}",
                        f"sets {excerpt(mine)}, which axis {excerpt(other)} sets too"
                        f"{f' ({excerpt(theirs)})' if theirs != other else ''}; vary each "
                        "scenario key in one axis only",
                    )


def _writes(name: str) -> tuple[str, ...]:
    """The scenario key paths an axis sets."""
    return NAMED_AXES[name][2] if name in NAMED_AXES else (name,)


def _overlap(one: str, other: str) -> bool:
    """Whether two key paths set a common key: ``*`` matches any key, a prefix overlaps.

    ``+`` (the brake ``failed_brake`` removes) overlaps a named key, not ``*``: every other
    brake still takes a ``*`` axis's value, and the removed one has none to take.
    """
    pairs = zip(one.split("."), other.split("."), strict=False)  # the shorter is a prefix
    return all(_same_key(a, b) for a, b in pairs)


def _same_key(a: str, b: str) -> bool:
    if "+" in (a, b):
        return "*" not in (a, b)
    return a == b or "*" in (a, b)


def _check_values(
    source: str,
    scenario: Path,
    base: Mapping[str, Any],
    axes: Mapping[str, list[Any] | tuple[float, float]],
) -> None:
    """Build the base scenario, then each axis value set alone into it; refuse the first failure.

    The robot is loaded once: the cost is one build per distinct value, not per case.
    """
    from ..physics.robot import RobotCache
    from ..scene.scenario import passes_schema

    loader = RobotCache()
    valid = base if passes_schema(base) else None
    failure = _build_case(base, {}, scenario, loader, valid)
    if failure is not None:
        raise StudyError(source, "scenario", _complaint(failure)) from failure
    for name, values in axes.items():
        for value in dict.fromkeys(values):  # a range's min and max, once if equal
            failure = _build_case(base, {name: value}, scenario, loader, valid)
            if failure is not None:
                raise StudyError(
                    source,
                    f"vary.{excerpt(name)}",
                    f"{_shown(value)} is refused: {_complaint(failure)}",
                ) from failure


def _build_case(
    base: Mapping[str, Any],
    values: Mapping[str, Any],
    scenario: Path,
    loader: Callable[..., Any],
    valid: Mapping[str, Any] | None,
) -> VtmError | None:
    """Why the base with ``values`` set cannot run as a study case, or None if it can."""
    from ..scene.scenario import build_scenario

    try:
        built = build_scenario(
            resolve_case(base, values),
            source=str(scenario),
            base_dir=scenario.parent,
            name=scenario.stem,
            loader=loader,
            valid=valid,
        )
    except VtmError as exc:
        return exc
    if built.stop is None:
        return StudyError(str(scenario), "stop", "a study case needs a stop to measure")
    if built.bounds is not None:  # its bounds' variant runs must build too
        from ..outputs.figures import bound_variants

        try:
            bound_variants(built, loader)
        except VtmError as exc:
            return exc
    return None


#: The kind of value each named axis takes: a test on one value, and what is allowed.
_KINDS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "joint": (lambda v: isinstance(v, str), "a joint name"),
    "failed_brake": (lambda v: isinstance(v, str), "a joint name, or none"),
    "category": (lambda v: v in (0, 1, 2) and not isinstance(v, bool), "0, 1 or 2"),
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
    from ..scene.scenario import SCHEMA

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
    """A digest of the robot's files (URDF and data file), or the package it comes from.

    A xacro robot is digested as the URDF it expands to, so that a change in a file it
    includes changes the digest too.
    """
    from ..physics.robot import ROBOTS_DIR, robot_data_file

    spec = str(base.get("robot", ""))
    side = robot_data_file(spec)
    extra = side.read_bytes() if side is not None else b""
    for candidate in (folder / spec, ROBOTS_DIR / f"{spec}.urdf"):
        try:
            if candidate.is_file():
                data = _robot_bytes(candidate, base, folder)
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

    The case is a variant of the base (with :data:`FAST_CASES`): only the top-level values its
    axes set are copied, the others are the base's own objects (read only: nothing modifies a
    case's scenario), so that the schema check of a case skips them at once.
    """
    raw = _variant(base, [_touches(name) for name in values])
    for name, value in values.items():
        if name in NAMED_AXES:
            NAMED_AXES[name][0](raw, value)
        else:
            _set_path(raw, name.split("."), value)
    return raw


def case_scenario(base: Mapping[str, Any], case: Case) -> dict[str, Any]:
    """The scenario (parsed YAML) of ``case``: its settings if it has any, else its values."""
    if not case.settings:
        return resolve_case(base, case.values)
    raw = _variant(base, [(path.split(".")[0],) for path in case.settings])
    for path, value in case.settings.items():
        _set_path(raw, path.split("."), value)
    return raw


#: Build each case as a variant of its validated base (:func:`resolve_case` copies only the
#: top-level values it sets; :mod:`vtm_pin.study.runner` checks only those against the schema).
#: False: every case is a deep copy, built and checked whole as a fresh scenario (for tests).
FAST_CASES = True

#: Top-level scenario keys a named axis modifies besides those of its key paths (the brake
#: axes state what they did in ``assumptions``).
_ALSO_TOUCHES = {"brake_scale": ("assumptions",), "failed_brake": ("assumptions",)}


def _touches(name: str) -> tuple[str, ...]:
    """The top-level scenario keys an axis modifies (``*``: any of them)."""
    return tuple(path.split(".")[0] for path in _writes(name)) + _ALSO_TOUCHES.get(name, ())


def _variant(base: Mapping[str, Any], touched: Sequence[tuple[str, ...]]) -> dict[str, Any]:
    """A copy of ``base`` to set values in: its ``touched`` top-level values copied, deeply."""
    keys = {key for keys in touched for key in keys}
    if not FAST_CASES or "*" in keys:
        return copy.deepcopy(dict(base))
    memo: dict[int, Any] = {}
    return {key: _tree_copy(value, memo) if key in keys else value for key, value in base.items()}


def _tree_copy(value: Any, memo: dict[int, Any] | None = None) -> Any:
    """:func:`copy.deepcopy` of a parsed document, at a fraction of its cost.

    Its mappings and lists are copied, each once (a YAML alias stays one object, as
    deepcopy's memo keeps it); strings, numbers, booleans and None are shared; anything else
    is deep-copied (a mapping or list of another type too).
    """
    if value is None or type(value) in (str, int, float, bool):
        return value
    memo = {} if memo is None else memo
    done = memo.get(id(value))
    if done is not None:
        return done
    if type(value) is dict:
        mapping: dict[Any, Any] = {}
        memo[id(value)] = mapping
        mapping.update((key, _tree_copy(item, memo)) for key, item in value.items())
        return mapping
    if type(value) is list:
        items: list[Any] = []
        memo[id(value)] = items
        items.extend(_tree_copy(item, memo) for item in value)
        return items
    memo[id(value)] = out = copy.deepcopy(value)
    return out


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


def _robot_bytes(path: Path, base: Mapping[str, Any], folder: Path) -> bytes:
    """A robot file's bytes; a xacro file's expanded URDF (its raw bytes if it cannot expand)."""
    if path.suffix.lower() != ".xacro":
        return path.read_bytes()
    from ..exceptions import RobotLoadError
    from ..physics.robot import xacro_urdf

    packages = base.get("robot_packages") or {}
    folders = {str(name): str(folder / str(d)) for name, d in packages.items()}
    try:
        return xacro_urdf(path, folders).encode()
    except RobotLoadError:  # building the case will say why, in one line
        return path.read_bytes()
