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


#: Subfolder of the output folder holding the override search's runs (one per F tried).
SEARCH_FOLDER = "override_search"
#: At most this many sampled instants of each stop go into the swept region.
SWEPT_SAMPLES = 12


@dataclass(frozen=True)
class ProgramOutput:
    """What :func:`run_program` produced.

    Attributes:
        study: The program study.
        table: One row per trigger and override (:func:`~.program_report.trigger_table`).
        summary: The JSON-ready summary written to ``summary.json``.
        search: The override search, or None if no allowed distance was given.
        files: Names of the files written into the output folder, sorted.
        phases: Wall time of the phases [s]: ``cases``, ``search``, ``swept``, ``outputs``.
    """

    study: ProgramStudy
    table: Any
    summary: Any
    search: OverrideSearch | None
    files: tuple[str, ...]
    phases: Any


def run_program(
    study: ProgramStudy,
    out: str | Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    engine: str = "batched",
    within: float | None = None,
    figure: str = "ssm_distance",
    tolerance: float = DEFAULT_TOLERANCE,
) -> ProgramOutput:
    """Run a program's triggers, search the override if asked, and write the program's files.

    ``out`` gets the study's files (:func:`vtm_pin.study.runner.run_study`) and
    ``program.csv``, ``program.png``, ``swept.png``, ``swept.npz``, ``program.html`` and, with
    ``within``, ``program_at_override.csv``. Every run is stored as it finishes, so the same
    call after an interruption computes only what is missing (the search's runs too, in
    ``out/override_search``).

    Args:
        study: The program study.
        out: Output folder.
        workers: Processes on this machine; all cores by default.
        scheduler: Address of a Dask scheduler.
        progress: Called with (cases done, cases in all) of the current run.
        engine: ``batched`` or ``scalar``.
        within: Allowed distance [m] for the override search; None: no search.
        figure: The figure the search bounds (:data:`SEARCH_FIGURES`).
        tolerance: The search's tolerance on F [-].

    Raises:
        StudyError: As :func:`vtm_pin.study.runner.run_study` and :func:`find_override`.
        OutputError: ``out`` cannot be written.
    """
    import time

    from .runner import run_study

    out = Path(out)
    if within is not None:
        _check_search(figure, within, tolerance)
    clock = {"begin": time.perf_counter()}
    kwargs = {"workers": workers, "scheduler": scheduler, "engine": engine}
    output = run_study(study, out, progress=progress, **kwargs)  # type: ignore[arg-type]
    clock["cases"] = time.perf_counter()
    search, at = None, None
    if within is not None:
        tables: dict[float, Any] = {}

        def evaluate(trial: ProgramStudy) -> Any:
            f = trial.overrides[0]
            folder = out / SEARCH_FOLDER / f"F_{f:.6f}"
            tables[f] = run_study(trial, folder, outputs=False, **kwargs).table  # type: ignore[arg-type]
            return tables[f]

        search = find_override(study, within, evaluate, figure=figure, tolerance=tolerance)
        at = tables.get(search.override) if search.override is not None else None
    clock["search"] = time.perf_counter()
    swept = swept_region(study)
    clock["swept"] = time.perf_counter()
    phases = {
        "cases": clock["cases"] - clock["begin"],
        "search": clock["search"] - clock["cases"],
        "swept": clock["swept"] - clock["search"],
    }
    files = _write_program(study, out, output, search, at, swept, phases)
    from .program_report import trigger_table

    phases["outputs"] = time.perf_counter() - clock["swept"]
    return ProgramOutput(
        study, trigger_table(study, output.table), files[1], search, files[0], phases
    )


def swept_region(study: ProgramStudy) -> tuple[Any, Any, str]:
    """The arm's sampled points at the triggers and during the stops, at the top override.

    Each trigger's stop is run again here (one process, the scalar engine; deterministic, so
    the same stop as the study's) and its points taken at up to :data:`SWEPT_SAMPLES`
    instants. Returns (positions during the stops (k, 3) [m], positions at the triggers
    (j, 3) [m], where the points come from).
    """
    from ..physics.arm_points import point_positions, sample_arm_points
    from ..physics.robot import RobotCache
    from ..scene.scenario import build_scenario, run_scenario
    from .cases import case_scenario

    top = max(study.overrides)
    robots = RobotCache()
    reached, start, note = [], [], ""
    for case in study.cases():
        if case.values["override"] != top:
            continue
        raw = case_scenario(study.base, case)
        scenario = build_scenario(
            raw, source=str(study.scenario), base_dir=study.scenario.parent, loader=robots
        )
        result = run_scenario(scenario)
        points = sample_arm_points(scenario.robot)
        note = points.source
        rows = np.unique(np.linspace(0, len(result.t) - 1, SWEPT_SAMPLES).astype(int))
        start.append(point_positions(scenario.robot, points, result.q[0]))
        reached += [point_positions(scenario.robot, points, result.q[k]) for k in rows[1:]]
    return np.concatenate(reached), np.concatenate(start), note


