"""Cases that differ in their payload: the batched engine against the scalar one (issue 27).

A Monte Carlo over an uncertain gripper and part draws a payload per case, so every case has
its own model. Runs ``vtm-pin study`` on the UR10 Annex-B scenario with ``samples`` cases
drawing the tested joint, its speed, the reach and the payload mass in [0, 10] kg (as
``studies/ur10_brake_wear.yaml`` does, without the wear), once per engine, back to back in one
run (the machine may be shared: quote the ratio, not the seconds), each into a fresh folder,
and prints per engine the wall time of the whole command, its ratio to the scalar engine's,
and how many cases each engine ran (with the reasons cases left the batched engine).

    OMP_NUM_THREADS=1 python benchmarks/payload_study.py [--cases 2000] [--workers 2]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import yaml
from benchlib import run_study_command as run

from vtm_pin.scene.scenario import SCENARIOS_DIR


def study_file(folder: Path, cases: int) -> Path:
    """The payload-drawn study, ``cases`` samples, written into ``folder``."""
    study = {
        "description": f"UR10 Annex-B cases with the payload drawn in [0, 10] kg ({cases} cases).",
        "scenario": str(SCENARIOS_DIR / "ur10_annex_b.yaml"),
        "samples": cases,
        "seed": 1,
        "vary": {
            "joint": ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"],
            "speed": {"min": 0.3, "max": 1.0},  # [-] fraction of the velocity limit
            "payload": {"min": 0.0, "max": 10.0},  # [kg]
            "extension": {"min": 0.3, "max": 1.0},  # [-] fraction of maximum reach
        },
    }
    path = folder / "payload_study.yaml"
    path.write_text(yaml.safe_dump(study, sort_keys=False))
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=2000)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--engines", nargs="+", default=["batched", "scalar"])
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        path = study_file(Path(folder), args.cases)
        results = {engine: run(path, engine, args.workers) for engine in args.engines}
    print(
        f"{args.cases} UR10 Annex-B cases, payload drawn in [0, 10] kg, {args.workers} workers, "
        "OMP_NUM_THREADS=1; engines run back to back"
    )
    print(f"{'cases':>6} {'engine':>8} {'wall [s]':>9} {'ratio':>6} {'batched':>8} {'scalar':>7}")
    scalar = results["scalar"][0] if "scalar" in results else None
    for engine, (wall, summary) in results.items():
        counts = summary["engines"]
        ratio = f"{wall / scalar:6.2f}" if scalar else f"{'-':>6}"
        print(
            f"{summary['counts']['cases']:>6} {engine:>8} {wall:>9.1f} {ratio} "
            f"{counts['batched']:>8} {counts['scalar']:>7}"
        )
        for reason, count in counts["fallbacks"].items():
            print(f"{'':>16}{count} on the scalar engine: {reason}")
    print("ratio: wall time / the scalar engine's")


if __name__ == "__main__":
    main()
