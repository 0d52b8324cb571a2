"""A program sweep run end to end, and its outputs: the trigger table, graphs and report.

:func:`run_program` runs the triggers of a :class:`~vtm_pin.study.sweep.ProgramStudy` on the
study machinery, searches the override if asked, computes the swept region and writes the
program's files.

``program.csv`` holds one row per trigger: the override F and program time, why the instant is
a trigger, T_robot and the overall T, the stop angles, S_s (the tool's largest displacement),
the largest displacement of any sampled point of the arm where the run gives it, ISO 13855's S
and ISO/TS 15066's S_p, their upper bounds, and the flags. ``program.png`` draws them along the
program with the worst trigger marked. ``program.html`` is the page of the study report's
style: what was run, the worst trigger, the override search, the graphs, the table, the flags,
every assumption and definition.
"""

from __future__ import annotations

import base64
import io
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .report import (
    _CSS,
    _esc,
    _html_table,
    _section_assumptions,
    _section_definitions,
    _section_failures,
    _section_flagged,
    _section_versions,
)
from .sweep import (
    DEFAULT_TOLERANCE,
    OverrideSearch,
    ProgramStudy,
    _check_search,
    find_override,
)

if TYPE_CHECKING:
    import pandas as pd
    from matplotlib.figure import Figure

#: Resolution of the saved graphs [dots per inch].
FIGURE_DPI = 120
#: The distance figures drawn along the program, with their labels.
DISTANCES = {
    "tcp_max_displacement": "S_s, tool [m]",
    "arm_max_displacement": "largest displacement of any arm point [m]",
    "iso13855_distance": "S of ISO 13855:2024 [m]",
    "ssm_distance": "S_p of ISO/TS 15066 [m]",
}
#: The times drawn along the program, with their labels.
TIMES = {"robot_stop_time": "T_robot [s]", "overall_stop_time": "T, overall [s]"}


def trigger_table(study: ProgramStudy, table: pd.DataFrame) -> pd.DataFrame:
    """The results table with each trigger's reason, its columns in the report's order."""
    reasons = {trigger.time: trigger.reason for trigger in study.triggers}
    frame = table.copy()
    frame.insert(3, "trigger", [reasons.get(float(t), "") for t in frame["program_time"]])
    drop = [c for c in ("test_stop_time", "test_stop_time_upper", "test_speed", "test_reach")]
    return frame.drop(columns=[c for c in drop if c in frame.columns])


def worst_trigger(table: pd.DataFrame) -> tuple[str, int]:
    """The figure that ranks the triggers (S_p, else S, else S_s) and the worst row's index."""
    for figure in ("ssm_distance", "iso13855_distance", "tcp_max_displacement"):
        column = f"{figure}_upper" if f"{figure}_upper" in table.columns else figure
        if column in table.columns and table[column].notna().any():
            values = table[column].astype(float).fillna(math.inf)  # a case that did not stop
            return column, int(np.argmax(values.to_numpy()))
    return "tcp_max_displacement", 0


