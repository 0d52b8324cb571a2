"""Reports of a simulation: the summary mapping, the trajectory table and the printed summary."""

from __future__ import annotations

import csv
import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..core.results import SimulationResult
from ..numerics.integrators import Integrator
from ..physics.brakes import BrakeEvent
from ..scene.scenario import Scenario
from .analysis import EnergyMomentum
from .figures import DEFINITIONS, METRICS, StopFigures, describe_flags
from .stopping import StoppingReport

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
    stopping: Mapping[str, StoppingReport] | None = None,
    figures: StopFigures | None = None,
) -> dict[str, Any]:
    """Summary of a run as plain JSON-ready data (keys documented in the README).

    Args:
        scenario: The scenario that was run.
        result: Its simulation.
        energy: Energies and momenta of ``result``.
        compare: Runs of the same scenario with other transition rules, by rule name.
        stopping: Stopping reports by rule name (main run and compared runs), for stops.
        figures: The main run's signed figures, flags and stopping chain, for stops.
    """
    lost_at_events = float(sum(e.transition.energy_loss for e in result.events))
    brake_work = float(result.brake_work[-1])
    drive_work = float(result.drive_work[-1])
    short_work = float(result.short_circuit_work[-1])
    mechanical_loss = float(energy.total[0] - energy.total[-1])
    summary: dict[str, Any] = {
        "scenario": scenario.source,
        "description": scenario.description,
        "robot": scenario.robot.name,
        "urdf": scenario.robot.source,
        "units": UNITS,
        "joints": list(result.joints),
        "gear_ratio": scenario.robot.gear_ratio.tolist(),
        "transition": result.transition,
        "integrator": integrator_settings(scenario.integrator),
        "duration": scenario.duration,
        "events": [_event_summary(result, i) for i in range(len(result.events))],
        "final": _final(result),
        "assumptions": list(scenario.robot.assumptions) + list(scenario.assumptions),
        "payload": _payload(scenario),
        "annex_b": _test_state(scenario),
        "energy": {
            "initial_total": float(energy.total[0]),
            "final_total": float(energy.total[-1]),
            "lost_at_events": lost_at_events,
            "brake_work": brake_work,
            "drive_work": drive_work,
            "short_circuit_work": short_work,
            "balance_residual": mechanical_loss
            - (lost_at_events + brake_work + short_work - drive_work),
        },
        "brakes": [
            {"joint": b.joint, "delay": b.delay, "friction": b.friction.describe()}
            for b in scenario.brakes
        ],
        "short_circuit": _short_circuit(scenario),
        "brake_events": [_brake_event(e) for e in result.brake_events],
        "constraints": [c.name for c in scenario.constraints],
        "constraint_drift": {
            "position_max": _num(float(np.nanmax(result.drift[:, 0], initial=np.nan)))
            if np.any(np.isfinite(result.drift[:, 0]))
            else None,
            "velocity_max": _num(float(np.nanmax(result.drift[:, 1])))
            if np.any(np.isfinite(result.drift[:, 1]))
            else None,
            "baumgarte": list(scenario.baumgarte),
        },
        "stats": {
            "rhs_evals": result.rhs_evals,
            "steps": result.steps,
            "wall_time": result.wall_time,
        },
    }
    if stopping and result.transition in stopping:
        summary["stopping"] = _stopping(stopping[result.transition], scenario)
    if figures is not None:
        summary["figures"] = {
            "values": dict(figures.metrics),
            "upper": dict(figures.upper),
            "bounds": dict(figures.bounds),
            "units": {**METRICS, "stop_time.<joint>": "s", "stop_angle.<joint>": "rad"},
            "definitions": DEFINITIONS,
        }
        summary["holds"] = figures.holds
        summary["flags"] = describe_flags(figures.flags)
        summary["stopping_chain"] = dict(figures.chain)
    if compare:
        summary["compare"] = {
            name: {
                "events": [_event_summary(other, i) for i in range(len(other.events))],
                "final": _final(other),
                "final_q_difference": (other.q[-1] - result.q[-1]).tolist(),
                **(
                    {"stopping": _stopping(stopping[name], scenario)}
                    if stopping and name in stopping
                    else {}
                ),
            }
            for name, other in compare.items()
        }
    return summary


