"""Batched against scalar engine: a whole ``vtm-pin study`` command, and where its time goes.

Runs ``vtm-pin study STUDY --workers W --engine E`` as a subprocess into a fresh folder, for
the batched and the scalar engine, and prints per engine the median wall time of the whole
command (process start, cases, table, graphs and report), the cases per second, and the
batched engine's speed-up. From the study's ``summary.json`` it splits the time: the mean
per-case model build (scenario, payload, Annex-B pose) and report (stopping figures), and the
batched engine's own split, summed over the workers (:data:`vtm_pin.core.batch.PARTS`: Pinocchio
calls with the solves of locked runs, the runs' hybrid loops, the lanes' own bookkeeping, event
location, vectorised stepping). It also prints the wall time per right-hand-side evaluation of
the whole command, against the 0.86 us per state that ``pinocchio.abaInParallel`` reaches on 2
threads here.

The default study is ``studies/ur10_envelope.yaml`` (10,000 UR10 category-0 cases); ``--cases
N`` runs its first N samples only (the same Halton sequence). Set ``OMP_NUM_THREADS=1``.

    OMP_NUM_THREADS=1 python benchmarks/batched_study.py [--cases 10000] [--repeat 1]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

import yaml
from benchlib import run_study_command as run

from vtm_pin.core.batch import PARTS
from vtm_pin.study.cases import find_study

#: Wall time per state of pinocchio.abaInParallel on a UR10 batch, 2 threads (issue 14) [s].
LIMIT = 0.86e-6


def study_file(folder: Path, study: Path, cases: int | None) -> Path:
    """The study, cut to its first ``cases`` samples (absolute scenario path)."""
    raw = yaml.safe_load(study.read_text())
    raw["scenario"] = str((study.parent / raw["scenario"]).resolve())
    if cases is not None:
        raw["samples"] = cases
    path = folder / "study.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study", default="ur10_envelope", help="study file or shipped name")
    parser.add_argument("--cases", type=int, default=None, help="first N samples only")
    parser.add_argument("--repeat", type=int, default=1, help="runs per engine")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--engines", nargs="+", default=["batched", "scalar"])
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        path = study_file(Path(folder), find_study(args.study), args.cases)
        results = {}
        for engine in args.engines:
            runs = [run(path, engine, args.workers) for _ in range(args.repeat)]
            results[engine] = (statistics.median(w for w, _ in runs), runs[-1][1])
    cases = next(iter(results.values()))[1]["counts"]["cases"]
    print(
        f"{cases} cases, {args.workers} workers, median of {args.repeat} whole commands; "
        f"OMP_NUM_THREADS=1"
    )
    print(
        f"{'engine':>8} {'wall [s]':>9} {'cases/s':>8} {'speed-up':>8} {'rhs evals':>10} "
        f"{'us/rhs':>7} {'x limit':>7} {'build [ms]':>10} {'sim [ms]':>9} {'report [ms]':>11}"
    )
    scalar = results.get("scalar", (None, None))[0]
    for engine, (wall, summary) in results.items():
        evals = summary["engines"]["rhs_evals_total"]
        per_rhs = wall / evals
        timing = summary["timing_mean"]
        speedup = f"{scalar / wall:8.2f}" if scalar else f"{'-':>8}"
        print(
            f"{engine:>8} {wall:>9.2f} {cases / wall:>8.1f} {speedup} {evals:>10d} "
            f"{1e6 * per_rhs:>7.2f} {per_rhs / LIMIT:>7.1f} {1e3 * timing['build']:>10.2f} "
            f"{1e3 * timing['simulate']:>9.2f} {1e3 * timing['report']:>11.2f}"
        )
    if "batched" in results:
        split = results["batched"][1]["engines"]["batched_split_total"]
        total = sum(split.values())
        print("batched engine's time, summed over the workers [s] (share):")
        for part in PARTS:
            share = f"{100 * split[part] / total:4.1f} %" if total > 0 else "no batched case"
            print(f"  {part:>9}: {split[part]:8.2f} ({share})")
        fallbacks = results["batched"][1]["engines"]["fallbacks"]
        print(f"  fallbacks to the scalar engine: {fallbacks or 'none'}")


if __name__ == "__main__":
    main()
