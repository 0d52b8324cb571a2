"""Cost of one lock transition per formulation, and of one right-hand side, for n up to 200.

For an n-link chain (``vtm_pin.physics.chain.build_chain``) at a random state, every other joint is
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
from pathlib import Path

from benchlib import format_transition_costs, measure_transition_costs, plot_transition_costs

SIZES = [3, 6, 12, 25, 50, 100, 200]
ROOT = Path(__file__).resolve().parent.parent


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spatial", action="store_true", help="alternate axes y, x, z")
    parser.add_argument(
        "--general", action="store_true", help="J1 = tip docking + locks (non-trivial rows)"
    )
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "out")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for n in [n for n in SIZES if n >= 12] if args.general else SIZES:
        rows.append(measure_transition_costs(n, args.spatial, args.general, seed=n))
        print(f"n = {n}: done", flush=True)
    kind = ("spatial" if args.spatial else "planar") + ("_docked" if args.general else "")
    print(f"\n{kind} chain, m1 = n // 2 persistent rows, m2 = 1 locking; median times [us]")
    print(format_transition_costs(rows))
    title = f"Cost of one transition and one right-hand side ({kind} chain, m1 = n/2)"
    path = args.out / f"scaling_{kind}.png"
    plot_transition_costs(rows, title).savefig(path, dpi=120)
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
