"""A study's throughput floor: what one case costs, against a wall-time target.

Runs the first ``--cases`` samples of a study (default ``studies/ur10_envelope.yaml``) in this
process, one worker's way; by default as many as one batch of the target's study,
``min(BATCH_CASES, total / (4 x workers))``, 1,250 for 10,000 cases on 2 workers (the study's
last round, 2,500 cases there, runs in halves: :func:`vtm_pin.study.runner._chunks`). It reports
the records' mean build, simulate and report times (their sum is what a worker spends) [ms] from
:func:`vtm_pin.study.runner.run_cases` (batched engine, one chunk), and the batched engine's
states and Pinocchio passes per case from :func:`vtm_pin.core.batch.run_many` on the same cases. It
times ``pin.rneaInParallel`` and ``pin.abaInParallel`` (1 thread, as in a worker) on batches of the
study's model states, as many as the batch's runs (a stage evaluates up to all of them in one
call; the engine's own Pinocchio calls are fewer with the compiled kernel), and the import of the
command
(``import vtm_pin.cli`` in a fresh interpreter, less an empty one).

From these it prints a budget: a target of ``--target`` s for ``--total`` cases on
``--workers`` single-threaded workers leaves (target - import) x workers / total core-ms a
case, before the outputs (table, graphs, report) and the workers' start, which it does not
count, so the budget is an upper bound. The Pinocchio floor (the states a case evaluates:
right-hand sides and output samples, x the cheaper of the two per-state costs) is a lower
bound of any engine that evaluates them once each with these algorithms.

It also prints each figure as a multiple of the floor (issue 27's target: a case at most 5x the
floor); then that multiple again over ``--rounds`` rounds, each the cases' time and the floor's
measured back to back (the machine's speed moves between minutes, and with it a ratio of two
figures measured minutes apart: quote the median); and what the batched engine still did lane by
lane in Python per case (:data:`vtm_pin.core.batch.LANE_PYTHON`): resumptions of a case's hybrid
loop (brake decisions, locks, the next phase), event locations with the phase's own functions,
rests located across the lanes, rests settled across the lanes (handed to the loop later, without a
resumption of their own) and the intervals handed to the loop.

    OMP_NUM_THREADS=1 python benchmarks/study_floor.py [--study S] [--cases N] [--target 15] \
        [--rounds 5]
"""

from __future__ import annotations

import argparse
import math
import statistics
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pinocchio as pin
from benchlib import median_time

from vtm_pin.core.batch import run_many
from vtm_pin.core.results import SimulationResult
from vtm_pin.exceptions import VtmError
from vtm_pin.physics.robot import RobotCache
from vtm_pin.scene.scenario import build_scenario
from vtm_pin.study.cases import find_study, load_study, resolve_case
from vtm_pin.study.executors import tune_collector
from vtm_pin.study.runner import BATCH_CASES, CaseTask, run_cases

#: The per-case timing split of a study's records.
PARTS = ("build", "simulate", "report")


def import_seconds() -> float:
    """Median wall time [s] of ``import vtm_pin.cli`` in a fresh interpreter, less startup."""

    def run(code: str) -> Callable[[], object]:
        return lambda: subprocess.run([sys.executable, "-c", code], check=True)

    return median_time(run("import vtm_pin.cli")) - median_time(run("pass"))


def per_state(model: pin.Model, batch: int) -> dict[str, float]:
    """Median wall time per state [us] of RNEA and ABA in parallel, 1 thread, ``batch`` states."""
    rng = np.random.default_rng(14)
    q = rng.uniform(-np.pi, np.pi, (model.nq, batch))
    v = rng.uniform(-1.0, 1.0, (model.nv, batch))
    x = rng.uniform(-1.0, 1.0, (model.nv, batch))
    pool = pin.ModelPool(model, 1)
    algorithms = {"rnea": pin.rneaInParallel, "aba": pin.abaInParallel}
    return {
        name: 1e6 * median_time(lambda f=f: f(1, pool, q, v, x)) / batch
        for name, f in algorithms.items()
    }


def case_times(tasks: list[CaseTask]) -> dict[str, float]:
    """Mean build, simulate and report time of the cases [ms] (a worker's batch, warmed)."""
    tune_collector()  # as a pool worker does at its start (vtm_pin.study.executors._init_worker)
    run_cases(tasks[:50])  # warm: the robots, reaches and schema memo a worker keeps
    ok = [r for r in run_cases(tasks) if r.get("status") == "ok"]
    return {p: 1e3 * statistics.fmean(r["timing"][p] for r in ok) for p in PARTS}


def study_tasks(name: str, cases: int) -> tuple[str, list[CaseTask]]:
    """The study's name and its first ``cases`` case tasks (a worker's way).

    Raises:
        VtmError: No such study, or it is not valid.
    """
    study = load_study(find_study(name))
    folder, source = str(study.scenario.parent), str(study.scenario)
    chosen = study.cases()[:cases]
    return study.name, [CaseTask(study.base, folder, source, "floor", c) for c in chosen]


def floor_ms(model: pin.Model, size: int, states: float) -> float:
    """The Pinocchio floor of a case [ms]: its states x the cheaper per-state cost."""
    return 1e-3 * states * min(per_state(model, size).values())


