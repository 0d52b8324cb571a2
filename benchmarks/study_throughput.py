"""Study throughput: cases per second on 1 and 2 workers, and where a case's time goes.

Runs a shipped study (``ur10_annex_b``, 162 cases, by default) with ``vtm_pin.study_runner``
into fresh folders, ``--repeat`` times per worker count, and prints the median wall time of the
whole study (cases and the final table, graphs and report), the cases per second, the speed-up
of 2 workers over 1, and the median per-case split into model build (scenario, payload and
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

from vtm_pin.study import find_study, load_study
from vtm_pin.study_runner import run_study

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
        f"{'workers':>7} {'wall [s]':>9} {'cases/s':>8} {'speed-up':>8} "
        + " ".join(f"{p + ' [ms]':>13}" for p in PARTS)
        + f" {'outside sim':>11}"
    )
    base: float | None = None
    for workers in args.workers:
        walls, splits = [], []
        for _ in range(args.repeat):
            with tempfile.TemporaryDirectory() as folder:
                begin = time.perf_counter()
                output = run_study(study, Path(folder) / "out", workers=workers)
                walls.append(time.perf_counter() - begin)
                splits.append(output.summary["timing_median"])
        wall = statistics.median(walls)
        base = base or wall
        split = {p: statistics.median(s[p] for s in splits) for p in PARTS}
        outside = 1.0 - split["simulate"] / sum(split.values())
        print(
            f"{workers:>7} {wall:>9.2f} {cases / wall:>8.1f} {base / wall:>8.2f} "
            + " ".join(f"{1e3 * split[p]:>13.2f}" for p in PARTS)
            + f" {100 * outside:>10.1f}%"
        )


if __name__ == "__main__":
    main()
