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
import itertools
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

import vtm_pin as vp
from vtm_pin.integrators import DOP853, SemiImplicitEuler

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ["pendulum3r", "rx160l_paper_locks", "rx160l_estop_cat0"]
LADDERS = {
    "rk4": [1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4],
    "euler": [1e-3, 5e-4, 2e-4, 1e-4, 5e-5, 2e-5],
    "dop853": [1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12],
}
MUJOCO_DT = [5e-2, 2.5e-2, 1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4]
TARGETS = [1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10]  # [rad]


def integrator(method: str, setting: float) -> vp.integrators.Integrator:
    if method == "rk4":
        return vp.RK4(setting)
    if method == "euler":
        return SemiImplicitEuler(setting)
    return DOP853(setting, setting * 1e-2)


def measure(scenario: vp.Scenario, method: str, setting: float, q_ref: np.ndarray, repeats: int):
    integ = integrator(method, setting)
    times, result = [], None
    for _ in range(repeats):
        result = vp.simulate(
            scenario.robot,
            scenario.q0,
            scenario.v0,
            scenario.duration,
            scenario.events,
            integ,
            "kkt",
            scenario.brakes,
            scenario.stop,
        )
        times.append(result.wall_time)
    assert result is not None
    return {
        "method": method,
        "setting": setting,
        "error": float(np.max(np.abs(result.q[-1] - q_ref))),
        "rhs_evals": result.rhs_evals,
        "steps": result.steps,
        "wall_time": statistics.median(times),
    }


def measure_mujoco(scenario: vp.Scenario, q_ref: np.ndarray, repeats: int) -> list[dict]:
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
                {
                    "method": variant,
                    "setting": dt,
                    "error": float(np.max(np.abs(runs[-1].q - q_ref))),
                    "rhs_evals": 4 * runs[-1].steps,
                    "steps": runs[-1].steps,
                    "wall_time": statistics.median(r.wall_time for r in runs),
                }
            )
    return rows


def time_at(rows: list[dict], method: str, target: float) -> float:
    """Wall time [s] the method needs for error <= target (log-log interpolation), or NaN."""
    pts = sorted((r["error"], r["wall_time"]) for r in rows if r["method"] == method)
    pts = [p for p in pts if p[0] > 0]
    if not pts or target < pts[0][0]:
        return float("nan")
    best = float("nan")
    for (e1, w1), (e2, w2) in itertools.pairwise(pts):
        if e1 <= target <= e2:
            s = (np.log(target) - np.log(e1)) / (np.log(e2) - np.log(e1))
            best = float(np.exp(np.log(w1) + s * (np.log(w2) - np.log(w1))))
            break
    cheaper = [w for e, w in pts if e <= target]
    candidates = [w for w in [best, *cheaper] if np.isfinite(w)]
    return min(candidates) if candidates else float("nan")


def plot(name: str, rows: list[dict], path: Path) -> None:
    fig = Figure(figsize=(7, 5), layout="constrained")
    ax = fig.add_subplot()
    for method in dict.fromkeys(r["method"] for r in rows):
        pts = sorted((r["error"], r["wall_time"]) for r in rows if r["method"] == method)
        ax.loglog([p[0] for p in pts], [1e3 * p[1] for p in pts], "o-", label=method)
    ax.set_xlabel("error at final time max |q - q_ref| [rad]")
    ax.set_ylabel("wall time [ms] (median)")
    ax.set_title(f"Work-precision: {name}")
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    fig.savefig(path, dpi=120)


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
        ref = vp.simulate(
            scenario.robot,
            scenario.q0,
            scenario.v0,
            scenario.duration,
            scenario.events,
            DOP853(1e-13, 1e-15),
            "kkt",
            scenario.brakes,
            scenario.stop,
        )
        q_ref = ref.q[-1]
        rows = []
        started = time.perf_counter()
        for method, ladder in LADDERS.items():
            for setting in ladder:
                rows.append(measure(scenario, method, setting, q_ref, args.repeats))
                print(
                    f"\r{name}: {len(rows)} runs, {time.perf_counter() - started:.0f} s",
                    end="",
                    file=sys.stderr,
                )
        if scenario.stop is None:
            rows += measure_mujoco(scenario, q_ref, args.repeats)
        print(file=sys.stderr)
        print(
            f"\n{name} (T = {scenario.duration} s, {len(scenario.events)} prescribed locks, "
            f"{'brakes' if scenario.brakes else 'no brakes'}); error vs DOP853 rtol 1e-13"
        )
        print(
            f"{'method':<13} {'dt / rtol':>9} {'error [rad]':>12} {'rhs evals':>10} "
            f"{'steps':>7} {'wall [ms]':>10}"
        )
        for r in rows:
            print(
                f"{r['method']:<13} {r['setting']:>9.0e} {r['error']:>12.2e} "
                f"{r['rhs_evals']:>10d} {r['steps']:>7d} {1e3 * r['wall_time']:>10.3f}"
            )
        methods = list(dict.fromkeys(r["method"] for r in rows))
        print("\nwall time [ms] to reach an error <= target (log-log interpolated):")
        print(f"{'target':>8} " + " ".join(f"{m:>13}" for m in methods) + "   ratio")
        ratios = {}
        for target in TARGETS:
            t = {m: time_at(rows, m, target) for m in methods}
            ours = min((t[m] for m in LADDERS if np.isfinite(t[m])), default=float("nan"))
            ratio = t.get("mujoco-exact", float("nan")) / ours
            ratios[target] = ratio
            cells = " ".join(
                f"{1e3 * t[m]:>13.3f}" if np.isfinite(t[m]) else f"{'-':>13}" for m in methods
            )
            print(
                f"{target:>8.0e} {cells}   {ratio:5.2f}"
                if np.isfinite(ratio)
                else f"{target:>8.0e} {cells}"
            )
        plot(name, rows, args.out / f"work_precision_{name}.png")
        report[name] = {
            "rows": rows,
            "mujoco_over_best_vtm_pin": {str(k): v for k, v in ratios.items()},
        }
    (args.out / "work_precision.json").write_text(json.dumps(report, indent=2))
    print(f"\nwrote {args.out}/work_precision_*.png and work_precision.json")


if __name__ == "__main__":
    main()
