"""The figures of one stop that a safety engineer signs, with the flags that qualify them.

One function, :func:`stop_figures`, derives them from a run's stopping report for both ``vtm-pin
run`` (``summary.json``) and every study case (its row of the results table):

* the robot's own stopping time **T_robot** (from the stop signal reaching the robot until
  every joint is at rest), never ISO 13855's overall T, which adds the safeguard's detection,
  the controller's response and the signal's latency (:mod:`vtm_pin.standards.separation`);
* the tested joint's angle and time, as makers publish them;
* **S_s**, the tool frame's largest displacement from where it was at the signal, and its
  straight-line distance at rest, its path, its peak speed, its drop;
* **S_arm**, the largest displacement of any sampled point of the arm (its links' collision
  geometry, or the segments between its joint origins; :mod:`vtm_pin.physics.arm_points`): the part
  nearest a person is not always the tool;
* T, S (ISO 13855:2024) and S_p (ISO/TS 15066) where the scenario gives their inputs;
* the flags of :mod:`vtm_pin.outputs.flags` (a brake that cannot hold the load, a joint that slips,
a
  payload above its rating, ...).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.results import SimulationResult
from ..physics.arm_points import max_displacement, point_speeds, sample_arm_points
from ..physics.kinematics import compute_tool_jacobian
from ..standards.bounds import derived_uppers, describe, upper_bounds, variants
from .flags import Flag, case_flags, tool_drop
from .stopping import StoppingReport, ToolMotion

#: Flags meaning the arm is not held: it collapses, or slides on once it moves.
NOT_HELD = ("brake_cannot_hold", "brake_cannot_stop", "drive_cannot_hold")
#: The figures of a stop, in table order, with their units.
METRICS = {
    "robot_stop_time": "s",
    "test_stop_time": "s",
    "stop_angle": "rad",
    "tcp_max_displacement": "m",
    "arm_max_displacement": "m",
    "tcp_distance": "m",
    "tcp_path": "m",
    "tool_drop": "m",
    "other_travel": "rad",
    "peak_tcp_speed": "m/s",
    "tcp_speed_at_signal": "m/s",
    "arm_speed_at_signal": "m/s",
    "overall_stop_time": "s",
    "iso13855_distance": "m",
    "ssm_distance": "m",
    "test_speed": "rad/s",
    "test_reach": "m",
}
#: What each figure means (summary.json and report.html quote these).
DEFINITIONS = {
    "robot_stop_time": "T_robot [s], the robot's own stopping time: from the stop signal "
    "reaching the robot until every joint's speed stays below stop.rest_speed. It is NOT ISO "
    "13855's overall stopping performance T, which adds the protective device's detection, "
    "the safety controller's response and the signal latency (overall_stop_time).",
    "test_stop_time": "Stopping time of the tested joint alone [s], as makers publish it "
    "(T_robot waits for every joint; another joint pushed by the stop, or falling until its "
    "own brake engages, can make it longer).",
    "stop_angle": "Stopping distance of the tested joint [rad], |q(end) - q(signal)|; the joint "
    "with the largest travel when the case has no annex_b joint.",
    "tcp_max_displacement": "S_s of the tool [m]: the largest straight-line displacement of the "
    "tool frame from its position at the signal, during the stop (ISO/TS 15066's S_s is the "
    "arm's, arm_max_displacement, which S_p uses).",
    "arm_max_displacement": "S_arm [m]: the largest straight-line displacement of any sampled "
    "point of the arm from its position at the signal, during the stop: points on each moving "
    "link's collision geometry (its convex hull's vertices, at most 100 per link), or on the "
    "segments between the joint origins where the robot has none, and the tool frame's origin "
    "(so S_arm >= S_s). The part of the arm nearest a person is not always the tool.",
    "tcp_distance": "Straight-line distance of the tool frame from the signal to rest [m] "
    "(at most tcp_max_displacement).",
    "tcp_path": "Length of the tool frame's path from the signal to rest [m].",
    "tool_drop": "How far the tool frame falls below its height at the signal [m].",
    "other_travel": "Largest travel after the signal of a joint other than the tested one "
    "[rad] (Annex-B cases): the test assumes 0; the joints fall or swing during the brake "
    "delay and slide to rest after it.",
    "peak_tcp_speed": "Largest tool-frame speed after the signal [m/s].",
    "tcp_speed_at_signal": "The tool frame's speed at the signal [m/s] (the drives hold the "
    "joint rates until the signal).",
    "arm_speed_at_signal": "The largest speed of any sampled point of the arm at the signal "
    "[m/s] (tool included, so at least tcp_speed_at_signal): v_r of ISO/TS 15066 during the "
    "reaction time, as S_p takes it.",
    "overall_stop_time": "T [s] of ISO 13855:2024: detection + response + latency + T_robot "
    "(the scenario's safeguard key); empty without it.",
    "iso13855_distance": "S [m] of ISO 13855:2024: S = K T + D_DS + Z (separation.iso13855); "
    "empty without its inputs.",
    "ssm_distance": "S_p [m] of ISO/TS 15066: S_h + S_r + S_s + C + Z_d + Z_r "
    "(separation.iso_ts_15066 with safeguard), S_s the arm's largest displacement "
    "(arm_max_displacement) and v_r the fastest arm point's speed at the signal "
    "(arm_speed_at_signal); empty without its inputs.",
    "test_speed": "The tested joint's rate at the signal [rad/s] (annex_b cases).",
    "test_reach": "Horizontal reach of the tool frame at the signal [m] (annex_b cases).",
}


@dataclass(frozen=True)
class StopFigures:
    """The figures of one stop and the flags that qualify them.

    Attributes:
        status: ``ok`` (every joint at rest at the end) or ``not_stopped``.
        metrics: :data:`METRICS` and per joint ``stop_time.<joint>`` [s] and
            ``stop_angle.<joint>`` [rad]; None where undefined (a joint still moving).
        flags: The broken assumptions (:mod:`vtm_pin.outputs.flags`), empty if none.
        chain: The stopping chain and separation distances with their inputs
            (:meth:`vtm_pin.standards.separation.Separation.describe`).
        upper: ``<figure>_upper`` bounds (:mod:`vtm_pin.standards.bounds`); empty without bounds.
        bounds: How the bounds were made; empty without bounds.
    """

    status: str
    metrics: Mapping[str, float | None]
    flags: tuple[Flag, ...]
    chain: Mapping[str, Any]
    upper: Mapping[str, float | None] = field(default_factory=dict)
    bounds: Mapping[str, Any] = field(default_factory=dict)

    @property
    def holds(self) -> bool:
        """Whether every brake can hold the arm's weight, and stop it, throughout the stop.

        In a category-2 stop, whether the drives can hold it within their torque limit.
        """
        return not any(f.kind in NOT_HELD for f in self.flags)


def stop_figures(scenario: Any, result: SimulationResult, report: StoppingReport) -> StopFigures:
    """The figures of a scenario's stop (see the module docstring).

    Args:
        scenario: The scenario that was run (:class:`vtm_pin.scene.scenario.Scenario`).
        result: Its simulation.
        report: Its stopping report.
    """
    robot = scenario.robot
    state = scenario.test_state
    angles = [abs(float(a)) for a in report.stop_angles]
    tested = (
        state.joint_index if state is not None else max(range(len(angles)), key=angles.__getitem__)
    )
    reach = report.tcp_reach
    motion = report.motion  # what the report was made from, computed with other runs' or not
    if motion is not None and len(motion.speed):
        speed = float(motion.speed[0])  # its tool speed from the placements, by NumPy
    else:
        speed = tool_speed_at_signal(robot, result, report)
    i0 = int(np.argmax(result.t >= report.signal_time))
    points = sample_arm_points(robot)
    placements = report.placements  # the joints' placements from the signal on, if kept
    if placements is not None and len(placements[1]) != len(result.q) - i0:
        placements = None
    arm = (motion.arm if motion is not None else None) or max_displacement(
        robot, points, result.q[i0:], swept=False, placements=placements
    )
    # The tool's origin is one of the arm's points: S_arm >= S_s, but the two are computed
    # apart and may differ in the last bit; keep the order exact.
    if reach > arm.distance:
        arm = dataclasses.replace(arm, distance=reach)
    # S_s of S_p is the arm's largest displacement (>= the tool's): the part of the arm that
    # reaches a person first is not always the tool, and a smaller S_s is the unsafe side.
    v_r = motion.arm_speed if motion is not None else None
    if v_r is None:
        v_r = float(np.max(point_speeds(robot, points, result.q[i0], result.v[i0])))
    v_r = max(v_r, speed)  # the tool is one of the points: equal up to round-off
    separation = scenario.separation.figures(report.all_stopped_time, v_r, arm.distance)
    metrics: dict[str, float | None] = {
        "robot_stop_time": report.all_stopped_time,
        "test_stop_time": float(report.stop_times[tested]),
        "stop_angle": angles[tested],
        "tcp_max_displacement": reach,
        "arm_max_displacement": arm.distance,
        "tcp_distance": report.tcp_distance,
        "tcp_path": report.tcp_path_length,
        "tool_drop": tool_drop(report),
        "other_travel": max((a for i, a in enumerate(angles) if i != tested), default=0.0)
        if state is not None
        else None,
        "peak_tcp_speed": report.tcp_peak_speed,
        "tcp_speed_at_signal": speed,
        "arm_speed_at_signal": v_r,
        "overall_stop_time": separation["T"],
        "iso13855_distance": separation["S"],
        "ssm_distance": separation["S_p"],
        "test_speed": abs(state.speed) if state is not None else None,
        "test_reach": state.reach if state is not None else None,
    }
    for name, stop_time, angle in zip(report.names, report.stop_times, angles, strict=True):
        metrics[f"stop_time.{name}"] = float(stop_time)
        metrics[f"stop_angle.{name}"] = angle
    clean = {k: (v if v is not None and math.isfinite(v) else None) for k, v in metrics.items()}
    flags = case_flags(
        robot,
        scenario.brakes,
        scenario.payload,
        result,
        report,
        robot.joints[state.joint_index] if state is not None else None,
        scenario.tool_frame,
    )
    chain = scenario.separation.describe(report.all_stopped_time, v_r, arm.distance)
    return StopFigures("ok" if not report.moving else "not_stopped", clean, flags, chain)


def tool_speed_at_signal(robot: Any, result: SimulationResult, report: StoppingReport) -> float:
    """The tool frame's speed at the stop signal [m/s]."""
    i0 = int(np.argmax(result.t >= report.signal_time))
    jac = compute_tool_jacobian(robot, result.q[i0][None], report.tool_frame)[0]
    return float(np.linalg.norm(jac @ result.v[i0]))