def plot_program(table: pd.DataFrame, title: str, allowed: float | None = None) -> Figure:
    """Distances and times along the program, one line per override, the worst marked.

    Dashed lines are the upper bounds where the table has them; the worst trigger (largest
    S_p, else S, else S_s, bounded where bounds exist) is ringed on every panel.
    """
    from matplotlib.figure import Figure

    distances = [c for c in DISTANCES if c in table.columns and table[c].notna().any()]
    panels = [distances[:2], distances[2:], list(TIMES)]
    panels = [p for p in panels if p]
    fig = Figure(figsize=(9.0, 2.6 * len(panels) + 0.6), layout="constrained")
    axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    _, worst = worst_trigger(table)
    labels = {**DISTANCES, **TIMES}
    for ax, columns in zip(axes, panels, strict=True):
        for override, part in table.groupby("override", sort=True):
            part = part.sort_values("program_time")
            for column in columns:
                if column not in part.columns:
                    continue
                (line,) = ax.plot(
                    part["program_time"],
                    part[column],
                    marker=".",
                    label=f"{labels[column]}, F = {override:g}",
                )
                if f"{column}_upper" in part.columns:
                    ax.plot(
                        part["program_time"],
                        part[f"{column}_upper"],
                        linestyle="--",
                        color=line.get_color(),
                        label=f"upper bound, F = {override:g}",
                    )
                ax.plot(
                    [table["program_time"].iloc[worst]],
                    [table[column].iloc[worst]],
                    marker="o",
                    markersize=12,
                    markerfacecolor="none",
                    color="red",
                )
        if allowed is not None and any(c in ("ssm_distance", "iso13855_distance") for c in columns):
            ax.axhline(allowed, color="black", linewidth=1.0, label=f"allowed {allowed:g} m")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    axes[-1].set_xlabel("program time [s] (at F = 1)")
    axes[0].set_title(
        f"{title}: worst trigger ringed (t = {table['program_time'].iloc[worst]:g} s)"
    )
    return fig


def render_program_html(
    study: ProgramStudy,
    summary: Mapping[str, Any],
    table: pd.DataFrame,
    images: Mapping[str, bytes],
    search: OverrideSearch | None = None,
) -> str:
    """The program sweep's report as one self-contained HTML page (no scripts, no links)."""
    column, worst = worst_trigger(table)
    row = table.iloc[worst]
    program = study.program
    assert program is not None
    head = (
        f"<section id='program'>\n<h2>Program and triggers</h2>\n"
        f"<p>{_esc(study.description)}. Velocities: {_esc(program.velocity_method)}.</p>\n"
        f"<p>{len(study.triggers)} triggers at overrides "
        f"{_esc(', '.join(f'{f:g}' for f in study.overrides))}: "
        f"{len(table)} stops. The stop is the base scenario's (category "
        f"{_esc(_category(study))}), triggered at each instant from the program's state "
        "there.</p>\n"
        f"<p class='worst'><strong>Worst trigger</strong>: program time "
        f"{row['program_time']:.4g} s ({_esc(row.get('trigger', ''))}), override "
        f"{row['override']:g}: {_esc(column)} = {float(row[column]):.4g} m"
        f"{_speed_note(row)}.</p>\n</section>"
    )
    sections = [
        head,
        _section_search(search),
        _section_images(images),
        "<section id='triggers'>\n<h2>Stops along the program</h2>\n"
        + _html_table(table, "trigger-table")
        + "\n</section>",
        _section_failures(table),
        _section_flagged(summary, table),
        _section_assumptions(summary),
        _section_definitions(summary, table),
        _section_versions(summary),
    ]
    name = study.name
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        f"<title>{_esc(name)} — simulated stops along a program</title>\n<style>{_CSS}</style>\n"
        f"</head>\n<body>\n<h1>Stops along the program {_esc(name)}</h1>\n"
        '<p class="banner"><strong>Simulated results</strong> (vtm_pin), not measurements: '
        "the robot's stop triggered at instants of its own program, under the assumptions "
        "listed below. T_robot is the robot's own stopping time, not ISO 13855's overall "
        "T.</p>\n" + "\n".join(s for s in sections if s) + "\n</body>\n</html>\n"
    )


def _category(study: ProgramStudy) -> str:
    stop = study.base.get("stop") or {}
    return str(stop.get("category", 0))


def _speed_note(row: Any) -> str:
    speed = row.get("tcp_speed_at_signal")
    if speed is None or (isinstance(speed, float) and math.isnan(speed)):
        return ""
    return f"; tool speed at the signal {float(speed):.3g} m/s"


