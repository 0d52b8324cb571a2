"""What a calibration writes: calibration.json, the calibrated.yaml fragment, and the plot.

``calibrated.yaml`` is a fragment a scenario includes (``include: [calibrated.yaml]``): the
drives and brakes of every joint, each line marked with where its values come from (fitted to
the table's source, or assumed), and the same statements under ``assumptions`` so that every
report of a scenario that includes it quotes them.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..files.staging import write_staged
from .comparison import Comparison, describe_comparison, warning_line
from .fit import (
    DRIVE_KEYS,
    PRIOR_DELAY,
    PRIOR_EFFORT_FRACTION,
    STATIC_RATIO,
    Calibration,
    LeftOut,
    RowFit,
    drives_and_brakes,
)
from .fit import Figure as FittedFigure
from .table import StoppingTable

#: Resolution of the saved plot [dots per inch].
FIGURE_DPI = 120

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def calibration_summary(
    calibration: Calibration,
    table: StoppingTable,
    checks: Sequence[LeftOut] = (),
    comparison: Comparison | None = None,
) -> dict[str, Any]:
    """The JSON-ready ``calibration.json`` (keys documented in the README)."""
    summary: dict[str, Any] = {
        "class": comparison.chosen if comparison is not None else "custom",
        "robot": calibration.robot,
        "table": table.path,
        "sources": list(table.sources),
        "fit": list(calibration.fit),
        "scatter": {"distance": calibration.scatter[0], "time": calibration.scatter[1]},
        "parameters": [
            {
                "name": f.name,
                "key": f.key,
                "joints": list(f.joints),
                "value": calibration.values[f.name],
                "unit": f.unit,
                "uncertainty": _finite(calibration.uncertainty[f.name]),
                "determined": calibration.determined[f.name],
                "at_bound": calibration.at_bound[f.name],
            }
            for f in calibration.figures
        ],
        "rows": [_row(fit, calibration.scatter) for fit in calibration.rows],
        "cost": calibration.cost,
        "chi2_per_dof": chi2_per_dof(calibration),
        "rank": calibration.rank,
        "parameters_count": len(calibration.figures),
        "singular_values": list(calibration.singular_values),
        "evaluations": calibration.evaluations,
        "success": calibration.success,
        "message": calibration.message,
        "priors": {joint: dict(spec) for joint, spec in calibration.priors.items()},
        "units": {"stop_distance": "rad", "stop_time": "s", "uncertainty": "1 sigma, SI"},
        "uncertainty": uncertainty_section(calibration, table),
    }
    if comparison is not None:
        summary["comparison"] = describe_comparison(comparison)
        summary["none_fits"] = comparison.none_fits
        summary["short_tolerance"] = comparison.short_tolerance
        summary["warning"] = warning_line(comparison)
    if checks:
        summary["leave_one_out"] = [
            {
                "joint": check.joint,
                "parameters": {
                    name: {
                        "value": check.calibration.values[name],
                        "uncertainty": _finite(check.calibration.uncertainty[name]),
                        "determined": check.calibration.determined[name],
                    }
                    for name in check.calibration.values
                },
                "predicted": [_row(fit, calibration.scatter) for fit in check.predictions],
            }
            for check in checks
        ]
    return summary


def chi2_per_dof(calibration: Calibration) -> float | None:
    """2 cost / (residuals - free figures): about 1 if the model fits within the scatter."""
    free = sum(not calibration.at_bound[f.name] for f in calibration.figures)
    dof = 2 * len(calibration.rows) - free
    return 2.0 * calibration.cost / dof if dof > 0 else None


def _row(fit: RowFit, scatter: tuple[float, float]) -> dict[str, Any]:
    row = fit.row
    return {
        "line": row.line,
        "joint": row.joint,
        "stop_distance_published": row.stop_distance,
        "stop_distance_simulated": fit.distance,
        "stop_distance_residual": fit.distance - row.stop_distance,
        "stop_time_published": row.stop_time,
        "stop_time_simulated": fit.time,
        "stop_time_residual": fit.time - row.stop_time,
        "stop_distance_sigmas": (fit.distance - row.stop_distance)
        / (scatter[0] * row.stop_distance),
        "stop_time_sigmas": (fit.time - row.stop_time) / (scatter[1] * row.stop_time),
        "stopped": fit.stopped,
    }


def _finite(x: float) -> float | None:
    return x if x == x and abs(x) != float("inf") else None


def uncertainty_section(calibration: Calibration, table: StoppingTable) -> dict[str, Any]:
    """The fitted figures' covariance for bounds (a fragment's ``calibration`` key).

    Each determined figure with a variance is listed with its value and the scenario keys it
    sets (a perturbation scales them all by the figure's ratio: a sliding torque moves its
    static torque, STATIC_RATIO x it, too); the covariance of those figures (SI, square
    units, figures held at a bound of the search included: see
    :func:`vtm_pin.calibration.fit.calibrate`) is inflated by chi^2 per degree of freedom when
    that is above 1 (the scatter was stated too small). Figures with no variance are fixed;
    undetermined ones are named: no bound can cover them. ``bias`` is the mean relative
    residual (simulated - published) / published of the times and of the distances, and
    ``shortfall`` the most negative one (0 if none is): bounds add the shortfall back, the
    conservative choice.
    """
    names = [f.name for f in calibration.figures]
    static_fitted = any(f.key == "static_torque" for f in calibration.figures)
    free = [
        i
        for i, f in enumerate(calibration.figures)
        if calibration.determined[f.name]
        and np.isfinite(calibration.covariance[i, i])
        and calibration.covariance[i, i] > 0.0
    ]
    chi2 = chi2_per_dof(calibration)
    inflation = max(1.0, chi2) if chi2 is not None else 1.0
    covariance = calibration.covariance[np.ix_(free, free)] * inflation
    rows = calibration.rows
    relative = {
        "stop_time": [(r.time - r.row.stop_time) / r.row.stop_time for r in rows],
        "stop_distance": [(r.distance - r.row.stop_distance) / r.row.stop_distance for r in rows],
    }
    return {
        "source": "; ".join(table.sources),
        "figures": [
            {
                "name": names[i],
                "value": calibration.values[names[i]],
                "unit": calibration.figures[i].unit,
                "keys": _figure_keys(calibration.figures[i], static_fitted),
            }
            for i in free
        ],
        "covariance": covariance.tolist(),
        "inflation": inflation,
        "fixed": [n for k, n in enumerate(names) if k not in free and calibration.determined[n]],
        "undetermined": [
            n for n in names if not calibration.at_bound[n] and not calibration.determined[n]
        ],
        "bias": {key: float(np.mean(values)) for key, values in relative.items()},
        "shortfall": {key: float(min(0.0, min(values))) for key, values in relative.items()},
    }


def _figure_keys(figure: FittedFigure, static_fitted: bool) -> list[str]:
    """The scenario key paths a figure sets."""
    section = "drives" if figure.key in DRIVE_KEYS else "brakes"
    keys = [f"{section}.{joint}.{figure.key}" for joint in figure.joints]
    if figure.key == "sliding_torque" and not static_fitted:
        keys += [f"brakes.{joint}.static_torque" for joint in figure.joints]
    return keys


def calibrated_fragment(
    calibration: Calibration, table: StoppingTable, comparison: Comparison | None = None
) -> str:
    """The ``calibrated.yaml`` text: drives and brakes with their origins, and the covariance."""
    source = "; ".join(table.sources)
    drives, brakes = drives_and_brakes(calibration.values, calibration.figures, calibration.priors)
    chosen = f"model class {comparison.chosen}, " if comparison is not None else ""
    lines = [
        f"# Drives and brakes of {calibration.robot}, fitted by vtm-pin calibrate to",
        f"#   {source}",
        f"# (table {table.path}; {chosen}--fit {','.join(calibration.fit)}).",
        "# Include it from a scenario or a study's base scenario: include: [calibrated.yaml].",
        "# Torques and rotor inertias motor side [N m, kg m^2], delays and ramps [s], speeds",
        "# motor side [rad/s]. `calibration` holds the fitted figures' covariance: a scenario",
        "# with `bounds` turns it into upper bounds of its stopping figures.",
        "assumptions:",
    ]
    statements = _statements(calibration, source)
    warning = warning_line(comparison) if comparison is not None else None
    if warning is not None:
        statements.append(f"CALIBRATION WARNING: {warning}.")
    lines += [f"  - {json.dumps(text)}" for text in statements]
    lines.append("drives:")
    drive_keys = ["rotor_inertia", "short_circuit_torque", "short_circuit_speed"]
    for joint, drive in drives.items():
        origin = _origin(calibration, joint, drive_keys, source)
        lines.append(f"  {joint}: {_flow(drive)}  # {origin}")
    lines.append("brakes:")
    keys = ["delay", "sliding_torque", "static_torque", "ramp", "viscous_velocity"]
    for joint, brake in brakes.items():
        lines.append(f"  {joint}: {_flow(brake)}  # {_origin(calibration, joint, keys, source)}")
    lines.append("calibration:")
    section = uncertainty_section(calibration, table)
    for key, value in section.items():
        lines.append(f"  {key}: {json.dumps(value)}")
    return "\n".join(lines) + "\n"


def _flow(values: Mapping[str, Any]) -> str:
    """A YAML flow mapping: numbers to 6 significant digits, words as they are."""
    return (
        "{"
        + ", ".join(
            f"{key}: {value:.6g}" if isinstance(value, float | int) else f"{key}: {value}"
            for key, value in values.items()
        )
        + "}"
    )


def _origin(calibration: Calibration, joint: str, keys: Sequence[str], source: str) -> str:
    """Where a joint's values of ``keys`` come from: fitted, fitted but undetermined, assumed."""
    fitted: list[str] = []
    loose: list[str] = []
    for figure in calibration.figures:
        if joint in figure.joints and figure.key in keys:
            (fitted if calibration.determined[figure.name] else loose).append(figure.key)
    parts = []
    if fitted:
        parts.append(f"{', '.join(fitted)} fitted to {source}")
    if loose:
        parts.append(f"{', '.join(loose)} fitted but NOT determined by the table")
    if "static_torque" in keys and "static_torque" not in fitted + loose:
        parts.append(f"static_torque = {STATIC_RATIO:g} x sliding (assumed)")
    if not parts:
        return "assumed (priors)"
    if len(fitted) + len(loose) < len(keys):
        parts.append("the others assumed (priors)")
    return "; ".join(parts)