def floor_ratios(
    tasks: list[CaseTask], model: pin.Model, size: int, states: float, rounds: int
) -> list[float]:
    """A case's core time over the floor, each round's pair measured back to back [-].

    The machine's speed moves between minutes; a case time and a floor measured minutes
    apart move their ratio with it. Each round times the cases (:func:`case_times`), then
    the floor's per-state cost (:func:`per_state`) right after.
    """
    ratios = []
    for _ in range(rounds):
        case = sum(case_times(tasks).values())
        ratios.append(case / floor_ms(model, size, states))
    return ratios


def pinocchio_work(
    tasks: list[CaseTask],
) -> tuple[float, float, int, pin.Model, dict[str, float]]:
    """Per case, the states evaluated and the batched engine's Pinocchio passes; batch size.

    Also the engine's lane-by-lane work per case (:attr:`BatchOutcome.lane_python`), and the
    states the compiled kernel evaluated (``kernel states``).

    The states are the right-hand sides and the output samples (whose holding torques a
    table of the run reads): an engine evaluates each at least once. (A study's records read
    none, and its runs, as these, evaluate none there: the floor keeps counting them.) The
    batched engine takes 1 + k RNEA passes for a state with locks (b and k free columns of
    M), or one compiled pass with the ``fast`` extra (:mod:`vtm_pin.physics.chain_dynamics`).
    """
    robots = RobotCache()
    scenarios = [
        build_scenario(
            resolve_case(t.base, t.case.values),
            source="floor",
            base_dir=Path(t.base_dir),
            name="floor",
            loader=robots,
        )
        for t in tasks
    ]
    outcome = run_many(  # as a study runs them: no holding torques at the samples
        [s.problem for s in scenarios],
        [s.integrator for s in scenarios],
        transition=scenarios[0].transition,
        holding=False,
    )
    results = [r for r in outcome.results if isinstance(r, SimulationResult)]
    states = statistics.fmean(r.rhs_evals + len(r.t) for r in results)
    batch = len(outcome.results)  # the runs stepped together
    lanes = {name: count / len(tasks) for name, count in outcome.lane_python.items()}
    lanes["kernel states (compiled, not Python)"] = outcome.kernel_states / len(tasks)
    return states, outcome.states / len(tasks), batch, scenarios[0].problem.robot.model, lanes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study", default="ur10_envelope", help="study file or shipped name")
    parser.add_argument("--cases", type=int, default=None, help="cases measured [-]")
    parser.add_argument("--target", type=float, default=15.0, help="wall-time target [s]")
    parser.add_argument("--total", type=int, default=10_000, help="cases of the target [-]")
    parser.add_argument("--workers", type=int, default=2, help="workers of the target [-]")
    parser.add_argument("--rounds", type=int, default=5, help="rounds of case and floor [-]")
    args = parser.parse_args()
    batch = min(BATCH_CASES, math.ceil(args.total / (4 * args.workers)))
    try:
        name, tasks = study_tasks(args.study, args.cases or batch)
    except VtmError as exc:
        sys.exit(f"study_floor.py: {exc}")
    split = case_times(tasks)
    states, passes, size, model, lanes = pinocchio_work(tasks)
    cost = per_state(model, size)
    floor = 1e-3 * states * min(cost.values())  # [ms]: us x states
    load = import_seconds()
    budget = 1e3 * (args.target - load) * args.workers / args.total
    measured = sum(split.values())
    print(f"study {name}: {len(tasks)} of its cases in this process; OMP_NUM_THREADS=1")
    print(
        f"Pinocchio per state, 1 thread, batches of {size}: RNEA {cost['rnea']:.2f} us, "
        f"ABA {cost['aba']:.2f} us; a case: {states:.0f} states (right-hand sides and output "
        f"samples), {passes:.0f} passes in the batched engine"
    )
    print(
        f"target: {args.total} cases in {args.target:g} s on {args.workers} workers; import "
        f"{load:.2f} s; budget {budget:.2f} core-ms a case (outputs and worker start not counted)"
    )
    print(f"{'per case':<46} {'[ms]':>7} {'x budget':>9} {'x floor':>8}")
    rows = [
        (f"Pinocchio floor ({states:.0f} states x {min(cost.values()):.2f} us)", floor),
        (f"Pinocchio, the engine's {passes:.0f} passes", 1e-3 * passes * min(cost.values())),
        *((f"{p} (mean)", value) for p, value in split.items()),
        ("build + simulate + report", measured),
        ("everything but the Pinocchio floor", measured - floor),
    ]
    for label, value in rows:
        print(f"{label:<46} {value:>7.2f} {value / budget:>9.2f} {value / floor:>8.1f}")
    room = budget - floor
    need = f"{(measured - floor) / room:.1f}x" if room > 0 else "impossible (floor over budget)"
    print(f"cut needed in everything but the Pinocchio floor to meet the target: {need}")
    ratios = floor_ratios(tasks, model, size, states, args.rounds)
    print(
        f"a case over the floor, {args.rounds} rounds of the cases then the floor, back to back: "
        f"median {statistics.median(ratios):.1f}x (from {min(ratios):.1f} to {max(ratios):.1f}x)"
    )
    print(
        "lane by lane in Python, per case: "
        + ", ".join(f"{name.replace('_', ' ')} {count:.2f}" for name, count in lanes.items())
    )


if __name__ == "__main__":
    main()