def describe_flags(flags: tuple[Flag, ...]) -> list[dict[str, Any]]:
    """The flags as JSON-ready data (NaN figures as None)."""
    return [
        {
            "kind": f.kind,
            "message": f.message,
            "joints": list(f.joints),
            "value": f.value if math.isfinite(f.value) else None,
            "limit": f.limit if math.isfinite(f.limit) else None,
        }
        for f in flags
    ]


def bound_variants(scenario: Any, loader: Any = None) -> list[Any]:
    """The scenarios a scenario's bounds need (:func:`vtm_pin.standards.bounds.variants`), built.

    Args:
        scenario: The nominal scenario, with ``bounds``.
        loader: Loads the robots (a study's cache); :func:`~vtm_pin.physics.robot.load_robot`
            if None.
    """
    from ..physics.robot import load_robot
    from ..scene.scenario import build_scenario

    return [
        build_scenario(
            raw,
            source=f"{scenario.source} (bound {k})",
            base_dir=scenario.base_dir,
            name=scenario.name,
            loader=loader or load_robot,
        )
        for k, raw in enumerate(variants(scenario.raw, scenario.bounds, scenario.uncertainty))
    ]


def bounded(
    scenario: Any,
    figures: StopFigures,
    runs: Sequence[tuple[Any, SimulationResult]],
    motions: Sequence[ToolMotion | None] = (),
) -> StopFigures:
    """``figures`` with their upper bounds, from the runs of :func:`bound_variants`' scenarios.

    ``motions``: the runs' tool motions, if they were computed together
    (:func:`vtm_pin.outputs.stopping.tool_motions`); each computed here if None.

    A worn state whose brakes cannot hold the load is flagged (``worn_brake_cannot_hold``):
    its bound describes a collapsing arm. A variant that has not stopped by the end of the run
    gives no bound at all (every ``*_upper`` None, flagged ``bounds_not_stopped``): its figures
    are only lower bounds.
    """
    from .stopping import compute_stopping_report

    measured = []
    for (variant, result), motion in zip(runs, motions or [None] * len(runs), strict=True):
        report = compute_stopping_report(
            variant.robot, result, variant.brakes, variant.tool_frame, motion
        )
        measured.append(stop_figures(variant, result, report))
    upper = upper_bounds(
        figures.metrics, [m.metrics for m in measured], scenario.bounds, scenario.uncertainty
    )
    upper |= derived_uppers(scenario.separation, figures.metrics, upper)
    flags = figures.flags
    moving = [k for k, m in enumerate(measured) if m.status != "ok"]
    if moving:
        upper = dict.fromkeys(upper)
        flags = (
            *flags,
            Flag(
                "bounds_not_stopped",
                f"{len(moving)} of the bounds' {len(measured)} variant runs (worn brakes, moved "
                "calibrated figures) still move at the end of the run: no upper bound is given; "
                "lengthen duration",
                (),
                float(len(moving)),
                0.0,
            ),
        )
    worn = measured[0]
    if not worn.holds and figures.holds:
        weak = next(f for f in worn.flags if f.kind in NOT_HELD)
        wear = 100 * scenario.bounds.brake_wear
        flags = (
            *flags,
            Flag(
                "worn_brake_cannot_hold",
                f"with every brake {wear:g} % weaker (the bounds' wear), {weak.message}: the "
                "upper bounds describe a collapsing arm",
                weak.joints,
                weak.value,
                weak.limit,
            ),
        )
    return dataclasses.replace(
        figures,
        flags=tuple(flags),
        upper=upper,
        bounds=describe(scenario.bounds, scenario.uncertainty),
    )