def _statements(calibration: Calibration, source: str) -> list[str]:
    """One assumption line per fitted figure, then one for the priors."""
    out = []
    for figure in calibration.figures:
        value = calibration.values[figure.name]
        sigma = calibration.uncertainty[figure.name]
        who = ", ".join(figure.joints)
        side = " motor side" if figure.positive else ""
        if calibration.at_bound[figure.name]:
            out.append(
                f"{figure.key} of {who}: {value:.4g} {figure.unit}{side}, fitted to {source}: "
                "held at the bound of its search (no uncertainty; the table asks for less)."
            )
        elif calibration.determined[figure.name]:
            out.append(
                f"{figure.key} of {who}: {value:.4g} {figure.unit}{side}, fitted to {source}, "
                f"1-sigma {sigma:.2g} {figure.unit}."
            )
        else:
            out.append(
                f"{figure.key} of {who}: {value:.4g} {figure.unit} was fitted but is NOT "
                f"determined by {source} (assumed)."
            )
    out.append(
        f"Brake and drive figures not fitted are assumed priors: delay {PRIOR_DELAY:g} s, "
        f"sliding torque {PRIOR_EFFORT_FRACTION:g} x the URDF effort limit over the gear "
        f"ratio, static = {STATIC_RATIO:g} x sliding, drives from the robot data."
    )
    return out


