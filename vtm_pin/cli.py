"""Command-line interface: ``vtm-pin run SCENARIO.yaml [--out DIR] [--transition NAME]``."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import sys
import tempfile
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from .analysis import compute_energy_momentum
from .exceptions import ScenarioError, VtmError, VtmWarning
from .integrators import INTEGRATORS
from .plotting import (
    plot_brake_states,
    plot_constraint_drift,
    plot_energy,
    plot_joint_angles,
    plot_joint_rates,
    plot_momenta,
    plot_tcp_path,
)
from .report import (
    build_summary,
    format_stopping,
    format_summary,
    integrator_settings,
    write_trajectory,
)
from .scenario import build_integrator, load_scenario, run_scenario
from .simulation import SimulationResult
from .stopping import compute_stopping_report
from .transitions import TRANSITIONS

#: Exit codes: 0 success, 1 a user error (bad scenario, robot, option value), 2 bad usage.
EXIT_OK, EXIT_ERROR, EXIT_USAGE = 0, 1, 2


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code instead of exiting (tests call this)."""
    parser = _parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse has printed its one-line usage error
        return int(exc.code) if isinstance(exc.code, int) else EXIT_USAGE
    with warnings.catch_warnings():
        warnings.simplefilter("always", VtmWarning)
        warnings.showwarning = _show_warning
        try:
            return int(args.func(args))
        except VtmError as exc:
            print(f"vtm-pin: error: {exc}", file=sys.stderr)
            return EXIT_ERROR


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:  # type: ignore[no-untyped-def]
    """One line per warning, like the errors."""
    print(f"vtm-pin: warning: {message}", file=sys.stderr)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vtm-pin",
        description="Emergency-stop simulator: joints lock one after another and the free "
        "joints' momentum is conserved at each lock (SI units: s, rad, rad/s, N m s, J).",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser(
        "run",
        help="simulate a scenario file and write its summary, trajectory and plots",
        description="Simulate SCENARIO.yaml; print a per-event table and write summary.json, "
        "trajectory.csv and PNG plots into --out.",
    )
    run.add_argument("scenario", type=Path, help="scenario YAML file")
    run.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output folder (default: results/<scenario name>); files in it are replaced",
    )
    run.add_argument(
        "--transition",
        choices=sorted(TRANSITIONS),
        default=None,
        help="transition rule at a lock, overriding the scenario's (default: the scenario's)",
    )
    run.add_argument(
        "--compare",
        choices=sorted(TRANSITIONS),
        action="append",
        default=[],
        help="also run with this rule and overlay it in the plots (repeatable), e.g. naive",
    )
    run.add_argument(
        "--integrator",
        choices=sorted(INTEGRATORS),
        default=None,
        help="integrator, overriding the scenario's: rk4 or euler (fixed step --dt) or dop853 "
        "(adaptive, --rtol / --atol)",
    )
    run.add_argument("--dt", type=float, default=None, help="fixed step of rk4 / euler [s]")
    run.add_argument("--rtol", type=float, default=None, help="dop853 relative tolerance [-]")
    run.add_argument(
        "--atol", type=float, default=None, help="dop853 absolute tolerance [rad, rad/s]"
    )
    run.set_defaults(func=_run)
    return parser


def _run(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario)
    overrides = {
        key: value
        for key, value in [
            ("method", args.integrator),
            ("dt", args.dt),
            ("rtol", args.rtol),
            ("atol", args.atol),
        ]
        if value is not None
    }
    if overrides:
        spec = {"method": overrides.get("method", scenario.integrator.name), **overrides}
        if spec["method"] == scenario.integrator.name and "method" not in overrides:
            spec = {**integrator_settings(scenario.integrator), **overrides}
        for key, value in spec.items():
            if key != "method" and not value > 0:
                raise ScenarioError("command line", f"--{key}", f"{value} is not > 0")
        try:
            integrator = build_integrator(spec, scenario.duration, "command line")
        except ScenarioError as exc:
            option = "--" + exc.key.split(".")[-1]
            raise ScenarioError("command line", option, exc.problem) from exc
        scenario = dataclasses.replace(scenario, integrator=integrator)
    out = args.out if args.out is not None else Path("results") / scenario.name
    if out.exists() and not out.is_dir():
        print(f"vtm-pin: error: --out '{out}' exists and is not a folder", file=sys.stderr)
        return EXIT_ERROR
    result = run_scenario(scenario, args.transition)
    others = {
        name: run_scenario(scenario, name) for name in args.compare if name != result.transition
    }
    results = {result.transition: result, **others}
    runs = {name: (r, compute_energy_momentum(scenario.robot, r)) for name, r in results.items()}
    stopping = {}
    if scenario.stop is not None:
        stopping = {
            name: compute_stopping_report(scenario.robot, r, scenario.brakes, scenario.tool_frame)
            for name, r in results.items()
        }
    summary = build_summary(scenario, result, runs[result.transition][1], others, stopping)

    figures = {
        "joint_angles.png": plot_joint_angles(runs),
        "joint_rates.png": plot_joint_rates(runs),
        "momenta.png": plot_momenta(runs),
        "energy.png": plot_energy(runs),
    }
    ratio = scenario.robot.gear_ratio
    if np.any(ratio != 1.0):
        figures["motor_angles.png"] = plot_joint_angles(runs, ratio)
        figures["motor_rates.png"] = plot_joint_rates(runs, ratio)
    if np.any(np.isfinite(result.drift)):
        figures["constraint_drift.png"] = plot_constraint_drift(result)
    if scenario.stop is not None:
        figures["brakes.png"] = plot_brake_states(result)
        figures["tcp_path.png"] = plot_tcp_path(stopping)
    _write_outputs(out, summary, results, result.transition, figures)
    print(format_summary(summary))
    for name, report in stopping.items():
        print()
        print(format_stopping(name, report))
    written = ["summary.json", "trajectory.csv", *figures]
    print(f"\nwrote {out}/: {', '.join(written)}")
    return EXIT_OK


def _write_outputs(
    out: Path,
    summary: dict[str, object],
    results: dict[str, SimulationResult],
    main_rule: str,
    figures: dict[str, Figure],
) -> None:
    """Write everything into a staging folder, then move it into ``out`` (no partial output)."""
    parent = out.resolve().parent
    parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".vtm-pin-", dir=parent))
    try:
        (staging / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        for name, result in results.items():
            suffix = "" if name == main_rule else f"_{name}"
            write_trajectory(staging / f"trajectory{suffix}.csv", result)
        for filename, figure in figures.items():
            figure.savefig(staging / filename, dpi=120)
        out.mkdir(parents=True, exist_ok=True)
        for item in sorted(staging.iterdir()):
            os.replace(item, out / item.name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
