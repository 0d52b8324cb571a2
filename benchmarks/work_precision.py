"""Work-precision benchmark: error at the final time against wall time, per integrator.

For each scenario every integrator runs over a ladder of step sizes / tolerances. The error is
max |q(T) - q_ref(T)| [rad] against DOP853 at rtol = 1e-13; the time is the median over
``--repeats`` runs of the simulation loop alone (``SimulationResult.wall_time``), taken in
interleaved rounds (each round runs every setting once, MuJoCo's included), so that a burst
of load on a shared machine lands on every setting alike. With the
optional ``mujoco`` extra installed, MuJoCo replays the scenarios that have prescribed locks
(exact locks: one model per topology plus the consistent jump; soft: its own equality lock
switched on with ``eq_active``) and the ratio of wall times at equal accuracy is printed.

    python benchmarks/work_precision.py [--repeats 5] [--out benchmarks/out]
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
from benchlib import (
    LADDERS,
    Run,
    compute_reference,
    format_work_precision,
    measure_runs,
    plot_work_precision,
    time_to_accuracy,
    vtm_pin_runs,
)

import vtm_pin as vp

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ["pendulum3r", "rx160l_paper_locks", "rx160l_estop_cat0"]
MUJOCO_DT = [5e-2, 2.5e-2, 1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4]
TARGETS = [1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10]  # [rad]


def mujoco_runs(scenario: vp.Scenario) -> list[Run]:
    """MuJoCo's replays of the scenario at each step of ``MUJOCO_DT`` it can land on.

    None (an empty list) without the ``mujoco`` extra; a dt off the grid of an event is left
    out (MuJoCo cannot land on the event).
    """
    try:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        import mujoco_reference
    except ImportError:
        return []

    def run(replay: Callable[..., Any], dt: float) -> tuple[np.ndarray, int, int, float]:
        done = replay(scenario, dt)
        return done.q, 4 * done.steps, done.steps, done.wall_time

    runs = []
    for variant, replay in [
        ("mujoco-exact", mujoco_reference.run_exact),
        ("mujoco-soft", mujoco_reference.run_soft),
    ]:
        for dt in MUJOCO_DT:
            try:
                replay(scenario, dt)
            except ValueError:  # an event off this dt grid: MuJoCo cannot land on it
                continue
            runs.append(Run(variant, dt, functools.partial(run, replay, dt)))
    return runs


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "out")
    parser.add_argument("--scenarios", nargs="*", default=SCENARIOS)
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error(f"--repeats {args.repeats}: at least 1 timed run per setting")
    args.out.mkdir(parents=True, exist_ok=True)
    report = {}
    for name in args.scenarios:
        scenario = vp.load_scenario(ROOT / "scenarios" / f"{name}.yaml")
        q_ref = compute_reference(scenario)
        started = time.perf_counter()

        def progress(done: int, total: int, name: str = name, started: float = started) -> None:
            elapsed = time.perf_counter() - started
            print(f"\r{name}: {done}/{total} runs, {elapsed:.0f} s", end="", file=sys.stderr)

        # MuJoCo's settings in the same interleaved rounds as ours (see measure_runs)
        runs = vtm_pin_runs(scenario, LADDERS)
        if scenario.stop is None:
            runs += mujoco_runs(scenario)
        rows = measure_runs(runs, q_ref, args.repeats, progress)
        print(file=sys.stderr)
        print(
            f"\n{name} (T = {scenario.duration} s, {len(scenario.events)} prescribed locks, "
            f"{'brakes' if scenario.brakes else 'no brakes'}); error vs DOP853 rtol 1e-13"
        )
        print(format_work_precision(rows, TARGETS))
        methods = list(dict.fromkeys(r.method for r in rows))
        ratios = {}
        if "mujoco-exact" in methods:
            print("\nMuJoCo exact locks / fastest vtm_pin integrator at equal accuracy:")
            for target in TARGETS:
                ours = [time_to_accuracy(rows, m, target) for m in LADDERS]
                best = min((t for t in ours if np.isfinite(t)), default=float("nan"))
                ratios[target] = time_to_accuracy(rows, "mujoco-exact", target) / best
                print(f"{target:>8.0e} {ratios[target]:6.2f}")
        figure = plot_work_precision(rows, name)
        figure.savefig(args.out / f"work_precision_{name}.png", dpi=120)
        report[name] = {
            "rows": [asdict(r) for r in rows],
            "mujoco_over_best_vtm_pin": {str(k): v for k, v in ratios.items()},
        }
    (args.out / "work_precision.json").write_text(json.dumps(report, indent=2))
    print(f"\nwrote {args.out}/work_precision_*.png and work_precision.json")


if __name__ == "__main__":
    main()
