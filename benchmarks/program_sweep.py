"""A program sweep's cost: the whole ``vtm-pin program`` command against single runs.

Runs ``vtm-pin program PROGRAM --scenario BASE --every DT --workers W [--within D]`` as a
subprocess into a fresh folder and prints its wall time, its phases (cases, override search,
swept region, outputs, from the command's own clock), the triggers, the worst trigger and the
override found. Then it times single runs in this process (:func:`vtm_pin.pipeline.run`, no
files) of the scenarios of a few triggers, each the median of repeats, and prints the
per-trigger cost of the sweep's cases phase (core time: wall x workers / cases) against one
single run. Set ``OMP_NUM_THREADS=1``.

    OMP_NUM_THREADS=1 python benchmarks/program_sweep.py [--every 0.1] [--workers 2] [--within 1.43]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from vtm_pin import pipeline
from vtm_pin.scene.scenario import build_scenario
from vtm_pin.study.cases import case_scenario
from vtm_pin.study.sweep import load_program_study


def whole_command(args: argparse.Namespace, out: Path) -> tuple[float, dict]:
    """The command's wall time [s] and its summary.json."""
    command = [sys.executable, "-m", "vtm_pin", "program", args.program, "--scenario"]
    command += [args.scenario, "--every", str(args.every), "--workers", str(args.workers)]
    command += ["--out", str(out), "--quiet"]
    if args.within is not None:
        command += ["--within", str(args.within)]
    begin = time.perf_counter()
    subprocess.run(command, check=True)
    return time.perf_counter() - begin, json.loads((out / "summary.json").read_text())


def single_runs(args: argparse.Namespace, count: int = 5, repeat: int = 3) -> list[float]:
    """Median wall time [s] of single runs of ``count`` triggers' scenarios, in this process."""
    study = load_program_study(args.program, args.scenario, every=args.every)
    cases = study.cases()
    picked = [cases[round(k * (len(cases) - 1) / (count - 1))] for k in range(count)]
    times = []
    for case in picked:
        raw = case_scenario(study.base, case)
        scenario = build_scenario(raw, source="bench", base_dir=study.scenario.parent)
        pipeline.run(scenario)  # warm: the robot's caches
        samples = []
        for _ in range(repeat):
            begin = time.perf_counter()
            pipeline.run(scenario)
            samples.append(time.perf_counter() - begin)
        times.append(statistics.median(samples))
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--program", default="ur10_pick_place")
    parser.add_argument("--scenario", default="ur10_program_cat0")
    parser.add_argument("--every", type=float, default=0.1)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--within", type=float, default=None)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        wall, summary = whole_command(args, Path(folder) / "out")
    study = summary["study"]
    cases = int(summary["counts"]["cases"])
    phases = summary.get("phases", {})
    print(f"vtm-pin program {args.program} --scenario {args.scenario} --every {args.every}")
    print(f"  cases (triggers)          {cases}")
    print(f"  whole command, wall [s]   {wall:.1f} on {args.workers} workers")
    for name, value in phases.items():
        print(f"    {name:<22}  {value:.1f}")
    worst = summary["worst_trigger"]
    print(
        f"  worst trigger             program time {worst['program_time']:.3g} s, "
        f"{worst['ranked_by']} = {worst['value']:.4g} m"
    )
    search = summary.get("override_search")
    if search:
        print(
            f"  override                  F = {search['override']} keeps {search['figure']} within "
            f"{search['allowed']} m (binding trigger {search['binding_program_time']} s, "
            f"{len(search['steps'])} overrides tried)"
        )
    singles = single_runs(args)
    single = statistics.median(singles)
    per_case = phases.get("cases", wall) * args.workers / cases
    print(f"  single run, median [s]    {single:.4f} (of {len(singles)} triggers, in process)")
    print(
        f"  sweep core time per trigger [s] {per_case:.4f} = {per_case / single:.2f} x a single run"
    )
    print(f"  (study {study.get('name')}, {cases} cases)")


if __name__ == "__main__":
    main()
