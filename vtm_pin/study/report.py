"""Reports of a stopping study: Annex-B tables, stopping graphs and one self-contained HTML page.

A study (``vtm-pin study``) runs many emergency stops of one robot and yields a results
table, one row per case. This module turns that table into what robot makers publish under
ISO 10218-1 Annex B, so that safety engineers can compare the two:

- :func:`annex_b_table`: stopping time and distance per case, sorted like a maker's table
  (category, joint, payload, extension, speed), for grid studies;
- :func:`distribution_table`: median, 95th percentile and maximum per tested joint, for
  sampled studies (an axis drawn from a range);
- :func:`plot_stopping_graphs`: stopping distance and time against speed [%], one curve per
  payload, one panel per extension, one figure per tested joint (and stop category);
- :func:`render_report_html` and :func:`write_study_report`: one HTML page (inline CSS,
  images embedded as ``data:`` URIs, no JavaScript) with the graphs, tables, failed cases,
  assumptions, definitions and versions.

The results table's columns are ``case``, then the varied axes (any of ``joint``, ``speed``
[fraction of the joint's velocity limit], ``payload`` [kg], ``extension`` [fraction of
maximum reach], ``category`` and others), then ``status`` (``ok``, ``not_stopped`` or
``error: <message>``), ``holds`` and ``flags`` (:mod:`vtm_pin.outputs.flags`), the figures of
:data:`vtm_pin.outputs.figures.METRICS` (``robot_stop_time`` [s], the robot's own stop, never ISO
13855's overall T; ``stop_angle`` [rad]; ``tcp_max_displacement`` [m], S_s; ...) with an
``<figure>_upper`` bound beside each where the study asked for bounds, per-joint
``stop_time.<joint>`` [s] and ``stop_angle.<joint>`` [rad], and ``wall_time`` [s]. Only cases
with status ``ok`` carry results: the tables show NaN ("—") for the others and the graphs
leave them out.

Figures are built with :class:`matplotlib.figure.Figure` (no pyplot state), like
:mod:`vtm_pin.outputs.plotting`, so they render headless. Matplotlib is imported only when a figure
is drawn.
"""

from __future__ import annotations

import base64
import html
import io
import itertools
import math
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from ..outputs.figures import DEFINITIONS as FIGURE_DEFINITIONS
from ..outputs.figures import METRICS as FIGURE_METRICS
from ..outputs.figures import NOT_HELD

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

#: Resolution of the saved graphs [dots per inch], as ``vtm-pin run``'s figures.
FIGURE_DPI = 120
#: zlib level of the study's graphs [0-9]: 1 encodes the 10,000-case study's three ~0.4 MB
#: graphs ~0.08 s faster than PIL's default 6, 9 % larger.
PNG_COMPRESSION = 1
#: An axis with more distinct values than this was drawn from a range (sampled): graphs
#: scatter the cases instead of joining them with lines.
CONTINUOUS_VALUES = 8
#: Most extension panels of a scattered graph; extension is binned into this many ranges.
MAX_EXTENSION_PANELS = 3
#: Known axes in the order an Annex-B table is sorted by.
SORT_AXES = ("category", "joint", "payload", "extension", "speed")
#: Result columns (per-joint ``stop_time.<joint>`` and ``stop_angle.<joint>``, and every
#: ``<figure>_upper`` bound, as well).
RESULT_COLUMNS = ("status", "holds", "flags", *FIGURE_METRICS, "wall_time")
#: Statistics of the distribution table: label and function of the values of ok cases.
STATISTICS = ("median", "p95", "max")
#: Quantities of the tables and graphs: column, unit.
QUANTITIES = (("robot_stop_time", "s"), ("stop_angle", "rad"), ("tcp_max_displacement", "m"))

#: Units of the results table's columns (``summary["units"]`` overrides them).
UNITS = {
    "case": "—",
    "joint": "—",
    "speed": "1 (fraction of the joint's velocity limit; % in tables and graphs)",
    "payload": "kg",
    "extension": "1 (fraction of maximum reach; % in tables and graphs)",
    "category": "—",
    "status": "—",
    "holds": "—",
    "flags": "—",
    **FIGURE_METRICS,
    "wall_time": "s",
}
#: Definitions of the results table's columns (``summary["definitions"]`` overrides them).
DEFINITIONS = {
    "case": "Stable identifier of the case.",
    "joint": "The joint under test: it moves at the test speed when the stop signal comes.",
    "speed": "Speed of the tested joint at the stop signal, as a fraction of its velocity "
    "limit (Annex B's speed %).",
    "payload": "Mass of the payload carried at the tool.",
    "extension": "Extension of the arm, as a fraction of its maximum reach.",
    "category": "Stop category (IEC 60204-1): 0 removes power at once and the brakes stop "
    "the arm; 1 brakes with the drives first, then removes power.",
    "status": "ok: every joint came to rest; not_stopped: a joint was still moving at the "
    "end of the simulated time; error: the case could not be run (the message says why).",
    "holds": "Whether every brake holds its joint's gravity load throughout the stop.",
    "flags": "Broken assumptions behind the case's figures.",
    **FIGURE_DEFINITIONS,
    "wall_time": "Computing time of the case.",
}
_PER_JOINT = {
    "stop_time": ("s", "Time from the stop signal until joint {joint} is at rest for good."),
    "stop_angle": ("rad", "Travel of joint {joint} from the stop signal until the end."),
}
_ROWS = (
    ("stop_angle", "stopping distance\nstop_angle [rad]"),
    ("robot_stop_time", "robot's stopping time\nT_robot [s]"),
)
_STYLES = ["-", "--", ":", "-."]
#: Legend of the cases whose brakes cannot hold or stop the load.
FLAG_LABEL = "FLAGGED: brake cannot hold"
_CSS = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1200px; color: #222;
  padding: 0 1em; line-height: 1.4; }