def plot_calibration(
    calibration: Calibration,
    checks: Sequence[LeftOut] = (),
    comparison: Comparison | None = None,
) -> Figure:
    """Published against simulated stopping distance and time, every row (and left-out rows).

    With a comparison of several classes, a second row of panels shows each class's relative
    residual (simulated - published) / published per row, against the stated scatter and the
    short tolerance (below it: the unsafe side).
    """
    from matplotlib.figure import Figure

    several = comparison is not None and len(comparison.classes) > 1
    fig = Figure(figsize=(11.0, 8.4 if several else 4.2), layout="constrained")
    axes = fig.subplots(2 if several else 1, 2, squeeze=False)
    labels = [f"{fit.row.joint_label or fit.row.joint}" for fit in calibration.rows]
    quantities = (
        ("stop_distance", "stopping distance [rad]", lambda f: (f.row.stop_distance, f.distance)),
        ("stop_time", "stopping time [s]", lambda f: (f.row.stop_time, f.time)),
    )
    for ax, (_, title, get) in zip(axes[0], quantities, strict=True):
        published = [get(f)[0] for f in calibration.rows]
        simulated = [get(f)[1] for f in calibration.rows]
        x = range(len(labels))
        ax.bar([i - 0.2 for i in x], published, width=0.4, label="published", color="0.6")
        ax.bar([i + 0.2 for i in x], simulated, width=0.4, label="simulated (fit)", color="C0")
        for check in checks:
            for fit in check.predictions:
                i = labels.index(fit.row.joint_label or fit.row.joint)
                ax.plot(i + 0.2, get(fit)[1], "D", color="C3", label="predicted, left out")
        ax.set_xticks(list(x), labels, rotation=15)
        ax.set_title(title)
        handles, names = ax.get_legend_handles_labels()
        unique = dict(zip(names, handles, strict=True))
        ax.legend(unique.values(), unique.keys(), fontsize="small")
        ax.grid(axis="y", alpha=0.3)
    if several:
        assert comparison is not None
        _plot_residuals(axes[1], comparison, labels, calibration.scatter)
    chosen = f"class {comparison.chosen}, " if comparison is not None else ""
    fig.suptitle(
        f"{calibration.robot}: published vs simulated ({chosen}{len(calibration.figures)} "
        f"figures fitted: {','.join(calibration.fit)}; cost {calibration.cost:.3g})",
        fontsize="medium",
    )
    return fig


