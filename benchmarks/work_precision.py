"""Work-precision benchmark: error at the final time against wall time, per integrator.

For each scenario every integrator runs over a ladder of step sizes / tolerances. The error is
max |q(T) - q_ref(T)| [rad] against DOP853 at rtol = 1e-13; the time is the median over
``--repeats`` runs of the simulation loop alone (``SimulationResult.wall_time``). With the
optional ``mujoco`` extra installed, MuJoCo replays the scenarios that have prescribed locks
(exact locks: one model per topology plus the consistent jump; soft: its own equality lock
switched on with ``eq_active``) and the ratio of wall times at equal accuracy is printed.

    python benchmarks/work_precision.py [--repeats 5] [--out benchmarks/out]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
from benchlib import (
    LADDERS,
    WorkPoint,
    compute_reference,
    format_work_precision,
    measure_work_precision,
    plot_work_precision,
    time_to_accuracy,
)

import vtm_pin as vp

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ["pendulum3r", "rx160l_paper_locks", "rx160l_estop_cat0"]
MUJOCO_DT = [5e-2, 2.5e-2, 1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4]
TARGETS = [1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10]  # [rad]


def measure_mujoco(scenario: vp.Scenario, q_ref: np.ndarray, repeats: int) -> list[WorkPoint]:
    try:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        import mujoco_reference
    except ImportError:
        return []
    rows = []
    for variant, run in [
        ("mujoco-exact", mujoco_reference.run_exact),
        ("mujoco-soft", mujoco_reference.run_soft),
    ]:
        for dt in MUJOCO_DT:
            try:
                runs = [run(scenario, dt) for _ in range(repeats)]
            except ValueError:  # an event off this dt grid: MuJoCo cannot land on it
                continue
            rows.append(
                WorkPoint(
                    variant,
                    dt,
                    float(np.max(np.abs(runs[-1].q - q_ref))),
                    4 * runs[-1].steps,
                    runs[-1].steps,
                    statistics.median(r.wall_time for r in runs),
                )
            )
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "out")
    parser.add_argument("--scenarios", nargs="*", default=SCENARIOS)
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    report = {}
    for name in args.scenarios:
        scenario = vp.load_scenario(ROOT / "scenarios" / f"{name}.yaml")
        q_ref = compute_reference(scenario)
        started = time.perf_counter()

        def progress(done: int, total: int, name: str = name, started: float = started) -> None:
            elapsed = time.perf_counter() - started
            print(f"\r{name}: {done}/{total} settings, {elapsed:.0f} s", end="", file=sys.stderr)

        rows = measure_work_precision(scenario, q_ref, LADDERS, args.repeats, progress)
        if scenario.stop is None:
            rows += measure_mujoco(scenario, q_ref, args.repeats)
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
