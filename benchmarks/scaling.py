"""Cost of one lock transition per formulation, and of one right-hand side, for n up to 200.

For an n-link chain (``vtm_pin.chain.build_chain``) at a random state, every other joint is
already locked (m1 = n // 2, the persistent constraints J1) and one more joint locks (m2 = 1).
Timed (median of repeats): ``kkt``, ``projected``, ``minimal`` given M, and Pinocchio's
``impulseDynamics`` (which runs its own CRBA) with J+; and one free-coordinate right-hand side
by ABA on the reduced model against CRBA + RNEA + a Cholesky solve of M_ff on the full one.
The paper's complexity statements are the hypothesis: kkt solves n + m1 + m2 equations,
projected n + m2 plus an m1 x m1 inverse (and here M^-1 for the projector), minimal
n - m1 + m2 plus an m1 x m1 inverse.

    python benchmarks/scaling.py [--spatial] [--out benchmarks/out]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pinocchio as pin
from matplotlib.figure import Figure

from vtm_pin import TRANSITIONS, compute_forward_dynamics, compute_M
from vtm_pin.chain import build_chain
from vtm_pin.constraints import lock_jacobian
from vtm_pin.holonomic import FrameConstraint, M_weighted_correction, compute_kinematics, stack
from vtm_pin.topology import Topology

SIZES = [3, 6, 12, 25, 50, 100, 200]
ROOT = Path(__file__).resolve().parent.parent


def median_time(fn: Callable[[], object], budget: float = 0.2) -> float:
    """Median wall time [s] of fn over repeats filling about ``budget`` seconds."""
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


def measure_size(
    n: int, spatial: bool, rng: np.random.Generator, general: bool = False
) -> dict[str, float]:
    """Median times [s] of the transitions and right-hand sides for an n-link chain.

    With ``general``, J1 is not made of unit rows: the chain's tip is docked (point, 3 rows;
    pose, 6 rows, from n = 12 on) and joints are locked until m1 = n // 2 rows.
    """
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
    v = v - M_weighted_correction(compute_M(model, data, q), J1, v)
    J2 = lock_jacobian(n, new)
    J = np.vstack([J1, J2])
    M = compute_M(model, data, q)
    row: dict[str, float] = {"n": n, "m1": J1.shape[0], "m2": len(new)}
    for rule in ("kkt", "projected", "minimal"):
        row[rule] = median_time(lambda rule=rule: TRANSITIONS[rule](M, J1, J2, v))
    row["impulseDynamics"] = median_time(
        lambda: pin.impulseDynamics(model, data, q, v, J, 0.0, 0.0)
    )
    row["crba"] = median_time(lambda: compute_M(model, data, q))
    topology = Topology(robot, old, q)
    y = topology.split(q, v)
    row["rhs_reduced_aba"] = median_time(lambda: topology.rhs(0.0, y))
    tau = np.zeros(n)
    row["rhs_full_crba"] = median_time(
        lambda: compute_forward_dynamics(model, data, q, v, tau, old)
    )
    return row


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spatial", action="store_true", help="alternate axes y, x, z")
    parser.add_argument(
        "--general", action="store_true", help="J1 = tip docking + locks (non-trivial rows)"
    )
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "out")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    rows = []
    for n in [n for n in SIZES if n >= 12] if args.general else SIZES:
        rows.append(measure_size(n, args.spatial, rng, args.general))
        print(f"n = {n}: done", flush=True)
    keys = [
        "kkt",
        "projected",
        "minimal",
        "impulseDynamics",
        "crba",
        "rhs_reduced_aba",
        "rhs_full_crba",
    ]
    kind = ("spatial" if args.spatial else "planar") + ("_docked" if args.general else "")
    print(f"\n{kind} chain, m1 = n // 2 persistent rows, m2 = 1 locking; median times [us]")
    print(f"{'n':>5} {'m1':>4} " + " ".join(f"{k:>16}" for k in keys))
    for row in rows:
        print(f"{row['n']:>5} {row['m1']:>4} " + " ".join(f"{1e6 * row[k]:>16.1f}" for k in keys))
    fig = Figure(figsize=(8, 5), layout="constrained")
    ax = fig.add_subplot()
    ns = [r["n"] for r in rows]
    for k in keys:
        ax.loglog(ns, [1e6 * r[k] for r in rows], "o-", label=k)
    ax.set_xlabel("number of joints n")
    ax.set_ylabel("median time [us]")
    ax.set_title(f"Cost of one transition and one right-hand side ({kind} chain, m1 = n/2)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize="small")
    path = args.out / f"scaling_{kind}.png"
    fig.savefig(path, dpi=120)
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
