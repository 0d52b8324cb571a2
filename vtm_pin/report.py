"""Reports of a simulation: the summary mapping, the trajectory table and the printed summary."""

from __future__ import annotations

import csv
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .analysis import EnergyMomentum
from .scenario import Scenario
from .simulation import SimulationResult

#: Units of the quantities in summary.json and trajectory.csv.
UNITS = {
    "t": "s",
    "q": "rad (m for prismatic joints)",
    "v": "rad/s (m/s for prismatic joints)",
    "impulse": "N m s (N s for prismatic joints)",
    "energy": "J",
    "momentum": "N m s (N s for prismatic joints)",
    "wall_time": "s",
}


def build_summary(
    scenario: Scenario,
    result: SimulationResult,
    energy: EnergyMomentum,
    compare: Mapping[str, SimulationResult] | None = None,
) -> dict[str, Any]:
    """Summary of a run as plain JSON-ready data (keys documented in the README).

    Args:
        scenario: The scenario that was run.
        result: Its simulation.
        energy: Energies and momenta of ``result``.
        compare: Runs of the same scenario with other transition rules, by rule name.
    """
    summary: dict[str, Any] = {
        "scenario": scenario.source,
        "description": scenario.description,
        "robot": scenario.robot.name,
        "urdf": scenario.robot.source,
        "units": UNITS,
        "joints": list(result.joints),
        "gear_ratio": scenario.robot.gear_ratio.tolist(),
        "transition": result.transition,
        "integrator": {"method": result.integrator, "dt": scenario.integrator.dt},
        "duration": scenario.duration,
        "events": [_event_summary(result, i) for i in range(len(result.events))],
        "final": _final(result),
        "energy": {
            "initial_total": float(energy.total[0]),
            "final_total": float(energy.total[-1]),
            "lost_at_events": float(sum(e.transition.energy_loss for e in result.events)),
        },
        "stats": {
            "rhs_evals": result.rhs_evals,
            "steps": result.steps,
            "wall_time": result.wall_time,
        },
    }
    if compare:
        summary["compare"] = {
            name: {
                "events": [_event_summary(other, i) for i in range(len(other.events))],
                "final": _final(other),
                "final_q_difference": (other.q[-1] - result.q[-1]).tolist(),
            }
            for name, other in compare.items()
        }
    return summary


def _event_summary(result: SimulationResult, i: int) -> dict[str, Any]:
    event = result.events[i]
    tr = event.transition
    free_after = [j for j in result.joints if j not in event.lock + event.locked_before]
    return {
        "t": event.t,
        "lock": list(event.lock),
        "locked_before": list(event.locked_before),
        "q": event.q.tolist(),
        "v_minus": event.v_minus.tolist(),
        "v_plus": tr.v_plus.tolist(),
        "impulse": (-tr.Lambda2).tolist(),
        "impulse_persistent": (-tr.Lambda1).tolist(),
        "energy_loss": tr.energy_loss,
        "free_joints": free_after,
        "p_free_minus": tr.p_free_minus.tolist(),
        "p_free_plus": tr.p_free_plus.tolist(),
    }


def _final(result: SimulationResult) -> dict[str, Any]:
    return {"t": float(result.t[-1]), "q": result.q[-1].tolist(), "v": result.v[-1].tolist()}


def write_trajectory(path: Path, result: SimulationResult) -> None:
    """Write ``t, q_<joint>..., v_<joint>...`` per sample as CSV (SI units, full precision)."""
    header = ["t"] + [f"q_{j}" for j in result.joints] + [f"v_{j}" for j in result.joints]
    table = np.column_stack([result.t, result.q, result.v])
    with path.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(header)
        writer.writerows([f"{x:.17g}" for x in row] for row in table)


def format_summary(summary: Mapping[str, Any]) -> str:
    """The short table the CLI prints: per event t, joints locked, v-/v+, energy lost."""
    joints = summary["joints"]
    lines = [
        f"{summary['scenario']}: robot {summary['robot']} ({len(joints)} joints: "
        f"{', '.join(joints)}), transition {summary['transition']}, "
        f"{summary['integrator']['method']} dt = {summary['integrator']['dt']:g} s, "
        f"{summary['duration']:g} s simulated in {summary['stats']['wall_time']:.3f} s",
        "",
        f"{'t [s]':>8}  {'lock':<14} {'v- [rad/s]':<36} {'v+ [rad/s]':<36} {'lost [J]':>10}",
    ]
    runs = [(summary["transition"], summary)] + [
        (name, run) for name, run in summary.get("compare", {}).items()
    ]
    for name, run in runs:
        if len(runs) > 1:
            lines.append(f"  {name}:")
        for ev in run["events"]:
            lines.append(
                f"{ev['t']:8.4f}  {','.join(ev['lock']):<14} {_vec(ev['v_minus']):<36} "
                f"{_vec(ev['v_plus']):<36} {ev['energy_loss']:10.4f}"
            )
    lines.append("")
    for name, run in runs:
        final = run["final"]
        label = f"final ({name}) at t = {final['t']:g} s"
        lines.append(f"{label}: q = {_vec(final['q'])} rad, v = {_vec(final['v'])} rad/s")
    for name, run in summary.get("compare", {}).items():
        diff = np.abs(run["final_q_difference"])
        lines.append(
            f"final pose {name} - {summary['transition']}: max |dq| = {diff.max():.4f} rad "
            f"({np.degrees(diff.max()):.2f} deg)"
        )
    return "\n".join(lines)


def _vec(values: list[float]) -> str:
    return " ".join(f"{x:+.4f}" for x in values)