def _write_program(
    study: ProgramStudy,
    out: Path,
    output: Any,
    search: OverrideSearch | None,
    at: Any,
    swept: tuple[Any, Any, str],
    phases: dict[str, float],
) -> tuple[tuple[str, ...], dict[str, Any]]:
    """Write the program's files beside the study's; returns (all files, the summary)."""
    import json

    from ..files.staging import write_staged
    from .program_report import (
        plot_program,
        plot_swept,
        png,
        render_program_html,
        summary_extras,
        trigger_table,
    )

    table = trigger_table(study, output.table)
    summary = {**output.summary, **summary_extras(search, table)}
    summary["swept_region"] = {"points": len(swept[0]), "source": swept[2]}
    summary["phases"] = {name: round(value, 3) for name, value in phases.items()}  # [s]
    allowed = None if search is None else search.allowed
    images = {
        "program.png": png(plot_program(table, study.name, allowed)),
        "swept.png": png(
            plot_swept(swept[0], swept[1], f"{study.name}: swept region of the stops")
        ),
    }

    def write(staging: Path) -> None:
        table.to_csv(staging / "program.csv", index=False)
        if at is not None:
            trigger_table(study, at).to_csv(staging / "program_at_override.csv", index=False)
        for name, data in images.items():
            (staging / name).write_bytes(data)
        np.savez_compressed(staging / "swept.npz", reached=swept[0], start=swept[1])
        (staging / "summary.json").write_text(json.dumps(summary, indent=2, allow_nan=False))
        page = render_program_html(study, summary, table, images, search)
        (staging / "program.html").write_text(page, encoding="utf-8")

    written = write_staged(out, write)
    return tuple(sorted({*output.files, *written})), summary


def format_program(output: ProgramOutput, elapsed: float) -> str:
    """The lines ``vtm-pin program`` prints: triggers, the worst one, the override found."""
    from .program_report import worst_trigger

    study, table = output.study, output.table
    column, worst = worst_trigger(table)
    row = table.iloc[worst]
    lines = [
        f"program {study.name}: {len(study.triggers)} triggers x {len(study.overrides)} "
        f"override(s) = {len(table)} stops ({study.size} cases) in {elapsed:.1f} s",
        f"worst trigger: program time {row['program_time']:.4g} s ({row['trigger']}), "
        f"F = {row['override']:g}: {column} = {float(row[column]):.4g} m",
    ]
    for name, label in (
        ("robot_stop_time", "T_robot [s] (the robot's own stop, not the overall T)"),
        (
            "overall_stop_time",
            "T overall [s] (ISO 13855: detection + response + latency + T_robot)",
        ),
        ("tcp_max_displacement", "S_s, tool [m]"),
        ("arm_max_displacement", "largest arm-point displacement [m]"),
        ("ssm_distance", "S_p [m]"),
    ):
        if name in table.columns and table[name].notna().any():
            bound = f"{name}_upper"
            upper = (
                f", upper bound {table[bound].max():.4g}"
                if bound in table.columns
                else ", NO bound"
            )
            lines.append(f"  largest {label}: {table[name].max():.4g}{upper}")
    flagged = int((table["flags"].astype(str) != "").sum())
    if flagged:
        lines.append(f"  {flagged} stops flagged (see program.html)")
    search = output.search
    if search is not None:
        kind = "upper bound" if search.bounded else "NOMINAL figure (no bounds asked for)"
        if search.override is None:
            lines.append(
                f"override: no F in (0, 1] keeps {search.figure} within {search.allowed:g} m"
            )
        else:
            lines.append(
                f"override: F = {search.override:.4g} keeps every trigger's {search.figure} "
                f"({kind}) within {search.allowed:g} m; binding trigger at program time "
                f"{search.binding:.4g} s ({search.worst:.4g} m); tolerance {search.tolerance:g}"
            )
    return "\n".join(lines)