def _plot_residuals(
    axes: Any, comparison: Comparison, labels: Sequence[str], scatter: tuple[float, float]
) -> None:
    """Each class's relative residual per row, distance (left) and time (right) [%]."""
    width = 0.8 / len(comparison.classes)
    for ax, what, s in zip(axes, ("distance", "time"), scatter, strict=True):
        for k, fit in enumerate(comparison.classes):
            rows = fit.calibration.rows
            values = [
                100.0 * ((r.distance - r.row.stop_distance) / r.row.stop_distance)
                if what == "distance"
                else 100.0 * ((r.time - r.row.stop_time) / r.row.stop_time)
                for r in rows
            ]
            positions = [i - 0.4 + width * (k + 0.5) for i in range(len(rows))]
            mark = " (chosen)" if fit.name == comparison.chosen else ""
            ax.bar(positions, values, width=width, color=f"C{k}", label=f"{fit.name}{mark}")
        ax.axhspan(-100.0 * s, 100.0 * s, color="0.9", zorder=0, label="stated scatter")
        ax.axhline(
            -100.0 * comparison.short_tolerance,
            color="red",
            linestyle="--",
            label=f"short by {100 * comparison.short_tolerance:g} % (unsafe below)",
        )
        ax.set_xticks(range(len(labels)), labels, rotation=15)
        ax.set_ylabel(f"{what}: simulated - published [% of published]")
        ax.set_title(f"stopping {what} residual per model class")
        ax.grid(axis="y", alpha=0.3)
        ax.legend(fontsize="x-small")


def write_calibration(
    out: str | Path,
    calibration: Calibration,
    table: StoppingTable,
    checks: Sequence[LeftOut],
    summary: Mapping[str, Any],
    comparison: Comparison | None = None,
) -> list[str]:
    """Write calibration.json, calibrated.yaml and calibration.png into ``out``, all or none."""
    figure = plot_calibration(calibration, checks, comparison)

    def write(staging: Path) -> None:
        text = json.dumps(summary, indent=2, allow_nan=False)
        (staging / "calibration.json").write_text(text + "\n")
        fragment = calibrated_fragment(calibration, table, comparison)
        (staging / "calibrated.yaml").write_text(fragment)
        figure.savefig(staging / "calibration.png", dpi=FIGURE_DPI)

    return write_staged(out, write)