h1 { margin-bottom: 0.2em; }
.banner { background: #fff4d6; border: 1px solid #e0b84c; padding: 0.6em 1em; }
table { border-collapse: collapse; margin: 0.8em 0; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 0.25em 0.6em; text-align: left; vertical-align: top; }
th { background: #eef1f5; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
tbody tr:nth-child(even) { background: #f8f9fb; }
figure { margin: 1em 0; }
figure img { max-width: 100%; height: auto; border: 1px solid #ddd; }
figcaption { font-size: 0.85em; color: #555; }
dt { font-weight: bold; margin-top: 0.6em; }
.note { color: #555; font-size: 0.9em; }
"""


# --- tables ------------------------------------------------------------------------------


def study_axes(table: pd.DataFrame) -> list[str]:
    """The varied axes of a results table, the known ones first in Annex-B sort order.

    The axes are the columns between ``case`` and ``status`` (the table's layout); a table
    without both takes every column that is not a result. Known axes (``category``,
    ``joint``, ``payload``, ``extension``, ``speed``) come first, the others in table order.
    """
    columns = [str(c) for c in table.columns]
    if (
        "case" in columns
        and "status" in columns
        and columns.index("case") < columns.index("status")
    ):
        candidates = columns[columns.index("case") + 1 : columns.index("status")]
    else:
        candidates = [c for c in columns if c != "case"]
    candidates = [c for c in candidates if not _is_result(c)]
    known = [a for a in SORT_AXES if a in candidates]
    return known + [c for c in candidates if c not in known]


def annex_b_table(table: pd.DataFrame) -> pd.DataFrame:
    """Stopping time and distance per case, laid out and sorted like a maker's Annex-B table.

    Rows are sorted by category, joint (in the order the table names them), payload,
    extension and speed (the axes present), then by the other axes. Columns: the axes
    (``speed [%]`` of the joint's velocity limit, ``extension [%]`` of maximum reach,
    ``payload [kg]``), ``robot_stop_time [s]``, ``stop_angle [rad]``, ``stop_angle [deg]``,
    ``tcp_max_displacement [m]`` (S_s), the overall T, S and S_p where computed, ``holds``,
    ``flags``, ``status`` and ``case``; each figure's ``_upper`` bound beside it where the
    study asked for bounds. Results are NaN unless the status is ok.

    Args:
        table: The study's results table (see the module docstring).

    Returns:
        A new table, one row per case, with a fresh index.
    """
    table = table.reset_index(drop=True)  # row labels may repeat (concatenated tables)
    axes = study_axes(table)
    ok = _status(table) == "ok"
    out = pd.DataFrame(index=table.index)
    for axis in axes:
        label, values = _axis_column(table, axis)
        out[label] = values
    angle = _numbers(table, "stop_angle").abs().where(ok)
    _figure(out, table, "robot_stop_time", "s", ok)
    _figure(out, table, "test_stop_time", "s", ok)  # the tested joint's own, as makers do
    out["stop_angle [rad]"] = angle
    out["stop_angle [deg]"] = np.degrees(angle)
    _figure(out, table, "stop_angle", "rad", ok, nominal=False)
    _figure(out, table, "tcp_max_displacement", "m", ok)
    for name in ("overall_stop_time", "iso13855_distance", "ssm_distance"):
        if name in table.columns and _numbers(table, name).notna().any():
            _figure(out, table, name, FIGURE_METRICS[name], ok)
    for column in ("holds", "flags"):
        if column in table.columns:
            out[column] = table[column]
    out["status"] = _status(table)
    out["case"] = table["case"].astype(str) if "case" in table else [str(i) for i in table.index]
    return out.iloc[_sorted_positions(table, axes)].reset_index(drop=True)


def _figure(
    out: pd.DataFrame,
    table: pd.DataFrame,
    name: str,
    unit: str,
    ok: pd.Series,
    nominal: bool = True,
) -> None:
    """Add the figure ``name [unit]`` (unless not ``nominal``) and its upper bound to ``out``."""
    if nominal and name in table.columns:
        out[f"{name} [{unit}]"] = _numbers(table, name).where(ok)
    if f"{name}_upper" in table.columns:
        out[f"{name}_upper [{unit}]"] = _numbers(table, f"{name}_upper").where(ok)


def distribution_table(table: pd.DataFrame) -> pd.DataFrame:
    """Statistics of a sampled study per tested joint (and stop category).

    For each group: the number of cases and of ok, not-stopped and failed ones, then the
    median, 95th percentile (linear interpolation, as :func:`numpy.percentile`) and maximum
    of ``robot_stop_time`` [s], ``stop_angle`` [rad] (absolute) and ``tcp_max_displacement``
    [m] over the ok cases (NaN if there are none), and the number of flagged cases.

    Args:
        table: The study's results table (see the module docstring).

    Returns:
        One row per group, sorted by category, then joint in the table's order.
    """
    keys = [k for k in ("category", "joint") if k in table.columns]
    columns = [*keys, "cases", "ok", "not_stopped", "error", "cannot_hold", "flagged"]
    for name, unit in QUANTITIES:
        columns += [f"{name} {stat} [{unit}]" for stat in STATISTICS]
        if f"{name}_upper" in table.columns:
            columns.append(f"{name}_upper max [{unit}]")
    ordered = table.iloc[_sorted_positions(table, keys)]
    rows = [
        _distribution_row(dict(zip(keys, key, strict=True)), group)
        for key, group in _groups(ordered, keys)
    ]
    return pd.DataFrame(rows, columns=columns)


def is_sampled(summary: Mapping[str, Any], table: pd.DataFrame) -> bool:
    """Whether a study was sampled (an axis drawn from a range) rather than a grid.

    The summary's ``study.mode`` decides; without it, an axis given as ``{min, max}``; without
    that, a numeric axis with more than :data:`CONTINUOUS_VALUES` distinct values.
    """
    study = _mapping(summary.get("study"))
    mode = study.get("mode")
    if mode in ("grid", "sampled"):
        return bool(mode == "sampled")
    axes = _mapping(study.get("axes"))
    if any(isinstance(values, Mapping) for values in axes.values()):
        return True
    return _has_continuous_axis(table)


# --- graphs ------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Layout:
    """How every figure of a study is laid out (shared, so figures compare panel by panel).

    Attributes:
        scatter: Scatter the cases (a sampled axis) instead of drawing lines.
        titles: Panel titles, one per extension value or bin.
        extensions: Extension values, one panel each (empty when binned or absent).
        edges: Extension bin edges when binned [1], else None.
        payloads: Payload values [kg] (one curve each in line mode; empty if absent).
        others: Other axes that vary (one curve per combination in line mode).
        combos: Their combinations ("brake_scale 0.8, ..."), in table order (line styles).
    """

    scatter: bool
    titles: list[str]
    extensions: list[float]
    edges: np.ndarray | None
    payloads: list[float]
    others: list[str]
    combos: list[str]

    def panel_of(self, frame: pd.DataFrame) -> np.ndarray:
        """Panel index of each row (-1 for an extension outside every panel)."""
        if "extension" not in frame.columns or not (self.extensions or self.edges is not None):
            return np.zeros(len(frame), dtype=int)
        x = frame["extension"].to_numpy(float)
        if self.edges is not None:
            last = len(self.edges) - 2
            return np.clip(np.searchsorted(self.edges, x, side="right") - 1, 0, last)
        index = {value: k for k, value in enumerate(self.extensions)}
        return np.array([index.get(value, -1) for value in x], dtype=int)


def plot_stopping_graphs(table: pd.DataFrame, *, robot: str = "") -> dict[str, Figure]:
    """Annex-B stopping graphs: one figure per tested joint (and stop category), by file name.

    Each figure has two rows, the stopping distance (``stop_angle`` [rad], absolute) and the
    robot's stopping time (``robot_stop_time`` [s]), and one column per extension value,
    against the speed
    [% of the joint's velocity limit], one curve per payload ("payload 5 kg"). Without a
    payload axis there is one curve, without an extension axis one column. When an axis was
    sampled (more than :data:`CONTINUOUS_VALUES` distinct values) the cases are scattered,
    coloured by payload with a colour bar, and extension is binned into at most
    :data:`MAX_EXTENSION_PANELS` panels whose titles give the bin edges. Only ok cases are
    drawn; the title says how many of the cases that is. Flagged cases are drawn again on top,
    red crosses where a brake cannot hold the load (the arm collapses), orange triangles for
    the other flags; where the table has ``<figure>_upper`` bounds, each curve's bound is a
    shaded band above it (scattered: a short bar above each case).

    File names are ``stopping_<joint>.png``, with ``_cat<category>`` when the table has
    several stop categories (``stopping.png`` without a joint axis).

    Args:
        table: The study's results table (see the module docstring).
        robot: Robot name for the figure titles.

    Returns:
        Figures by PNG file name, in joint order.
    """
    return dict(_stopping_graphs(table, robot))


def _stopping_graphs(
    table: pd.DataFrame, robot: str, share: tuple[int, int] = (0, 1)
) -> Iterator[tuple[str, Figure]]:
    """The stopping graphs one at a time (so a caller can save and drop each in turn).

    ``share``: as :func:`stopping_images`'s; the other graphs are not drawn.
    """
    layout = _layout(table)
    several = "category" in table.columns and table["category"].nunique() > 1
    keys = [k for k in ("joint", "category") if k in table.columns]
    ordered = table.iloc[_sorted_positions(table, keys)]
    first, step = share
    for index, (key, group) in enumerate(_groups(ordered, keys)):
        if index % step != first:
            continue
        values = dict(zip(keys, key, strict=True))
        name = "stopping"
        if "joint" in values:
            name += "_" + _slug(str(values["joint"]))
        if several:
            name += f"_cat{_category_text(values['category'])}"
        yield f"{name}.png", _stopping_figure(group, layout, _figure_title(values, robot, group))


def _stopping_figure(group: pd.DataFrame, layout: _Layout, title: str) -> Figure:
    from matplotlib.figure import Figure  # Matplotlib only when figures are drawn

    n = len(layout.titles)
    # Fixed margins, not a layout engine: constrained layout took 2/3 of a study's report time.
    width = max(8.0, 2.5 + 3.4 * n)  # room for the title and the key beside one panel
    fig = Figure(figsize=(width, 6.4))
    fig.subplots_adjust(
        left=1.0 / width, right=1.0 - 2.6 / width, bottom=0.1, top=0.86, wspace=0.12, hspace=0.12
    )
    axes = fig.subplots(2, n, sharex=True, sharey="row", squeeze=False)
    ok = group[_status(group) == "ok"]
    panel = layout.panel_of(ok)
    for col in range(n):
        part = ok[panel == col]
        for row, (column, _) in enumerate(_ROWS):
            ax = axes[row, col]
            if layout.scatter:
                _scatter(ax, part, column, layout)
            else:
                _lines(ax, part, column, layout)
            _flagged(ax, part, column)
            ax.grid(alpha=0.3)
        axes[0, col].set_title(layout.titles[col], fontsize="medium")
        axes[1, col].set_xlabel(
            "speed [% of maximum speed]" if "speed" in group.columns else "speed not varied"
        )
    for row, (_, label) in enumerate(_ROWS):
        axes[row, 0].set_ylabel(label)
    _key(fig, axes, layout)
    fig.suptitle(title, fontsize="medium")
    return fig


def _lines(ax: Axes, part: pd.DataFrame, column: str, layout: _Layout) -> None:
    """One line per payload (and combination of other varied axes), in order of speed."""
    combos = _combinations(part, layout.others)
    for k, combo in enumerate(layout.combos):
        for p, payload in enumerate(layout.payloads or [None]):
            mask = combos == combo
            if payload is not None:
                mask &= part["payload"].to_numpy(float) == payload
            curve = part[mask]
            if curve.empty:
                continue
            if "speed" in curve.columns:
                curve = curve.sort_values("speed", kind="stable")
            label = ", ".join(
                t for t in (_payload_text(payload), combo if layout.others else "") if t
            )
            x = _speed_percent(curve)
            ax.plot(
                x,
                _values(curve, column),
                _STYLES[k % len(_STYLES)],
                marker="o",
                markersize=4,
                color=f"C{p % 10}",
                label=label or "cases",
            )
            if f"{column}_upper" in curve.columns:
                ax.fill_between(
                    x,
                    _values(curve, column),
                    _values(curve, f"{column}_upper"),
                    color=f"C{p % 10}",
                    alpha=0.15,
                    linewidth=0,
                    label="one-sided upper bound (band)",
                )


def _values(frame: pd.DataFrame, column: str) -> np.ndarray:
    """A figure's values as floats (stop angles, and their bounds, as absolute values)."""
    values = _numbers(frame, column).to_numpy(float)
    return np.abs(values) if column.startswith("stop_angle") else values


def _flagged(ax: Axes, part: pd.DataFrame, column: str) -> None:
    """Flagged cases on top: red crosses (a brake cannot hold), orange triangles (others)."""
    if "flags" not in part.columns or part.empty:
        return
    flags = _flag_texts(part).to_numpy()
    collapse = np.array([_not_held(f) for f in flags], dtype=bool)
    other = (flags != "") & ~collapse
    x, y = _speed_percent(part), _values(part, column)
    styles: tuple[tuple[np.ndarray, dict[str, Any]], ...] = (
        (collapse, {"marker": "x", "color": "red", "s": 50, "label": FLAG_LABEL}),
        (other, {"marker": "^", "facecolors": "none", "edgecolors": "darkorange", "s": 40}),
    )
    for mask, style in styles:
        if mask.any():
            ax.scatter(x[mask], y[mask], zorder=5, **{"label": "flagged (see report)", **style})


def _scatter(ax: Axes, part: pd.DataFrame, column: str, layout: _Layout) -> None:
    """The cases as points, coloured by payload when it varies; bounds as bars above them."""
    y = _numbers(part, column).abs() if column == "stop_angle" else _numbers(part, column)
    if f"{column}_upper" in part.columns:
        ax.vlines(
            _speed_percent(part),
            _values(part, column),
            _values(part, f"{column}_upper"),
            color="0.5",
            alpha=0.5,
            linewidth=1.0,
            label="one-sided upper bound (bar)",
        )
    if len(layout.payloads) > 1:
        ax.scatter(
            _speed_percent(part),
            y,
            c=part["payload"].to_numpy(float),
            cmap="viridis",
            vmin=layout.payloads[0],
            vmax=layout.payloads[-1],
            s=14,
            alpha=0.8,
            edgecolors="none",
        )
    else:
        ax.scatter(_speed_percent(part), y, color="C0", s=14, alpha=0.8, edgecolors="none")


def _key(fig: Figure, axes: np.ndarray, layout: _Layout) -> None:
    """The figure's legend (line mode) or payload colour bar (scatter mode)."""
    if layout.scatter:
        flagged = {
            label: handle
            for ax in axes.flat
            for handle, label in zip(*ax.get_legend_handles_labels(), strict=True)
        }
        if flagged:
            fig.legend(
                list(flagged.values()),
                list(flagged),
                loc="lower center",
                fontsize="small",
                ncols=min(3, len(flagged)),
            )
        if len(layout.payloads) > 1:
            from matplotlib.cm import ScalarMappable
            from matplotlib.colors import Normalize

            norm = Normalize(layout.payloads[0], layout.payloads[-1])
            mappable = ScalarMappable(norm=norm, cmap="viridis")
            cax = fig.add_axes(
                (1.0 - 1.6 / fig.get_figwidth(), 0.15, 0.15 / fig.get_figwidth(), 0.65)
            )
            fig.colorbar(mappable, cax=cax, label="payload [kg]")
        return
    handles: dict[str, Any] = {}
    for ax in axes.flat:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(label, handle)
    if handles:
        fig.legend(
            list(handles.values()),
            list(handles),
            loc="upper left",
            bbox_to_anchor=(1.0 - 2.5 / fig.get_figwidth(), 0.86),
            fontsize="small",
        )


def _layout(table: pd.DataFrame) -> _Layout:
    scatter = _has_continuous_axis(table)
    extensions = _distinct(table, "extension")
    payloads = _distinct(table, "payload")
    others = [
        a
        for a in study_axes(table)
        if a not in SORT_AXES and table[a].astype(str).nunique(dropna=False) > 1
    ]
    edges = None
    if scatter and len(extensions) > MAX_EXTENSION_PANELS:
        edges = np.linspace(extensions[0], extensions[-1], MAX_EXTENSION_PANELS + 1)
        titles = [
            f"extension [{100 * lo:.3g}, {100 * hi:.3g}{']' if k == len(edges) - 2 else ')'}"
            " % of reach"
            for k, (lo, hi) in enumerate(itertools.pairwise(edges))
        ]
        extensions = []
    elif extensions:
        titles = [f"extension {100 * e:.3g} % of reach" for e in extensions]
    else:
        titles = ["extension not varied"]
    combos = list(dict.fromkeys(_combinations(table, others)))
    return _Layout(scatter, titles, extensions, edges, payloads, others, combos)


def _figure_title(values: Mapping[str, Any], robot: str, group: pd.DataFrame) -> str:
    where = [f"robot {robot}" if robot else ""]
    if "joint" in values:
        where.append(f"joint {values['joint']}")
    if "category" in values:
        where.append(f"stop category {_category_text(values['category'])}")
    drawn = int((_status(group) == "ok").sum())
    if drawn == len(group):
        cases = f"all {drawn} cases came to rest and are drawn"
    else:
        rest = len(group) - drawn
        cases = (
            f"{drawn} of {len(group)} cases drawn (status ok); "
            + ("the other one is" if rest == 1 else f"the other {rest} are")
            + " listed in the report's failed cases"
        )
    return (
        "SIMULATED stopping distance and time (ISO 10218-1 Annex B layout): "
        + ", ".join(w for w in where if w)
        + f"\n{cases}"
    )


# --- HTML --------------------------------------------------------------------------------


def render_report_html(
    summary: Mapping[str, Any], table: pd.DataFrame, images: Mapping[str, bytes]
) -> str:
    """The study report as one self-contained HTML page.

    Inline CSS, PNG images embedded as base64 ``data:`` URIs, no external resources and no
    JavaScript. It holds the study's description and counts, the graphs, the Annex-B table
    (grid studies) or the distribution table (sampled ones), the failed and not-stopped cases
    with their messages, every assumption, the definitions of T and S_s and of every column
    with its unit, and the versions. All text is escaped; numbers have 4 significant digits
    and NaN shows as "—".

    Args:
        summary: The study's summary mapping (``study``, ``counts``, ``versions``,
            ``assumptions``, ``definitions``, ``units``; each optional).
        table: The study's results table (see the module docstring).
        images: PNG images by file name, shown in this order.

    Returns:
        The page's HTML text.
    """
    study = _mapping(summary.get("study"))
    name = str(study.get("name") or study.get("file") or "stopping study")
    sections = [
        _section_study(study, summary, table),
        _section_graphs(images),
        _section_results(summary, table),
        _section_failures(table),
        _section_flagged(summary, table),
        _section_assumptions(summary),
        _section_definitions(summary, table),
        _section_versions(summary),
    ]
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        f"<title>{_esc(name)} — simulated stopping study</title>\n<style>{_CSS}</style>\n"
        f"</head>\n<body>\n<h1>Stopping study: {_esc(name)}</h1>\n"
        '<p class="banner"><strong>Simulated results</strong> (vtm_pin), not measurements. '
        "They follow the layout of ISO 10218-1 Annex B so they can be compared with a "
        "maker's published stopping data, under the assumptions listed below.</p>\n"
        + "\n".join(sections)
        + "\n</body>\n</html>\n"
    )


def write_study_report(
    folder: Path,
    summary: Mapping[str, Any],
    table: pd.DataFrame,
    images: Mapping[str, bytes] | None = None,
) -> list[str]:
    """Write a study's graphs, table and HTML report into ``folder``.

    Writes ``stopping_*.png`` (:func:`stopping_images`), ``annex_b_table.csv`` (grid studies)
    or ``distribution.csv`` (sampled ones, see :func:`is_sampled`) and ``report.html``.

    Args:
        folder: Output folder (created if missing).
        summary: The study's summary mapping (see :func:`render_report_html`).
        table: The study's results table (see the module docstring).
        images: The graphs, if drawn already (``stopping_images(table, robot)``, e.g. in
            another process); drawn here if None.

    Returns:
        The names of the files written, sorted.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if images is None:
        images = stopping_images(table, str(_mapping(summary.get("study")).get("robot") or ""))
    for name, data in images.items():
        (folder / name).write_bytes(data)
    if is_sampled(summary, table):
        csv_name, frame = "distribution.csv", distribution_table(table)
    else:
        csv_name, frame = "annex_b_table.csv", annex_b_table(table)
    frame.to_csv(folder / csv_name, index=False)
    (folder / "report.html").write_text(render_report_html(summary, table, images), "utf-8")
    return sorted([*images, csv_name, "report.html"])


def stopping_images(
    table: pd.DataFrame, robot: str, share: tuple[int, int] = (0, 1)
) -> dict[str, bytes]:
    """The stopping graphs (:func:`plot_stopping_graphs`) as PNG files' bytes, by file name.

    At :data:`FIGURE_DPI`, compressed at :data:`PNG_COMPRESSION`. Each figure is drawn and
    saved before the next is made, and then dropped (no pyplot state holds it), so large
    studies do not hold them all. (Clearing it as well cost ~0.06 s of the 10,000-case
    study's ~1 s of graphs, on the command's critical path.)

    ``share`` = (k, n): only the graphs k, k + n, k + 2n, ... of the study's, so that n
    processes draw them together (:func:`merge_shares` puts them back in order).
    """
    images: dict[str, bytes] = {}
    for name, figure in _stopping_graphs(table, robot, share):
        buffer = io.BytesIO()
        figure.savefig(
            buffer, format="png", dpi=FIGURE_DPI, pil_kwargs={"compress_level": PNG_COMPRESSION}
        )
        images[name] = buffer.getvalue()
    return images


def merge_shares(shares: Sequence[Mapping[str, bytes]]) -> dict[str, bytes]:
    """The graphs of n processes in the order one process draws them.

    ``shares``: share k of n drawn by :func:`stopping_images`, k = 0 .. n - 1 in order.
    """
    parts = [list(part.items()) for part in shares]
    longest = max((len(part) for part in parts), default=0)
    return dict(part[i] for i in range(longest) for part in parts if i < len(part))


def format_value(value: Any) -> str:
    """A table cell's text: floats with 4 significant digits, NaN and None as "—"."""
    if value is None:
        return "—"
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        x = float(value)
        if math.isnan(x):
            return "—"
        if math.isinf(x):
            return "∞" if x > 0 else "-∞"
        return f"{x:.4g}"
    if value is pd.NA or value is pd.NaT:
        return "—"
    return str(value)


def _section_study(
    study: Mapping[str, Any], summary: Mapping[str, Any], table: pd.DataFrame
) -> str:
    parts = ["<section id='study'>", "<h2>Study</h2>"]
    if study.get("description"):
        parts.append(f"<p>{_esc(study['description'])}</p>")
    fields = [
        ("study file", study.get("file")),
        ("scenario", study.get("scenario")),
        ("robot", study.get("robot")),
        ("tool frame", study.get("tool_frame")),
        ("mode", study.get("mode")),
        ("samples", study.get("samples")),
        ("seed", study.get("seed")),
    ]
    rows = [(label, value) for label, value in fields if value is not None]
    rows += [(f"axis {axis}", _axis_text(v)) for axis, v in _mapping(study.get("axes")).items()]
    if rows:
        parts.append(_html_table(pd.DataFrame(rows, columns=["item", "value"]), "study-table"))
    counts = _counts(summary, table)
    parts.append("<h3>Cases</h3>")
    parts.append(_html_table(pd.DataFrame([counts]), "counts"))
    parts.append("</section>")
    return "\n".join(parts)


def _section_graphs(images: Mapping[str, bytes]) -> str:
    parts = ["<section id='graphs'>", "<h2>Stopping graphs</h2>"]
    if not images:
        parts.append("<p>No graphs.</p>")
    for name, data in images.items():
        uri = "data:image/png;base64," + base64.b64encode(data).decode("ascii")
        parts.append(
            f'<figure><img src="{uri}" alt="{_esc(name)}">'
            f"<figcaption>{_esc(name)}</figcaption></figure>"
        )
    parts.append("</section>")
    return "\n".join(parts)


def _section_results(summary: Mapping[str, Any], table: pd.DataFrame) -> str:
    if is_sampled(summary, table):
        return (
            "<section id='results'>\n<h2>Distribution of the sampled cases</h2>\n"
            "<p class='note'>Per tested joint (and stop category): the number of cases, then "
            "median, 95th percentile (p95, linear interpolation) and maximum over the cases "
            "with status ok. stop_angle is the tested joint's absolute travel.</p>\n"
            + _html_table(distribution_table(table), "distribution")
            + "\n</section>"
        )
    return (
        "<section id='results'>\n<h2>Stopping time and distance per case (Annex B)</h2>\n"
        "<p class='note'>Speed in % of the tested joint's velocity limit, extension in % of "
        "maximum reach. Results only for cases with status ok (— otherwise).</p>\n"
        + _html_table(annex_b_table(table), "annex-b")
        + "\n</section>"
    )


def _section_failures(table: pd.DataFrame) -> str:
    table = table.reset_index(drop=True)  # row labels may repeat (concatenated tables)
    status = _status(table)
    failed = table[status != "ok"]
    parts = ["<section id='failures'>", "<h2>Failed and not-stopped cases</h2>"]
    if failed.empty:
        parts.append("<p>None: every case came to rest.</p>")
    else:
        frame = pd.DataFrame(index=failed.index)
        frame["case"] = failed["case"].astype(str) if "case" in failed else failed.index
        for axis in study_axes(table):
            label, values = _axis_column(failed, axis)
            frame[label] = values
        kind_message = [_split_status(s) for s in status[failed.index]]
        frame["status"] = [k for k, _ in kind_message]
        frame["message"] = [m for _, m in kind_message]
        parts.append(_html_table(frame, "failures"))
    parts.append("</section>")
    return "\n".join(parts)


#: Most flagged cases the report lists one by one (the table has them all).
MAX_FLAGGED_LISTED = 100


def _section_flagged(summary: Mapping[str, Any], table: pd.DataFrame) -> str:
    """The cases whose figures rest on broken assumptions, with what broke."""
    table = table.reset_index(drop=True)
    flags = _flag_texts(table) if "flags" in table else None
    parts = ["<section id='flagged'>", "<h2>Flagged cases</h2>"]
    if flags is None or not (flags != "").any():
        parts.append(
            "<p>None: in every case every brake holds its joint's load, no other joint "
            "slips, and payload and tool speed are within the robot's figures.</p>"
        )
        parts.append("</section>")
        return "\n".join(parts)
    flagged = table[flags != ""]
    collapse = int(flags.map(_not_held).sum())
    falls = (
        f"; in {collapse} a brake cannot hold the load and the arm collapses" if collapse else ""
    )
    parts.append(
        f"<p class='banner'><strong>{len(flagged)} of {len(table)} cases are flagged</strong>"
        f"{falls}. Their figures describe what the model computes under broken assumptions: "
        "do not sign "
        "them as stopping data. The graphs mark them (red crosses: a brake cannot hold; "
        "orange triangles: other flags).</p>"
    )
    messages = {
        str(item.get("case")): "; ".join(f"{f['kind']}: {f['message']}" for f in item["flags"])
        for item in summary.get("flagged", [])
    }
    frame = pd.DataFrame(index=flagged.index[:MAX_FLAGGED_LISTED])
    shown = flagged.iloc[:MAX_FLAGGED_LISTED]
    frame["case"] = shown["case"].astype(str) if "case" in shown else shown.index
    for axis in study_axes(table):
        label, values = _axis_column(shown, axis)
        frame[label] = values
    frame["flags"] = shown["flags"]
    for column, unit in (("tool_drop", "m"), ("tcp_max_displacement", "m")):
        if column in shown:
            frame[f"{column} [{unit}]"] = _numbers(shown, column)
    frame["what broke"] = [
        messages.get(str(c), "see its record in cases/*.jsonl") for c in frame["case"]
    ]
    parts.append(_html_table(frame, "flagged"))
    if len(flagged) > MAX_FLAGGED_LISTED:
        parts.append(
            f"<p class='note'>{len(flagged) - MAX_FLAGGED_LISTED} more flagged cases are in "
            "results.csv (column flags).</p>"
        )
    parts.append("</section>")
    return "\n".join(parts)


def _section_assumptions(summary: Mapping[str, Any]) -> str:
    assumptions = summary.get("assumptions") or []
    items = "".join(f"<li>{_esc(a)}</li>" for a in assumptions)
    body = f"<ol>{items}</ol>" if items else "<p>None listed.</p>"
    return f"<section id='assumptions'>\n<h2>Assumptions</h2>\n{body}\n</section>"


def _section_definitions(summary: Mapping[str, Any], table: pd.DataFrame) -> str:
    rows = [
        (column, _unit(summary, column), _definition(summary, column))
        for column in map(str, table.columns)
    ]
    frame = pd.DataFrame(rows, columns=["column", "unit", "definition"])
    chain = _mapping(summary.get("stopping_chain"))
    return (
        "<section id='definitions'>\n<h2>Definitions</h2>\n<dl>\n"
        "<dt>T_robot — the robot's own stopping time (column robot_stop_time) [s]</dt>\n"
        f"<dd>{_esc(_definition(summary, 'robot_stop_time'))} Per joint: "
        "stop_time.&lt;joint&gt;.</dd>\n"
        "<dt>T — ISO 13855:2024's overall stopping performance (column overall_stop_time) "
        "[s]</dt>\n"
        "<dd>T = t_detection + t_response + t_latency + T_robot: the protective device's "
        "detection time, the safety controller's response time and the signal's latency to the "
        "robot, then the robot's own stop. "
        + (
            f"This study: {_esc(_chain_text(chain))}"
            if chain.get("safeguard")
            else "This study gives no safeguard times (scenario key safeguard), so T is not "
            "computed: T_robot alone is NOT T and must not be used as it."
        )
        + "</dd>\n"
        "<dt>S — ISO 13855:2024's minimum distance (column iso13855_distance) [m]</dt>\n"
        "<dd>S = K·T + D_DS + Z, with K, D_DS and Z from the scenario's separation.iso13855 "
        "(none defaulted).</dd>\n"
        "<dt>S_p — ISO/TS 15066's protective separation distance (column ssm_distance) "
        "[m]</dt>\n"
        "<dd>S_p = S_h + S_r + S_s + C + Z_d + Z_r, S_h = v_h (T_r + T_s), S_r = v_r T_r, "
        "T_r = t_detection + t_response + t_latency, T_s = T_robot, v_r = the tool's speed at "
        "the signal, v_h = 1.6 m/s unless the scenario gives another.</dd>\n"
        "<dt>S_s — stopping distance (columns tcp_max_displacement [m] and stop_angle [rad])"
        "</dt>\n<dd>The distance the robot travels while it stops, as ISO/TS 15066 uses it: "
        f"{_esc(_definition(summary, 'tcp_max_displacement'))} "
        "stop_angle [rad], the stopping distance of ISO 10218-1 Annex B: "
        f"{_esc(_definition(summary, 'stop_angle'))}</dd>\n"
        + _bounds_definition(summary)
        + "</dl>\n<h3>Columns of the results table</h3>\n"
        + _html_table(frame, "columns")
        + "\n</section>"
    )


def _chain_text(chain: Mapping[str, Any]) -> str:
    guard = _mapping(chain.get("safeguard"))
    return (
        f"t_detection {format_value(guard.get('detection_time'))} s, t_response "
        f"{format_value(guard.get('response_time'))} s, t_latency "
        f"{format_value(guard.get('latency'))} s."
    )


def _bounds_definition(summary: Mapping[str, Any]) -> str:
    """How the ``_upper`` bounds were made, if the study has them."""
    bounds = _mapping(summary.get("bounds"))
    if not bounds:
        return (
            "<dt>Bounds</dt>\n<dd>None asked for (scenario key bounds): every figure is the "
            "nominal model's, with no allowance for the calibration's uncertainty or brake "
            "wear.</dd>\n"
        )
    return f"<dt>&lt;figure&gt;_upper — bounds</dt>\n<dd>{_esc(bounds.get('text', ''))}</dd>\n"


def _section_versions(summary: Mapping[str, Any]) -> str:
    versions = _mapping(summary.get("versions"))
    if not versions:
        return "<section id='versions'>\n<h2>Versions</h2>\n<p>Not recorded.</p>\n</section>"
    frame = pd.DataFrame(list(versions.items()), columns=["software", "version"])
    return (
        f"<section id='versions'>\n<h2>Versions</h2>\n{_html_table(frame, 'versions')}\n</section>"
    )


def _html_table(frame: pd.DataFrame, table_id: str) -> str:
    head = "".join(f"<th>{_esc(c)}</th>" for c in frame.columns)
    rows = []
    for row in frame.itertuples(index=False, name=None):
        cells = "".join(
            f'<td class="num">{_esc(format_value(v))}</td>'
            if isinstance(v, (int, float, np.number)) and not isinstance(v, (bool, np.bool_))
            else f"<td>{_esc(format_value(v))}</td>"
            for v in row
        )
        rows.append(f"<tr>{cells}</tr>")
    return (
        f'<table id="{_esc(table_id)}">\n<thead><tr>{head}</tr></thead>\n<tbody>\n'
        + "\n".join(rows)
        + "\n</tbody>\n</table>"
    )


# --- helpers -----------------------------------------------------------------------------


def _is_result(column: str) -> bool:
    return (
        column in RESULT_COLUMNS
        or column.startswith(("stop_time.", "stop_angle."))
        or column.endswith("_upper")
    )


def _status(table: pd.DataFrame) -> pd.Series:
    if "status" not in table.columns:
        return pd.Series("ok", index=table.index)
    return table["status"].astype(str)


def _numbers(table: pd.DataFrame, column: str) -> pd.Series:
    """A column as floats (NaN where missing or not a number)."""
    if column not in table.columns:
        return pd.Series(np.nan, index=table.index, dtype=float)
    return pd.to_numeric(table[column], errors="coerce").astype(float)


def _axis_column(table: pd.DataFrame, axis: str) -> tuple[str, pd.Series]:
    """An axis's label with its unit and its values as tables show them (speed in %)."""
    if axis in ("speed", "extension"):
        return f"{axis} [%]", (_numbers(table, axis) * 100.0).round(9)
    if axis == "payload":
        return "payload [kg]", _numbers(table, axis)
    return axis, table[axis]


def _sorted_positions(table: pd.DataFrame, axes: Sequence[str]) -> np.ndarray:
    """Row positions sorted by the axes: numbers by value, the rest in order of first use."""
    if not axes or table.empty:
        return np.arange(len(table))
    keys = pd.DataFrame(index=pd.RangeIndex(len(table)))
    for axis in axes:
        column = table[axis].reset_index(drop=True)
        if axis != "joint" and pd.api.types.is_numeric_dtype(column):
            keys[axis] = column
        else:
            text = column.astype(str)
            order = list(dict.fromkeys(text))
            keys[axis] = pd.Categorical(text, categories=order, ordered=True)
    return keys.sort_values(list(axes), kind="stable").index.to_numpy()


def _groups(table: pd.DataFrame, keys: Sequence[str]) -> Iterator[tuple[tuple[Any, ...], Any]]:
    """Groups of rows by the keys, in the table's order (the whole table without keys)."""
    if not keys:
        if not table.empty:
            yield (), table
        return
    for key, group in table.groupby(list(keys), sort=False, dropna=False):
        yield (key if isinstance(key, tuple) else (key,)), group


def _distribution_row(row: dict[str, Any], group: pd.DataFrame) -> dict[str, Any]:
    status = _status(group)
    ok = group[status == "ok"]
    row |= {
        "cases": len(group),
        "ok": int((status == "ok").sum()),
        "not_stopped": int((status == "not_stopped").sum()),
        "error": int(status.str.startswith("error").sum()),
        **_flag_counts(group),
    }
    for name, unit in QUANTITIES:
        if f"{name}_upper" in ok.columns:
            upper = np.abs(_numbers(ok, f"{name}_upper").dropna().to_numpy(float))
            row[f"{name}_upper max [{unit}]"] = float(np.max(upper)) if upper.size else math.nan
        values = _numbers(ok, name).dropna().to_numpy(float)
        if name == "stop_angle":
            values = np.abs(values)
        stats = (
            (float(np.median(values)), float(np.percentile(values, 95.0)), float(np.max(values)))
            if values.size
            else (math.nan,) * len(STATISTICS)
        )
        for label, stat in zip(STATISTICS, stats, strict=True):
            row[f"{name} {label} [{unit}]"] = stat
    return row


def _distinct(table: pd.DataFrame, column: str) -> list[float]:
    if column not in table.columns:
        return []
    return sorted(float(v) for v in _numbers(table, column).dropna().unique())


def _has_continuous_axis(table: pd.DataFrame) -> bool:
    return any(
        pd.api.types.is_numeric_dtype(table[a]) and table[a].nunique() > CONTINUOUS_VALUES
        for a in study_axes(table)
        if a not in ("joint", "category")
    )


def _combinations(frame: pd.DataFrame, columns: Sequence[str]) -> np.ndarray:
    """Each row's values of ``columns`` as one text ("a 1, b x"), "" without columns."""
    if not columns or frame.empty:
        return np.full(len(frame), "", dtype=object)
    parts = [c + " " + frame[c].map(format_value) for c in columns]
    text = parts[0]
    for part in parts[1:]:
        text = text + ", " + part
    return text.to_numpy(dtype=object)


def _speed_percent(frame: pd.DataFrame) -> np.ndarray:
    if "speed" not in frame.columns:
        return np.zeros(len(frame))
    return frame["speed"].to_numpy(float) * 100.0


def _payload_text(payload: float | None) -> str:
    return "" if payload is None else f"payload {payload:g} kg"


def _category_text(category: Any) -> str:
    try:
        return str(int(category))
    except (TypeError, ValueError):
        return _slug(str(category))


def _slug(text: str) -> str:
    """Text safe in a file name: runs of other characters become "_"."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("_") or "joint"


def _counts(summary: Mapping[str, Any], table: pd.DataFrame) -> dict[str, Any]:
    status = _status(table)
    counted = {
        "cases": len(table),
        "ok": int((status == "ok").sum()),
        "not_stopped": int((status == "not_stopped").sum()),
        "error": int(status.str.startswith("error").sum()),
        **_flag_counts(table),
    }
    given = _mapping(summary.get("counts"))
    return {key: given.get(key, value) for key, value in counted.items()}


def _flag_counts(table: pd.DataFrame) -> dict[str, int]:
    """Cases whose brakes cannot hold the load (``cannot_hold``), and all flagged cases."""
    flags = _flag_texts(table)
    return {
        "cannot_hold": int(flags.map(_not_held).sum()),
        "flagged": int((flags != "").sum()),
    }


def _not_held(flags: str) -> bool:
    """Whether a case's flags (``;``-separated kinds) say a brake cannot hold or stop it."""
    return any(kind in NOT_HELD for kind in flags.split(";"))


def _flag_texts(table: pd.DataFrame) -> pd.Series:
    """The ``flags`` column as text ("" for none, also where a CSV reader made it NaN)."""
    if "flags" not in table:
        return pd.Series([""] * len(table), index=table.index, dtype=object)
    return table["flags"].map(lambda value: value if isinstance(value, str) else "")


def _split_status(status: str) -> tuple[str, str]:
    kind, _, message = status.partition(":")
    if kind == "not_stopped" and not message:
        return kind, "a joint was still moving at the end of the simulated time"
    return kind.strip(), message.strip()


def _axis_text(values: Any) -> str:
    if isinstance(values, Mapping):
        return f"range {format_value(values.get('min'))} … {format_value(values.get('max'))}"
    if isinstance(values, (list, tuple)):
        return ", ".join(format_value(v) for v in values)
    return format_value(values)


def _unit(summary: Mapping[str, Any], column: str) -> str:
    units = _mapping(summary.get("units"))
    if column in units:
        return str(units[column])
    base, _, _ = column.partition(".")
    if base in _PER_JOINT and column != base:
        return _PER_JOINT[base][0]
    return UNITS.get(column, "—")


def _definition(summary: Mapping[str, Any], column: str) -> str:
    definitions = _mapping(summary.get("definitions"))
    if column in definitions:
        return str(definitions[column])
    base, _, joint = column.partition(".")
    if base in _PER_JOINT and joint:
        return _PER_JOINT[base][1].format(joint=joint)
    return DEFINITIONS.get(column, "A varied axis of the study.")


def _mapping(value: Any) -> Mapping[str, Any]:
    return value if isinstance(value, Mapping) else {}


def _esc(value: Any) -> str:
    return html.escape(str(value), quote=True)
