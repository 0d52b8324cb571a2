"""Two checkouts of vtm_pin against each other on a study's cases, in interleaved pairs.

This machine's speed moves by up to 40 % between minutes, more than most changes gain, so one
run of each checkout cannot tell them apart. This runs the first ``--cases`` cases of a study
in a fresh process of each checkout in turn (``PYTHONPATH`` set to it), ``--pairs`` times,
and prints each pair's core time per case [ms] (build + simulate + report, one process, the
batched engine, after 50 warm-up cases; as :func:`vtm_pin.study.runner.run_cases` does in a
worker), the medians, and the median of the pairs' ratios with how many pairs are below 1.

    OMP_NUM_THREADS=1 python benchmarks/interleaved.py NEW OLD [--study S] [--cases 700]
        [--pairs 8]

Each checkout needs its compiled kernels warm (one earlier run), or its first process
includes their compile.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
from pathlib import Path

#: What each process runs: the cases, timed in CPU time and wall time [ms a case].
PROBE = """
import gc, sys, time
from vtm_pin.study.cases import find_study, load_study
from vtm_pin.study.runner import CaseTask, run_cases
study = load_study(find_study(sys.argv[1]))
tasks = [CaseTask(study.base, str(study.scenario.parent), str(study.scenario), "ab", c)
         for c in study.cases()[: int(sys.argv[2])]]
run_cases(tasks[:50]); gc.collect()
try:  # as the checkout's pool workers set their collector
    from vtm_pin.study.executors import tune_collector
except ImportError:  # a checkout from before it
    gc.freeze()
else:
    tune_collector()
begin = time.perf_counter()
run_cases(tasks)
print(1e3 * (time.perf_counter() - begin) / len(tasks))
"""


def per_case(checkout: Path, study: str, cases: int) -> float:
    """Mean wall time per case [ms] of the study's first ``cases`` cases in ``checkout``."""
    env = {**os.environ, "PYTHONPATH": str(checkout), "OMP_NUM_THREADS": "1"}
    out = subprocess.run(
        [sys.executable, "-c", PROBE, study, str(cases)],
        cwd=checkout,
        env=env,
        check=True,
        capture_output=True,
        text=True,
    )
    return float(out.stdout.split()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("new", type=Path, help="checkout measured first in each pair")
    parser.add_argument("old", type=Path, help="checkout it is compared with")
    parser.add_argument("--study", default="ur10_envelope", help="study file or shipped name")
    parser.add_argument("--cases", type=int, default=700, help="cases a process runs [-]")
    parser.add_argument("--pairs", type=int, default=8, help="interleaved pairs [-]")
    args = parser.parse_args()
    for checkout in (args.new, args.old):
        if not (checkout / "vtm_pin" / "__init__.py").is_file():
            parser.error(f"'{checkout}' is not a vtm_pin checkout (no vtm_pin/__init__.py)")
    new, old = [], []
    print(f"{args.study}, {args.cases} cases a process; build + simulate + report [ms a case]")
    print(f"{'pair':>4} {'new':>7} {'old':>7} {'ratio':>6}")
    for k in range(args.pairs):
        new.append(per_case(args.new.resolve(), args.study, args.cases))
        old.append(per_case(args.old.resolve(), args.study, args.cases))
        print(f"{k + 1:>4} {new[-1]:>7.3f} {old[-1]:>7.3f} {new[-1] / old[-1]:>6.3f}")
    ratios = [a / b for a, b in zip(new, old, strict=True)]
    print(
        f"medians: new {statistics.median(new):.3f}, old {statistics.median(old):.3f} ms a "
        f"case; ratio {statistics.median(ratios):.3f} (below 1 in {sum(r < 1 for r in ratios)} "
        f"of {len(ratios)} pairs)"
    )


if __name__ == "__main__":
    main()
