"""Stops triggered along a robot program: one study case per trigger instant.

A program (:mod:`vtm_pin.scene.program`) is the arm's motion in a cell. The stop can come at
any instant of it, so :func:`load_program_study` makes a study of the base scenario's stop
triggered at instants along the program: every ``every`` seconds of program time, plus the
instants of peak joint speed and peak tool speed. Each trigger is a case that starts from the
program's q and v there (v times the speed override F), with the payload, brakes, stop,
safeguard and bounds of the base scenario. The cases run on the study machinery
(:func:`vtm_pin.study.runner.run_study`: all cores, Dask, resumable).

Program time is the program's own clock at F = 1: a trigger at program time tau stops the arm
at the program's pose q(tau) with the velocity F v(tau), the same instant of the cycle for
every override (running the program at F stretches its clock by 1/F).

:func:`find_override` bisects on F for the largest override whose every trigger keeps a figure
(S_p by default) within an allowed distance, with the figure's upper bound where the base
scenario asks for bounds.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..exceptions import StudyError, excerpt
from ..scene.program import Program
from .cases import Case, Study, _hash, _read_base, _robot_digest, _version

#: Default spacing of the triggers [s] of program time.
DEFAULT_EVERY = 0.1
#: At most this many triggers per override (a finer spacing is refused).
MAX_TRIGGERS = 5000
#: Figures the override search may bound, with what they are.
SEARCH_FIGURES = {
    "ssm_distance": "S_p of ISO/TS 15066",
    "iso13855_distance": "S of ISO 13855:2024",
    "tcp_max_displacement": "S_s, the tool's largest displacement",
}
#: Default tolerance of the override search [-]: the answer is within this of the largest F.
DEFAULT_TOLERANCE = 0.01


@dataclass(frozen=True)
class Trigger:
    """An instant of the program at which the stop is triggered.

    Attributes:
        time: Program time [s] (the program's clock at F = 1).
        reason: Why it is a trigger: ``every 0.1 s``, ``peak joint speed``, ``peak tool speed``
            (several joined by ``; `` when they coincide).
    """

    time: float
    reason: str


@dataclass(frozen=True)
class ProgramStudy(Study):
    """A study whose cases are a program's triggers, at one or more speed overrides.

    Attributes:
        program: The program (at F = 1).
        triggers: The trigger instants, in time order.
        overrides: The speed overrides F in (0, 1] [-].
    """

    program: Program | None = None
    triggers: tuple[Trigger, ...] = ()
    overrides: tuple[float, ...] = (1.0,)

    @property
    def mode(self) -> str:
        """``program``."""
        return "program"

    @property
    def size(self) -> int:
        """Triggers times overrides."""
        return len(self.triggers) * len(self.overrides)

    def cases(self) -> list[Case]:
        """One case per (override, trigger): the program's state there, v scaled by F."""
        assert self.program is not None
        times = np.array([trigger.time for trigger in self.triggers])
        q, v = self.program.state_at(times)
        q, v = np.atleast_2d(q), np.atleast_2d(v)
        cases: list[Case] = []
        for override in self.overrides:
            for k, trigger in enumerate(self.triggers):
                values = {"override": override, "program_time": trigger.time}
                settings = {
                    "initial.q": [float(x) for x in q[k]],
                    "initial.v": [float(x) * override for x in v[k]],
                }
                case_id = _hash({**values, **settings})[:12]
                cases.append(Case(case_id, len(cases), values, settings))
        return cases

    def at(self, overrides: Sequence[float]) -> ProgramStudy:
        """The same program and triggers at other overrides (its own fingerprint)."""
        overrides = tuple(float(f) for f in overrides)
        fingerprint = _hash({"program study": self.fingerprint, "overrides": overrides})
        return dataclasses.replace(
            self,
            overrides=overrides,
            axes={"override": list(overrides), "program_time": self.axes["program_time"]},
            fingerprint=fingerprint,
        )


def tool_speeds(program: Program, robot: Any) -> np.ndarray:
    """The tool frame's speed at each sample of the program [m/s], shape (m,)."""
    from ..physics.kinematics import compute_tool_motion

    return compute_tool_motion(robot, program.q, program.v)[1]


def make_triggers(program: Program, robot: Any, every: float) -> tuple[Trigger, ...]:
    """Trigger instants every ``every`` seconds, plus peak joint and peak tool speed.

    Raises:
        StudyError: ``every`` is not a finite number > 0, or it gives more than
            :data:`MAX_TRIGGERS` triggers.
    """
    if not (math.isfinite(every) and every > 0.0):
        raise StudyError("command line", "--every", f"{every} s is not a finite number > 0")
    t0, t1 = float(program.t[0]), float(program.t[-1])
    count = math.floor((t1 - t0) / every + 1e-9) + 1
    if count > MAX_TRIGGERS:
        raise StudyError(
            "command line",
            "--every",
            f"{every} s gives {count} triggers over the program's {t1 - t0:g} s; at most "
            f"{MAX_TRIGGERS} are allowed",
        )
    reasons: dict[float, list[str]] = {}
    for k in range(count):
        reasons.setdefault(round(t0 + k * every, 9), []).append(f"every {every:g} s")
    peak_tool = float(program.t[int(np.argmax(tool_speeds(program, robot)))])
    for time, reason in (
        (program.peak_joint_speed_time(), "peak joint speed"),
        (peak_tool, "peak tool speed"),
    ):
        reasons.setdefault(round(float(time), 9), []).append(reason)
    return tuple(Trigger(time, "; ".join(why)) for time, why in sorted(reasons.items()))


def load_program_study(
    program_path: str | Path,
    scenario: str | Path,
    *,
    every: float = DEFAULT_EVERY,
    overrides: Sequence[float] = (1.0,),
) -> ProgramStudy:
    """Read a program and its base scenario, and make the study of its triggers.

    Args:
        program_path: The program file (CSV or Parquet), or a shipped program's name.
        scenario: The base scenario file, or a shipped scenario's name: its robot, payload,
            brakes, stop (t = 0: the signal comes at the trigger), safeguard and bounds.
        every: Spacing of the triggers [s] of program time.
        overrides: Speed overrides F in (0, 1] [-].

    Raises:
        StudyError: A bad override or spacing, a base scenario with ``annex_b`` (which sets its
            own state) or without a stop, or a stop signal after t = 0.
        InputError: The program cannot be read, or breaks its checks (one line naming the row
            and the column).
    """
    from ..physics.robot import RobotCache
    from ..scene.program import find_program, read_program
    from ..scene.scenario import build_scenario

    overrides = _check_overrides(overrides)
    path = find_program(program_path)
    scenario_path, base = _read_base(Path.cwd() / "program.yaml", str(scenario))
    _check_base(base, str(scenario_path))
    robots = RobotCache()
    built = build_scenario(
        dict(base), source=str(scenario_path), base_dir=scenario_path.parent, loader=robots
    )
    program = read_program(path, built.robot)
    triggers = make_triggers(program, built.robot, every)
    fingerprint = _hash(
        {
            "program": _hash({"t": program.t.tolist(), "q": program.q.tolist()}),
            "v": _hash(program.v.tolist()),
            "triggers": [dataclasses.astuple(t) for t in triggers],
            "overrides": list(overrides),
            "scenario": base,
            "robot": _robot_digest(base, scenario_path.parent),
            "vtm_pin": _version(),
        }
    )
    return ProgramStudy(
        source=str(path),
        name=path.stem,
        description=f"Stops along the program {path.name} ({program.duration:g} s), "
        f"base scenario {scenario_path.name}",
        scenario=scenario_path,
        base=base,
        axes={"override": list(overrides), "program_time": [t.time for t in triggers]},
        samples=None,
        seed=0,
        fingerprint=fingerprint,
        program=program,
        triggers=triggers,
        overrides=overrides,
    )


def _check_overrides(overrides: Sequence[float]) -> tuple[float, ...]:
    values = tuple(float(f) for f in overrides)
    for f in values:
        if not (math.isfinite(f) and 0.0 < f <= 1.0):
            raise StudyError("command line", "--override", f"{f:g} is not in (0, 1]")
    if not values or len(set(values)) != len(values):
        raise StudyError("command line", "--override", "give each override once")
    return values


def _check_base(base: Any, source: str) -> None:
    """The base scenario must stop at t = 0 from the state the trigger sets."""
    if "annex_b" in base:
        raise StudyError(
            source,
            "annex_b",
            "a program's base scenario may not set an Annex-B test state (the program sets "
            "the state); remove annex_b",
        )
    stop = base.get("stop")
    if not isinstance(stop, dict):
        raise StudyError(source, "stop", "a program's base scenario needs a stop to trigger")
    if float(stop.get("t", 0.0)) != 0.0:
        raise StudyError(
            source,
            "stop.t",
            f"is {excerpt(str(stop.get('t')))} s; a program's stop is triggered at t = 0 "
            "(the trigger's instant)",
        )


@dataclass(frozen=True)
class OverrideSearch:
    """The largest speed override that keeps every trigger within an allowed distance.

    Attributes:
        figure: The bounded figure (:data:`SEARCH_FIGURES`).
        allowed: The allowed distance [m].
        bounded: True if the figure's upper bound was used (the base asks for bounds); False
            if only the nominal figure exists (it may be too small: see the report).
        override: The largest override found to pass [-], or None if even the smallest tried
            fails.
        failing: The smallest override found to fail [-], or None if F = 1 passes.
        tolerance: The bisection stops when ``failing - override`` is at most this [-].
        binding: Program time of the trigger whose figure is largest at ``override`` [s].
        worst: That figure at ``override`` [m].
        steps: (override, largest figure [m], passes) for each override tried, in order.
    """

    figure: str
    allowed: float
    bounded: bool
    override: float | None
    failing: float | None
    tolerance: float
    binding: float | None
    worst: float | None
    steps: tuple[tuple[float, float, bool], ...]


def find_override(
    study: ProgramStudy,
    allowed: float,
    evaluate: Callable[[ProgramStudy], Any],
    *,
    figure: str = "ssm_distance",
    tolerance: float = DEFAULT_TOLERANCE,
) -> OverrideSearch:
    """Bisect on F in (0, 1] for the largest override whose every trigger stays within.

    The figure of a trigger is its upper bound (``<figure>_upper``) where the records carry
    one, else the nominal figure. A trigger that fails, or whose figure is missing (the arm
    does not stop), counts as not within. The bisection assumes the largest figure grows
    with F; the override it returns was run and passed, whatever the figure does elsewhere.

    Args:
        study: The program study (its overrides are ignored).
        allowed: The allowed distance [m], > 0.
        evaluate: Runs a study and returns its results table
            (:func:`vtm_pin.study.runner.results_table`).
        figure: One of :data:`SEARCH_FIGURES`.
        tolerance: Stop when the passing and failing overrides are this close [-].

    Raises:
        StudyError: A bad figure, distance or tolerance, or a figure the base scenario does not
            give (S and S_p need the base's safeguard and separation inputs).
    """
    _check_search(figure, allowed, tolerance)
    steps: list[tuple[float, float, bool]] = []
    results: dict[float, tuple[float, float | None, bool]] = {}

    def trial(f: float) -> bool:
        worst, binding, bounded = _largest(evaluate(study.at([f])), figure, study.source)
        passes = math.isfinite(worst) and worst <= allowed
        steps.append((f, worst, passes))
        results[f] = (worst, binding, bounded)
        return passes

    low, high = 0.0, 1.0
    if trial(1.0):
        low, high = 1.0, math.nan
    else:
        while high - low > tolerance:
            middle = 0.5 * (low + high)
            if trial(middle):
                low = middle
            else:
                high = middle
    best = low if low > 0.0 else None
    worst, binding, bounded = results.get(low, (math.nan, None, results[1.0][2]))
    return OverrideSearch(
        figure=figure,
        allowed=allowed,
        bounded=bounded,
        override=best,
        failing=None if math.isnan(high) else high,
        tolerance=tolerance,
        binding=binding,
        worst=None if best is None else worst,
        steps=tuple(steps),
    )


def _check_search(figure: str, allowed: float, tolerance: float) -> None:
    if figure not in SEARCH_FIGURES:
        raise StudyError(
            "command line",
            "--figure",
            f"'{excerpt(figure)}' is not one of {', '.join(SEARCH_FIGURES)}",
        )
    if not (math.isfinite(allowed) and allowed > 0.0):
        raise StudyError("command line", "--within", f"{allowed} m is not a number > 0")
    if not (math.isfinite(tolerance) and 0.0 < tolerance < 0.5):
        raise StudyError("command line", "--tolerance", f"{tolerance} is not in (0, 0.5)")


def _largest(table: Any, figure: str, source: str) -> tuple[float, float | None, bool]:
    """The largest figure in a results table [m] (inf if one is missing), its trigger, bounded."""
    bounded = f"{figure}_upper" in table.columns
    if figure not in table.columns or (
        table[figure].isna().all() and (table["status"] == "ok").all()
    ):
        raise StudyError(
            source,
            figure,
            f"the base scenario gives no {SEARCH_FIGURES[figure]} (it needs the scenario's "
            "safeguard and separation inputs)",
        )
    values = table[f"{figure}_upper" if bounded else figure].astype(float)
    values = values.where((table["status"] == "ok") & values.notna(), math.inf)
    k = int(np.argmax(values.to_numpy()))
    return float(values.iloc[k]), float(table["program_time"].iloc[k]), bounded