def _short_circuit(scenario: Scenario) -> dict[str, Any]:
    """The short-circuit braking figures of the motors that have it (motor side), by joint."""
    from ..physics.drives import short_circuit

    law = short_circuit(scenario.robot)
    return {} if law is None else law.describe(scenario.robot.joints)


def _payload(scenario: Scenario) -> dict[str, Any] | None:
    """The payload attached to the robot, or None."""
    from ..physics.payload import payload_summary

    payload = scenario.payload
    return None if payload is None else payload_summary(payload, payload.frame)


def _test_state(scenario: Scenario) -> dict[str, Any] | None:
    """The Annex-B test state the initial state was computed from, or None."""
    state = scenario.test_state
    if state is None:
        return None
    return {
        "joint": scenario.robot.joints[state.joint_index],
        "speed": state.speed,
        "reach": state.reach,
        "max_reach": state.max_reach,
        "extension": state.reach / state.max_reach,
        "moves_tool_vertically": state.vertical,
        "units": {"speed": "rad/s (m/s for prismatic joints)", "reach": "m", "max_reach": "m"},
    }


def _brake_event(event: BrakeEvent) -> dict[str, Any]:
    return {
        "t": event.t,
        "joint": event.joint,
        "kind": event.kind.value,
        "v": event.v,
        "holding_torque": _num(event.holding_torque),
        "static_torque": _num(event.static_torque),
    }


#: How the stopping report's times are defined (written into summary.json and the README).
STOP_TIME_DEFINITION = (
    "stop_time: time from the stop signal reaching the robot until the joint's speed falls "
    "below rest_speed for good (the robot's own stopping time, part of but not ISO 13855's "
    "overall T, which adds detection, response and latency: see stopping_chain); null if the "
    "joint still moves at the end of the run. latch_time: time from the signal until the "
    "joint's brake sticks or locks for good; in a category-1 stop the drives end the motion "
    "before the brakes latch; in a category-2 stop no brake is signalled (the drives hold the "
    "arm) and latch_time is null."
)


def _stopping(report: StoppingReport, scenario: Scenario) -> dict[str, Any]:
    ideal = {b.joint for b in scenario.brakes if b.ideal}
    return {
        "definition": STOP_TIME_DEFINITION,
        "rest_speed": report.rest_speed,
        "signal_time": report.signal_time,
        "all_stopped": not report.moving,
        "all_stopped_time": _num(report.all_stopped_time),
        "still_moving": list(report.moving),
        "tool_frame": report.tool_frame,
        "tcp_distance": report.tcp_distance,
        "tcp_path_length": report.tcp_path_length,
        "tcp_peak_speed": report.tcp_peak_speed,
        "tcp_peak_surge": report.tcp_peak_surge,
        "joints": [
            {
                "joint": j.joint,
                "stopped": j.stopped,
                "stop_time": _num(j.stop_time),
                "latch_time": _num(j.latch_time),
                "stop_angle": j.stop_angle,
                "stop_angle_motor": j.stop_angle_motor,
                "peak_surge": j.peak_surge,
                "friction_impulse": j.friction_impulse,
                "lock_impulse": j.lock_impulse,
                "brake_impulse": j.friction_impulse + j.lock_impulse,
                "peak_holding_torque": _num(j.peak_holding_torque),
                "holding_margin": "ideal" if j.joint in ideal else _num(j.holding_margin),
            }
            for j in report.joints
        ],
    }


def _num(x: float) -> float | None:
    """JSON has no NaN or infinity: None stands for 'not applicable'."""
    return float(x) if np.isfinite(x) else None