def format_calibration(summary: Mapping[str, Any]) -> str:
    """The fitted figures and the rows, published against simulated (for the command line)."""
    chi2 = summary["chi2_per_dof"]
    lines = [
        f"calibration of {summary['robot']} to {'; '.join(summary['sources'])}",
        f"  cost {summary['cost']:.4g} (chi2 per degree of freedom "
        f"{'n/a' if chi2 is None else f'{chi2:.3g}'}), rank {summary['rank']} of "
        f"{summary['parameters_count']} figures, {summary['evaluations']} evaluations",
        f"  {'figure':<34} {'value':>11} {'1-sigma':>10}  unit",
    ]
    for p in summary["parameters"]:
        sigma = (
            "at bound"
            if p["at_bound"]
            else "undetermined"
            if not p["determined"]
            else f"{p['uncertainty']:.3g}"
        )
        lines.append(f"  {p['name']:<34} {p['value']:>11.5g} {sigma:>10}  {p['unit']}")
    lines.append(
        f"  {'line':>4} {'joint':<22} {'d pub':>7} {'d sim':>7} [rad] {'t pub':>7} {'t sim':>7} [s]"
    )
    for r in summary["rows"]:
        lines.append(
            f"  {r['line']:>4} {r['joint']:<22} {r['stop_distance_published']:>7.3f} "
            f"{r['stop_distance_simulated']:>7.3f}       {r['stop_time_published']:>7.3f} "
            f"{r['stop_time_simulated']:>7.3f}"
        )
    far = [
        f"row {r['line']} {quantity} {r[f'stop_{quantity}_sigmas']:+.1f} sigma"
        for r in summary["rows"]
        for quantity in ("distance", "time")
        if abs(r[f"stop_{quantity}_sigmas"]) > 2.0
    ]
    if far or (chi2 is not None and chi2 > 2.0):
        lines.append(
            "  the model does not reproduce the table within its stated scatter"
            + (f": {', '.join(far)}" if far else "")
        )
    if not summary["success"]:
        lines.append(f"  the fit did not converge: {summary['message']}")
    lines += _format_comparison(summary.get("comparison", []))
    for check in summary.get("leave_one_out", []):
        for r in check["predicted"]:
            lines.append(
                f"  left out {r['joint']}: distance {r['stop_distance_simulated']:.3f} rad "
                f"(published {r['stop_distance_published']:.3f}), time "
                f"{r['stop_time_simulated']:.3f} s (published {r['stop_time_published']:.3f})"
            )
    return "\n".join(lines)


def _format_comparison(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """The model-class comparison table and its leave-one-out predictions (CLI lines)."""
    if not rows:
        return []
    lines = [
        "  model classes (simplest first; fits = within 2x scatter, chi2 p >= 0.05, unbiased, "
        "nothing short beyond the tolerance):",
        f"  {'class':<15} {'k':>2} {'chi2/dof':>8} {'AIC':>7} {'BIC':>7} {'t bias':>7} "
        f"{'shortest':>8}  fits",
    ]
    for row in rows:
        chi2 = row["chi2_per_dof"]
        mark = " <- chosen" if row["chosen"] else ""
        lines.append(
            f"  {row['class']:<15} {row['free']:>2} {'n/a' if chi2 is None else f'{chi2:.3g}':>8} "
            f"{row['aic']:>7.3g} {row['bic']:>7.3g} {100 * row['time_bias']['mean']:>+6.1f}% "
            f"{100 * row['shortest']:>+7.1f}%  {'yes' if row['fits'] else 'no'}{mark}"
        )
        for reason in row["reasons"]:
            lines.append(f"      {reason}")
    for row in rows:
        for check in row["leave_one_out"]:
            for p in check["rows"]:
                lines.append(
                    f"  left out {check['joint']} ({row['class']}, shared figures): distance "
                    f"{p['distance_predicted']:.3f} rad (published {p['distance_published']:.3f}), "
                    f"time {p['time_predicted']:.3f} s (published {p['time_published']:.3f})"
                )
    return lines