def _section_search(search: OverrideSearch | None) -> str:
    if search is None:
        return ""
    kind = "its upper bound" if search.bounded else "the NOMINAL figure (no bounds asked for)"
    if search.override is None:
        verdict = (
            f"<p class='warn'><strong>No override in (0, 1] keeps every trigger within "
            f"{search.allowed:g} m</strong> (down to F = {search.failing:.4g}).</p>"
        )
    else:
        upper = "1 (the program as written)" if search.failing is None else f"{search.failing:.4g}"
        verdict = (
            f"<p><strong>Largest override F = {search.override:.4g}</strong>: every trigger's "
            f"{_esc(search.figure)} ({kind}) is at most {search.allowed:g} m; the largest, "
            f"{search.worst:.4g} m, at program time {search.binding:.4g} s (the binding "
            f"trigger). F = {upper} fails; bisection tolerance {search.tolerance:g}.</p>"
        )
    rows = "".join(
        f"<tr><td class='num'>{f:.4g}</td><td class='num'>{w:.4g}</td><td>{'yes' if ok else 'no'}"
        "</td></tr>"
        for f, w, ok in search.steps
    )
    return (
        "<section id='override'>\n<h2>The speed that fits the cell</h2>\n"
        + verdict
        + "\n<table id='search'><thead><tr><th>override F [-]</th><th>largest figure [m]</th>"
        "<th>within</th></tr></thead><tbody>" + rows + "</tbody></table>\n</section>"
    )


def _section_images(images: Mapping[str, bytes]) -> str:
    parts = ["<section id='graphs'>", "<h2>Graphs</h2>"]
    for name, data in images.items():
        uri = "data:image/png;base64," + base64.b64encode(data).decode("ascii")
        parts.append(
            f'<figure><img src="{uri}" alt="{_esc(name)}"><figcaption>{_esc(name)}'
            "</figcaption></figure>"
        )
    parts.append("</section>")
    return "\n".join(parts)


def png(figure: Figure) -> bytes:
    """The figure as PNG bytes at :data:`FIGURE_DPI`; the figure is cleared."""
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=FIGURE_DPI)
    figure.clear()
    return buffer.getvalue()


def plot_swept(points: np.ndarray, start: np.ndarray, title: str) -> Figure:
    """The swept region in 3D: every arm point's positions during the stops [m].

    Args:
        points: Positions reached during the stops, shape (k, 3) [m].
        start: Positions at the triggers, shape (j, 3) [m], drawn lighter.
        title: The figure's title.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.0, 6.0), layout="constrained")
    ax = fig.add_subplot(projection="3d")
    ax.scatter(*start.T, s=1, alpha=0.15, color="grey", label="arm at the triggers")
    ax.scatter(*points.T, s=2, alpha=0.5, color="tab:red", label="reached during the stops")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_title(title)
    ax.legend(loc="upper left", fontsize=8)
    return fig


def summary_extras(search: OverrideSearch | None, table: pd.DataFrame) -> dict[str, Any]:
    """What summary.json adds for a program: the worst trigger and the override search."""
    column, worst = worst_trigger(table)
    row = table.iloc[worst]
    extras: dict[str, Any] = {
        "worst_trigger": {
            "program_time": float(row["program_time"]),
            "override": float(row["override"]),
            "ranked_by": column,
            "value": _finite(row[column]),
        }
    }
    if search is not None:
        extras["override_search"] = {
            "figure": search.figure,
            "allowed": search.allowed,
            "bounded": search.bounded,
            "override": search.override,
            "failing": search.failing,
            "tolerance": search.tolerance,
            "binding_program_time": search.binding,
            "worst": search.worst,
            "steps": [[f, _finite(w), ok] for f, w, ok in search.steps],
        }
    return extras


def _finite(value: Any) -> float | None:
    value = float(value)
    return value if math.isfinite(value) else None


#: Subfolder of the output folder holding the override search's runs (one per F tried).
SEARCH_FOLDER = "override_search"
#: At most this many sampled instants of each stop go into the swept region.
SWEPT_SAMPLES = 12


@dataclass(frozen=True)
class ProgramOutput:
    """What :func:`run_program` produced.

    Attributes:
        study: The program study.
        table: One row per trigger and override (:func:`trigger_table`).
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
