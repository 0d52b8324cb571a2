"""Study throughput: cases per second on 1 and 2 workers, and where a case's time goes.

Runs a shipped study (``ur10_annex_b``, 162 cases, by default) with ``vtm_pin.study.runner``
into fresh folders, ``--repeat`` times per worker count, and prints the median wall time of the
whole study (cases and the final table, graphs and report) and of its two phases (running the
cases; writing the outputs), the cases per second of each, the speed-ups of 2 workers over 1,
and the mean per-case split (the median of the runs) into model build (scenario, payload and
Annex-B pose), simulation, report (energies, stopping report, summary) and writing the case's
record. Set ``OMP_NUM_THREADS=1`` when timing; the workers pin their own threads.

    OMP_NUM_THREADS=1 python benchmarks/study_throughput.py [--study ur10_annex_b] [--repeat 3]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from vtm_pin.study.cases import find_study, load_study
from vtm_pin.study.runner import run_study

PARTS = ("build", "simulate", "report", "write")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study", default="ur10_annex_b", help="study file or shipped name")
    parser.add_argument("--repeat", type=int, default=3, help="runs per worker count")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    study = load_study(find_study(args.study))
    cases = len(study.cases())
    print(f"study {study.name}: {cases} cases; median of {args.repeat} runs per worker count")
    print(
        f"{'workers':>7} {'whole [s]':>9} {'cases/s':>8} {'speed-up':>8} {'cases [s]':>9} "
        f"{'cases/s':>8} {'speed-up':>8} {'outputs [s]':>11} "
        + " ".join(f"{p + ' [ms]':>13}" for p in PARTS)
        + f" {'outside sim':>11}"
    )
    base: tuple[float, float] | None = None
    for workers in args.workers:
        walls, phases, splits = [], [], []
        for _ in range(args.repeat):
            with tempfile.TemporaryDirectory() as folder:
                begin = time.perf_counter()
                output = run_study(study, Path(folder) / "out", workers=workers)
                walls.append(time.perf_counter() - begin)
                phases.append(output.phases)
                splits.append(output.summary["timing_mean"])
        wall = statistics.median(walls)
        running = statistics.median(p["cases"] for p in phases)
        writing = statistics.median(p["outputs"] for p in phases)
        base = base or (wall, running)
        split = {p: statistics.median(s[p] for s in splits) for p in PARTS}
        outside = 1.0 - split["simulate"] / sum(split.values())
        print(
            f"{workers:>7} {wall:>9.2f} {cases / wall:>8.1f} {base[0] / wall:>8.2f} "
            f"{running:>9.2f} {cases / running:>8.1f} {base[1] / running:>8.2f} {writing:>11.2f} "
            + " ".join(f"{1e3 * split[p]:>13.2f}" for p in PARTS)
            + f" {100 * outside:>10.1f}%"
        )


if __name__ == "__main__":
    main()