def format_stopping(name: str, report: StoppingReport) -> str:
    """Per-joint stopping table of one run, with the definition of its times."""
    w = max(12, *(len(j.joint) for j in report.joints))
    lines = [
        f"stopping report ({name}), signal at t = {report.signal_time:g} s; a joint has "
        f"stopped once its speed stays below {report.rest_speed:g} rad/s (stop.rest_speed); "
        "latch = its brake stuck or locked:",
        f"{'joint':<{w}} {'stop [s]':>9} {'latch [s]':>9} {'angle [rad]':>12} "
        f"{'motor [rad]':>12} {'surge [rad/s]':>14} {'brake imp. [N m s]':>19} "
        f"{'peak hold [N m]':>16} {'margin [N m]':>13}",
    ]
    for j in report.joints:
        stop = _fmt(j.stop_time, "9.4f") if j.stopped else f"{'moving':>9}"
        lines.append(
            f"{j.joint:<{w}} {stop} {_fmt(j.latch_time, '9.4f')} {j.stop_angle:12.4f} "
            f"{j.stop_angle_motor:12.2f} {j.peak_surge:14.4f} "
            f"{j.friction_impulse + j.lock_impulse:19.3f} {_fmt(j.peak_holding_torque, '16.1f')} "
            f"{_fmt(j.holding_margin, '13.1f')}"
        )
    if report.moving:
        status = (
            f"not every joint stopped: {', '.join(report.moving)} still moving at the end of "
            f"the run (t = {report.end_time:g} s)"
        )
    else:
        status = f"all joints stopped {report.all_stopped_time:.4f} s after the signal"
    lines.append(
        f"{status}; tool frame '{report.tool_frame}': stopping distance "
        f"{report.tcp_distance:.4f} m, path {report.tcp_path_length:.4f} m, peak speed "
        f"{report.tcp_peak_speed:.3f} m/s, largest speed jump at a lock "
        f"{report.tcp_peak_surge:.4f} m/s"
    )
    return "\n".join(lines)


def format_figures(figures: StopFigures) -> str:
    """The signed figures, the stopping chain with its formulas, and the flags (CLI lines)."""
    m = figures.metrics
    chain = figures.chain
    lines = [
        f"signed figures: T_robot {_opt(m['robot_stop_time'], 's')} (the robot's own stop, "
        f"from the signal reaching it; NOT ISO 13855's T); tested joint "
        f"{_opt(m['stop_angle'], 'rad')} in {_opt(m['test_stop_time'], 's')}; S_s "
        f"{_opt(m['tcp_max_displacement'], 'm')} (the tool's largest displacement); S_arm "
        f"{_opt(m['arm_max_displacement'], 'm')} (any point of the arm); tool drop "
        f"{_opt(m['tool_drop'], 'm')}"
    ]
    guard = chain.get("safeguard")
    if guard is None:
        lines.append("stopping chain: no safeguard given: T, S and S_p are not computed")
    else:
        lines.append(
            f"stopping chain: T = t_detection + t_response + t_latency + T_robot = "
            f"{guard['detection_time']:g} + {guard['response_time']:g} + {guard['latency']:g} + "
            f"{_opt(m['robot_stop_time'])} = {_opt(chain['T'], 's')}"
        )
    iso = chain.get("iso13855")
    if iso is not None:
        lines.append(
            f"ISO 13855:2024: S = K T + D_DS + Z = {iso['approach_speed']:g} x "
            f"{_opt(chain['T'])} + {iso['intrusion_distance']:g} + {iso['supplement']:g} "
            f"= {_opt(iso['S'], 'm')}"
        )
    ssm = chain.get("iso_ts_15066")
    if ssm is not None and ssm["terms"] is not None:
        terms = ssm["terms"]
        lines.append(
            "ISO/TS 15066: S_p = S_h + S_r + S_s + C + Z_d + Z_r = "
            + " + ".join(_opt(terms[k]) for k in ("S_h", "S_r", "S_s", "C", "Z_d", "Z_r"))
            + f" = {_opt(terms['S_p'], 'm')} (v_h {ssm['human_speed']:g} m/s, T_r "
            f"{ssm['T_r']:g} s, v_r {ssm['v_r']:.3g} m/s)"
        )
    if figures.upper:
        shown = ", ".join(
            f"{name.removesuffix('_upper')} {_opt(value, METRICS[name.removesuffix('_upper')])}"
            for name, value in figures.upper.items()
            if value is not None
        )
        lines.append(f"upper bounds: {shown}")
        lines.append(f"  {figures.bounds['text']}")
    if not figures.flags:
        lines.append(
            "flags: none (every brake holds the load, or in category 2 the drives; no other "
            "joint slips)"
        )
    lines += [f"FLAG {flag.kind}: {flag.message}" for flag in figures.flags]
    return "\n".join(lines)


def _opt(x: float | None, unit: str = "") -> str:
    """A figure with its unit, or ``-`` (not computed)."""
    if x is None:
        return "-"
    return f"{x:.4g} {unit}" if unit else f"{x:.4g}"


