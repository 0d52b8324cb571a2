"""Measurements of speed against accuracy: work-precision points, per-call costs, their plots.

The library of the scripts beside it (``work_precision.py``, ``scaling.py``) and of
``notebooks/03_speed_vs_accuracy.ipynb``; it is not part of the ``vtm_pin`` package, so nothing
the simulator imports at run time loads it. Import it with ``benchmarks/`` on ``sys.path``
(a script run from there has it). Times are medians of wall-clock repeats on whatever machine
runs them; quote ratios measured in one run, not absolute numbers from another machine.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import json
import math
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
from matplotlib.figure import Figure

from vtm_pin.core.holonomic import FrameConstraint, compute_kinematics, stack
from vtm_pin.core.results import SimulationResult
from vtm_pin.core.topology import Topology
from vtm_pin.numerics.constraints import lock_jacobian
from vtm_pin.numerics.dynamics import compute_forward_dynamics, compute_M
from vtm_pin.numerics.integrators import DOP853, RK4, Integrator, SemiImplicitEuler
from vtm_pin.numerics.transitions import TRANSITIONS
from vtm_pin.numerics.transitions.projected import compute_null_space_projector
from vtm_pin.numerics.transitions.recursive import compute_joint_lock_transition, weightless
from vtm_pin.physics.chain import build_chain
from vtm_pin.scene.scenario import Scenario, run_scenario

#: Step sizes [s] (rk4, euler) and relative tolerances [-] (dop853) of a full sweep.
LADDERS: dict[str, list[float]] = {
    "rk4": [1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4],
    "euler": [1e-3, 5e-4, 2e-4, 1e-4, 5e-5, 2e-5],
    "dop853": [1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12],
}
#: Relative tolerance of the DOP853 reference solution [-].
REFERENCE_RTOL = 1e-13
#: Columns of :func:`measure_transition_costs`: three rules, Pinocchio's impulse dynamics,
#: CRBA alone, and one right-hand side on the reduced model vs CRBA + Cholesky on the full one.
COST_KEYS = [
    "kkt",
    "projected",
    "minimal",
    "recursive",
    "recursive_cached",
    "impulseDynamics",
    "crba",
    "rhs_reduced_aba",
    "rhs_full_crba",
]


@dataclass(frozen=True)
class WorkPoint:
    """One run of a work-precision sweep.

    Attributes:
        method: Integrator name (or another label, e.g. ``mujoco-exact``).
        setting: Step [s] of a fixed-step method, or relative tolerance [-] of dop853.
        error: max |q(T) - q_ref(T)| at the final time [rad].
        rhs_evals: Right-hand-side evaluations of the run.
        steps: Integrator steps of the run.
        wall_time: Median wall time of the simulation loop over the repeats [s].
    """

    method: str
    setting: float
    error: float
    rhs_evals: int
    steps: int
    wall_time: float


def median_time(fn: Callable[[], object], budget: float = 0.2) -> float:
    """Median wall time [s] of ``fn()`` over as many repeats (5 to 200) as fill ``budget`` [s]."""
    fn()
    start = time.perf_counter()
    fn()
    once = max(time.perf_counter() - start, 1e-7)
    repeats = int(min(200, max(5, budget / once)))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def make_integrator(method: str, setting: float) -> Integrator:
    """An integrator of a sweep.

    ``rk4`` / ``euler`` take ``setting`` as their step [s]; ``dop853`` as rtol, with
    atol = rtol / 100.

    Raises:
        ValueError: Unknown method.
    """
    if method == "rk4":
        return RK4(setting)
    if method == "euler":
        return SemiImplicitEuler(setting)
    if method == "dop853":
        return DOP853(setting, setting * 1e-2)
    raise ValueError(f"unknown method '{method}'; allowed: dop853, euler, rk4")


def _simulate(scenario: Scenario, integrator: Integrator) -> SimulationResult:
    """The scenario with another integrator and the ``kkt`` rule."""
    return run_scenario(dataclasses.replace(scenario, integrator=integrator), "kkt")


def compute_reference(scenario: Scenario, rtol: float = REFERENCE_RTOL) -> np.ndarray:
    """Final joint positions q(T) [rad] by DOP853 at ``rtol`` (atol = rtol / 100)."""
    return np.asarray(_simulate(scenario, make_integrator("dop853", rtol)).q[-1])


@dataclass(frozen=True)
class Run:
    """One setting of a work-precision sweep, ready to run.

    Attributes:
        method: Integrator name (or another label, e.g. ``mujoco-exact``).
        setting: Step [s] or relative tolerance [-].
        run: One run: final positions q(T) [rad], right-hand-side evaluations, steps, and
            the wall time of the simulation loop [s].
    """

    method: str
    setting: float
    run: Callable[[], tuple[np.ndarray, int, int, float]]


def vtm_pin_runs(scenario: Scenario, ladders: Mapping[str, Sequence[float]]) -> list[Run]:
    """The scenario with every integrator setting of ``ladders`` (``kkt`` rule)."""

    def run(integrator: Integrator) -> tuple[np.ndarray, int, int, float]:
        result = _simulate(scenario, integrator)
        return result.q[-1], result.rhs_evals, result.steps, result.wall_time

    return [
        Run(m, s, functools.partial(run, make_integrator(m, s)))
        for m, settings in ladders.items()
        for s in settings
    ]


def measure_runs(
    runs: Sequence[Run],
    q_ref: np.ndarray,
    rounds: int = 5,
    progress: Callable[[int, int], None] | None = None,
) -> list[WorkPoint]:
    """Error at T and median wall time of each run, measured in interleaved rounds.

    Each round times every setting once, so a burst of load on a shared machine lands on all
    of them alike rather than on the few measured during it: the ratios of one sweep compare
    times taken side by side. Each timed run follows an untimed run of the same setting, so
    every setting is timed warm, as in the repeated runs of a study (right after a long run of
    another setting, a 1 ms run of ours took up to twice as long; MuJoCo's C loop hardly
    changed).

    Args:
        runs: The settings (e.g. :func:`vtm_pin_runs` plus MuJoCo's).
        q_ref: Reference final positions [rad], e.g. from :func:`compute_reference`.
        rounds: Runs per setting; the wall time is their median.
        progress: Called with (runs done, runs in all) after each run.
    """
    walls: list[list[float]] = [[] for _ in runs]
    last: list[tuple[np.ndarray, int, int, float]] = []
    for r in range(rounds):
        for k, item in enumerate(runs):
            item.run()  # warm-up
            outcome = item.run()
            walls[k].append(outcome[3])
            if r == rounds - 1:
                last.append(outcome)
            if progress is not None:
                progress(r * len(runs) + k + 1, rounds * len(runs))
    return [
        WorkPoint(
            item.method,
            item.setting,
            float(np.max(np.abs(q - q_ref))),
            evals,
            steps,
            statistics.median(wall),
        )
        for item, (q, evals, steps, _), wall in zip(runs, last, walls, strict=True)
    ]


def measure_work_precision(
    scenario: Scenario,
    q_ref: np.ndarray,
    ladders: Mapping[str, Sequence[float]] = LADDERS,
    repeats: int = 5,
    progress: Callable[[int, int], None] | None = None,
) -> list[WorkPoint]:
    """Run the scenario with every integrator setting; error at T and median wall time.

    Args:
        scenario: The scenario (its own integrator is ignored; the transition is ``kkt``).
        q_ref: Reference final positions [rad], e.g. from :func:`compute_reference`.
        ladders: Settings per method, as :data:`LADDERS`.
        repeats: Timed runs per setting (in interleaved rounds); the wall time is their
            median.
        progress: Called with (runs done, runs in all) after each run.
    """
    return measure_runs(vtm_pin_runs(scenario, ladders), q_ref, repeats, progress)


def time_to_accuracy(points: Sequence[WorkPoint], method: str, target: float) -> float:
    """Wall time [s] ``method`` needs for an error <= ``target`` [rad], or NaN if never reached.

    Interpolated log-log between the two points that bracket the target; a cheaper point
    that is already more accurate wins.
    """
    pts = sorted((p.error, p.wall_time) for p in points if p.method == method and p.error > 0)
    if not pts or target < pts[0][0]:
        return float("nan")
    best = float("nan")
    for (e1, w1), (e2, w2) in itertools.pairwise(pts):
        if e1 <= target <= e2:
            s = (np.log(target) - np.log(e1)) / (np.log(e2) - np.log(e1))
            best = float(np.exp(np.log(w1) + s * (np.log(w2) - np.log(w1))))
            break
    candidates = [w for w in [best, *(w for e, w in pts if e <= target)] if np.isfinite(w)]
    return min(candidates) if candidates else float("nan")


def format_work_precision(points: Sequence[WorkPoint], targets: Sequence[float]) -> str:
    """Two text tables: every run, then the wall time [ms] per method to reach each target."""
    lines = [
        f"{'method':<13} {'dt / rtol':>9} {'error [rad]':>12} {'rhs evals':>10} "
        f"{'steps':>7} {'wall [ms]':>10}"
    ]
    for p in points:
        lines.append(
            f"{p.method:<13} {p.setting:>9.0e} {p.error:>12.2e} {p.rhs_evals:>10d} "
            f"{p.steps:>7d} {1e3 * p.wall_time:>10.3f}"
        )
    methods = list(dict.fromkeys(p.method for p in points))
    lines += ["", "wall time [ms] to reach an error <= target (log-log interpolated):"]
    lines.append(f"{'target':>8} " + " ".join(f"{m:>13}" for m in methods))
    for target in targets:
        cells = []
        for method in methods:
            t = time_to_accuracy(points, method, target)
            cells.append(f"{1e3 * t:>13.3f}" if np.isfinite(t) else f"{'-':>13}")
        lines.append(f"{target:>8.0e} " + " ".join(cells))
    return "\n".join(lines)


def measure_transition_costs(
    n: int,
    spatial: bool = False,
    general: bool = False,
    seed: int = 0,
    budget: float = 0.2,
) -> dict[str, float]:
    """Median times [s] of one lock transition per rule and of one right-hand side.

    For an n-link chain at a random state, every other joint is already locked (m1 = n // 2
    persistent rows J1) and one more joint locks (m2 = 1). With ``general``, J1 is not made
    of unit rows: the chain's tip is docked (point, 3 rows; pose, 6 rows from n = 12 on) and
    joints are locked until m1 = n // 2 rows.

    Returns:
        ``n``, ``m1``, ``m2`` and the times of :data:`COST_KEYS` [s].
    """
    rng = np.random.default_rng(seed)
    robot = build_chain(n, spatial=spatial)
    model = robot.model
    data = model.createData()
    q = rng.uniform(-0.5, 0.5, n)
    old = list(range(0, n - 1, 2))[: n // 2]
    new = [n - 1] if (n - 1) not in old else [n - 2]
    v = rng.uniform(-1, 1, n)
    J1 = lock_jacobian(n, old)
    if general:
        dock = FrameConstraint("dock", "tip", None, "pose" if n >= 12 else "point")
        dock = dock.latch(model, data, q)
        compute_kinematics(model, data, q, v)
        _, J_dock, _ = stack((dock,), model, data)
        old = old[: max(0, n // 2 - J_dock.shape[0])]
        J1 = np.vstack([J_dock, lock_jacobian(n, old)])
    v = compute_null_space_projector(compute_M(model, data, q), J1) @ v
    J2 = lock_jacobian(n, new)
    J = np.vstack([J1, J2])
    M = compute_M(model, data, q)
    row: dict[str, float] = {"n": n, "m1": J1.shape[0], "m2": len(new)}
    for rule in ("kkt", "projected", "minimal"):
        transition = TRANSITIONS[rule]
        row[rule] = median_time(functools.partial(transition, M, J1, J2, v), budget)
    row["recursive"] = row["recursive_cached"] = math.nan  # joint locks only
    if not general:
        free_model = weightless(model)
        free_data = free_model.createData()
        row["recursive"] = median_time(
            functools.partial(
                compute_joint_lock_transition, free_model, q, v, old, new, data=free_data
            ),
            budget,
        )
        ids = [free_model.getJointId(f"joint{i + 1}") for i in [*old, *new]]
        reduced = pin.buildReducedModel(free_model, ids, q)
        cached = functools.partial(
            compute_joint_lock_transition,
            free_model,
            q,
            v,
            old,
            new,
            reduced=reduced,
            data=free_data,
            reduced_data=reduced.createData(),
        )
        row["recursive_cached"] = median_time(cached, budget)
    row["impulseDynamics"] = median_time(
        lambda: pin.impulseDynamics(model, data, q, v, J, 0.0, 0.0), budget
    )
    row["crba"] = median_time(lambda: compute_M(model, data, q), budget)
    topology = Topology(robot, old, q)
    y = topology.split(q, v)
    row["rhs_reduced_aba"] = median_time(lambda: topology.rhs(0.0, y), budget)
    tau = np.zeros(n)
    row["rhs_full_crba"] = median_time(
        lambda: compute_forward_dynamics(model, data, q, v, tau, old), budget
    )
    return row


def format_transition_costs(rows: Sequence[Mapping[str, float]]) -> str:
    """A text table of :func:`measure_transition_costs` rows, times in microseconds."""
    lines = [f"{'n':>5} {'m1':>4} " + " ".join(f"{k:>16}" for k in COST_KEYS)]
    for row in rows:
        cells = " ".join(f"{1e6 * row[k]:>16.1f}" for k in COST_KEYS)
        lines.append(f"{row['n']:>5.0f} {row['m1']:>4.0f} {cells}")
    return "\n".join(lines)


def plot_work_precision(points: Sequence[WorkPoint], title: str) -> Figure:
    """Wall time [ms] against final-time error [rad], one line per method (log-log)."""
    fig = Figure(figsize=(7, 5), layout="constrained")
    ax = fig.add_subplot()
    for method in dict.fromkeys(p.method for p in points):
        pts = sorted((p.error, p.wall_time) for p in points if p.method == method)
        ax.loglog([e for e, _ in pts], [1e3 * w for _, w in pts], "o-", label=method)
    ax.set_xlabel("error at final time max |q - q_ref| [rad]")
    ax.set_ylabel("wall time [ms] (median)")
    ax.set_title(f"Work-precision: {title}")
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    return fig


def plot_transition_costs(rows: Sequence[Mapping[str, float]], title: str) -> Figure:
    """Median time [us] of one transition per rule and one right-hand side, against n."""
    fig = Figure(figsize=(8, 5), layout="constrained")
    ax = fig.add_subplot()
    ns = [r["n"] for r in rows]
    for key in COST_KEYS:
        ax.loglog(ns, [1e6 * r[key] for r in rows], "o-", label=key)
    ax.set_xlabel("number of joints n")
    ax.set_ylabel("median time [us]")
    ax.set_title(title)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize="small")
    return fig


def run_study_command(path: Path, engine: str, workers: int) -> tuple[float, dict]:
    """One whole ``vtm-pin study`` command into a fresh folder: (wall time [s], summary.json)."""
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "out"
        command = [sys.executable, "-m", "vtm_pin", "study", str(path), "--out", str(out)]
        command += ["--workers", str(workers), "--engine", engine, "--quiet"]
        begin = time.perf_counter()
        subprocess.run(command, check=True)
        wall = time.perf_counter() - begin
        return wall, json.loads((out / "summary.json").read_text())