def _fmt(x: float, spec: str) -> str:
    width = int(spec.split(".")[0])
    if np.isnan(x):
        return f"{'-':>{width}}"
    if np.isinf(x):
        return f"{'ideal':>{width}}"
    return format(x, spec)


def _event_summary(result: SimulationResult, i: int) -> dict[str, Any]:
    event = result.events[i]
    tr = event.transition
    free_after = [j for j in result.joints if j not in event.lock + event.locked_before]
    return {
        "t": event.t,
        "kind": event.kind.value,
        "lock": list(event.lock),
        "locked_before": list(event.locked_before),
        "q": event.q.tolist(),
        "v_minus": event.v_minus.tolist(),
        "v_plus": tr.v_plus.tolist(),
        "activate": list(event.activate),
        "impulse": (-tr.Lambda2).tolist(),
        "impulse_rows": [str(label) for label in event.rows[tr.m1 :]],
        "impulse_persistent": (-tr.Lambda1).tolist(),
        "impulse_persistent_rows": [str(label) for label in event.rows[: tr.m1]],
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
    w = 8 * len(joints)
    lines = [
        f"{summary['scenario']}: robot {summary['robot']} ({len(joints)} joints: "
        f"{', '.join(joints)}), transition {summary['transition']}, "
        f"{_describe(summary['integrator'])}, "
        f"{summary['duration']:g} s simulated in {summary['stats']['wall_time']:.3f} s",
        "",
        f"{'t [s]':>8}  {'kind':<5} {'lock':<22} {'v- [rad/s]':<{w}} {'v+ [rad/s]':<{w}} "
        f"{'lost [J]':>10}",
    ]
    runs = [(summary["transition"], summary)] + [
        (name, run) for name, run in summary.get("compare", {}).items()
    ]
    for name, run in runs:
        if len(runs) > 1:
            lines.append(f"  {name}:")
        for ev in run["events"]:
            lines.append(
                f"{ev['t']:8.4f}  {ev['kind']:<5} {','.join(ev['lock'] + ev['activate']):<22} "
                f"{_vec(ev['v_minus']):<{w}} {_vec(ev['v_plus']):<{w}} {ev['energy_loss']:10.4f}"
            )
    lines.append("")
    for name, run in runs:
        final = run["final"]
        label = f"final ({name}) at t = {final['t']:g} s"
        lines.append(f"{label}: q = {_vec(final['q'])} rad, v = {_vec(final['v'])} rad/s")
    energy = summary["energy"]
    if energy["brake_work"] or energy["drive_work"] or energy["short_circuit_work"]:
        lines.append(
            f"energy: lost at locks {energy['lost_at_events']:.4f} J, brake friction work "
            f"{energy['brake_work']:.4f} J, short-circuit braking "
            f"{energy['short_circuit_work']:.4f} J, drive work {energy['drive_work']:.4f} J; "
            "balance residual "
            f"{energy['balance_residual']:.2e} J"
        )
    for name, run in summary.get("compare", {}).items():
        diff = np.abs(run["final_q_difference"])
        lines.append(
            f"final pose {name} - {summary['transition']}: max |dq| = {diff.max():.4f} rad "
            f"({np.degrees(diff.max()):.2f} deg)"
        )
    if summary["assumptions"]:
        lines.append("assumptions behind these figures:")
        lines.extend(f"  - {' '.join(text.split())}" for text in summary["assumptions"])
    return "\n".join(lines)


def integrator_settings(integrator: Integrator) -> dict[str, Any]:
    """``{"method": name, <its settings>}`` for summary.json (event tolerance left out).

    dop853's ``output_dt`` [s] is there when set.
    """
    fields = {
        k: v
        for k, v in dataclasses.asdict(integrator).items()  # type: ignore[call-overload]
        if k not in ("name", "event_tol")
    }
    if fields.get("max_step") == float("inf"):
        del fields["max_step"]
    if "output_dt" in fields and fields["output_dt"] is None:  # dop853 at its steps
        del fields["output_dt"]
    return {"method": integrator.name, **fields}


def _describe(settings: Mapping[str, Any]) -> str:
    parts = [
        f"{k} = {v:g}{' s' if k in ('dt', 'output_dt') else ''}"
        for k, v in settings.items()
        if k != "method"
    ]
    return f"{settings['method']} {', '.join(parts)}"


def _vec(values: list[float]) -> str:
    return " ".join(f"{x:+.4f}" for x in values)
