"""The stopping report: where and when each joint stops, and how hard brakes and gears are hit.

A joint's **stopping time** is the time from the stop signal until its speed falls below the
rest speed (``stop.rest_speed``, default 1e-3 rad/s) for good, as a safety engineer measures
it (ISO 13855's T). It is not the instant the brake latches (sticks, or locks ideally),
which is reported beside it as the **latch time**: in a category-1 stop the drives' ramp ends
the motion before the brakes engage.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.results import RowKind, SimulationResult
from ..physics.arm_points import (
    ArmDisplacement,
    fastest_point_speeds,
    max_displacements,
    sample_arm_points,
)
from ..physics.brakes import Brake, BrakeEventKind, BrakeMode
from ..physics.kinematics import (
    cached_chain,
    compute_tool_jacobian,
    frame_motion,
    kinematics_key,
    tool_column_norms,
)
from ..physics.robot import Robot
from ..physics.stop import DEFAULT_REST_SPEED


@dataclass(frozen=True)
class JointStop:
    """How one joint stopped.

    Attributes:
        joint: Joint name.
        stop_time: Time from the stop signal until the joint's speed falls below the rest
            speed for good [s]; NaN if it was still moving at the end (see ``stopped``).
        latch_time: Time from the stop signal until the joint locked for good (its brake
            stuck or locked) [s]; NaN if it was not locked at the end.
        stop_angle: Joint travel from the signal to the end, q(end) - q(signal) [rad].
        stop_angle_motor: The same on the motor side, x gear ratio [rad].
        peak_surge: Largest speed-up |v+| - |v-| this joint received from a lock of other
            joints while it was free [rad/s] (0 if none).
        friction_impulse: Angular impulse of the brake's sliding friction [N m s].
        lock_impulse: Sum of the impulsive torques its lock took at lock events, -Lambda
            [N m s] (its own lock and later locks of other joints).
        peak_holding_torque: Largest |torque| the lock had to hold while locked [N m], joint
            side; NaN if never locked or not computed.
        holding_margin: Smallest static torque minus |holding torque| while stuck [N m];
            +inf for ideal locks, NaN if the joint never stuck.
    """

    @property
    def stopped(self) -> bool:
        """Whether the joint was at rest (below the rest speed) at the end of the run."""
        return bool(np.isfinite(self.stop_time))

    joint: str
    stop_time: float
    latch_time: float
    stop_angle: float
    stop_angle_motor: float
    peak_surge: float
    friction_impulse: float
    lock_impulse: float
    peak_holding_torque: float
    holding_margin: float


@dataclass(frozen=True)
class StoppingReport:
    """Stopping report of an emergency stop.

    The figures every stop's record needs are computed with the report; the per-joint
    details of the locks and brakes (:attr:`joints`' latch times, surges, impulses, holding
    torques and margins) and :attr:`tcp_peak_surge` when first asked for, from the run kept
    in :attr:`source` (a study's record does not hold them: ~0.2 ms a UR10 case).

    Attributes:
        signal_time: When the stop button was pressed [s].
        names: The joints, in model order.
        stop_times: Each joint's stopping time [s] (:attr:`JointStop.stop_time`), shape (n,).
        stop_angles: Each joint's travel from the signal to the end [rad]
            (:attr:`JointStop.stop_angle`), shape (n,).
        rest_speed: Speed below which a joint counts as stopped [rad/s].
        end_time: End of the run [s].
        all_stopped_time: Time from the signal until every joint is at rest for good [s]
            (NaN if some joint was still moving at the end: see ``moving``).
        tool_frame: Frame followed.
        tcp_path: Tool-frame positions from the signal on [m], shape (k, 3).
        tcp_distance: Straight-line distance from the signal position to the final one [m].
        tcp_path_length: Length of the swept path after the signal [m].
        tcp_peak_speed: Largest tool-frame speed after the signal [m/s].
        tcp_reach: Largest distance of the tool frame from its signal position [m].
        placements: The joints' world placements ``(R, p)`` at the samples from the signal on
            (:func:`vtm_pin.physics.kinematics.joint_placements`), which
            :func:`vtm_pin.outputs.figures.stop_figures` reuses; None if not at hand.
        motion: The motion from the signal on that the report was made from
            (:class:`ToolMotion`: what :func:`tool_motions` computed with other runs' as well).
        source: The robot, the run and its brakes the report was made from.
    """

    signal_time: float
    names: tuple[str, ...]
    stop_times: np.ndarray
    stop_angles: np.ndarray
    rest_speed: float
    end_time: float
    all_stopped_time: float
    tool_frame: str
    tcp_path: np.ndarray
    tcp_distance: float
    tcp_path_length: float
    tcp_peak_speed: float
    tcp_reach: float
    placements: tuple[np.ndarray, np.ndarray] | None = field(
        default=None, repr=False, compare=False
    )
    motion: ToolMotion | None = field(default=None, repr=False, compare=False)
    source: tuple[Robot, SimulationResult, tuple[Brake, ...]] | None = field(
        default=None, repr=False, compare=False
    )

    @property
    def moving(self) -> tuple[str, ...]:
        """Joints still moving (above the rest speed) at the end of the run."""
        return tuple(
            name
            for name, t in zip(self.names, self.stop_times.tolist(), strict=True)
            if not math.isfinite(t)
        )

    @functools.cached_property
    def joints(self) -> tuple[JointStop, ...]:
        """One :class:`JointStop` per joint, in model order (computed when first asked for)."""
        robot, result, brakes = self._source()
        latch_time, surge, lock_impulse = _event_figures(robot, result, self.signal_time)
        peak_hold, margin = _holding_figures(robot, result, brakes)
        motor = self.stop_angles * robot.gear_ratio
        return tuple(
            JointStop(
                joint=name,
                stop_time=float(self.stop_times[j]),
                latch_time=float(latch_time[j]),
                stop_angle=float(self.stop_angles[j]),
                stop_angle_motor=float(motor[j]),
                peak_surge=float(surge[j]),
                friction_impulse=float(result.brake_impulse[j]),
                lock_impulse=float(lock_impulse[j]),
                peak_holding_torque=float(peak_hold[j]),
                holding_margin=float(margin[j]),
            )
            for j, name in enumerate(self.names)
        )

    @functools.cached_property
    def tcp_peak_surge(self) -> float:
        """Largest jump of the tool-frame speed at a lock [m/s] (computed when first asked for)."""
        robot, result, _ = self._source()
        events = result.events
        surge = 0.0
        if not events:
            return surge
        jacobians = compute_tool_jacobian(robot, np.array([e.q for e in events]), self.tool_frame)
        for event, jac in zip(events, jacobians, strict=True):
            after, before = jac @ event.v_plus, jac @ event.v_minus
            # |x| as np.linalg.norm takes it for a vector: sqrt(x . x)
            jump = math.sqrt(after @ after) - math.sqrt(before @ before)
            surge = max(surge, float(jump))
        return surge

    def _source(self) -> tuple[Robot, SimulationResult, tuple[Brake, ...]]:
        if self.source is None:
            raise ValueError("this stopping report keeps no run to compute its details from")
        return self.source


@dataclass(frozen=True)
class ToolMotion:
    """The motion a stopping report reads, from the stop signal's sample on.

    Attributes:
        placements: The joints' world placements ``(R, p)`` at those samples
            (:func:`vtm_pin.physics.kinematics.joint_placements`): rotations, shape
            (k, njoints, 3, 3), and origins [m], shape (k, njoints, 3).
        path: The tool frame's origin [m], shape (k, 3).
        speed: Its speed [m/s], shape (k,).
        arm: The arm's points' largest displacement from the first of those samples
            (:func:`~vtm_pin.physics.arm_points.max_displacements`), if it was computed.
        arm_speed: The fastest arm point's speed at the first sample [m/s]
            (:func:`~vtm_pin.physics.arm_points.fastest_point_speeds`), if it was computed.
        column_norms: The lengths of the tool frame's linear Jacobian columns at the first
            sample [m/rad or -], shape (nv,)
            (:func:`~vtm_pin.physics.kinematics.tool_column_norms`), if they were computed.
        figures: What the report reads from the run's samples (:func:`sample_figures`), if
            they were computed with other runs'.
    """

    placements: tuple[np.ndarray, np.ndarray]
    path: np.ndarray
    speed: np.ndarray
    arm: ArmDisplacement | None = None
    arm_speed: float | None = None
    column_norms: np.ndarray | None = None
    figures: SampleFigures | None = None


@dataclass(frozen=True)
class SampleFigures:
    """What a stopping report reads from one run's samples from its stop signal on.

    Attributes:
        rest_times: When each joint's speed falls below the rest speed for good [s]
            (:func:`_rest_times`; NaN: still moving at the end), shape (n,).
        distance: The tool frame's straight-line distance from its first sample to its last [m].
        length: The length of its path [m].
        peak_speed: Its largest speed [m/s].
        reach: Its largest distance from the first sample [m].
    """

    rest_times: np.ndarray
    distance: float
    length: float
    peak_speed: float
    reach: float


def sample_figures(
    results: Sequence[SimulationResult],
    rows: Sequence[int],
    path: np.ndarray,
    speed: np.ndarray,
) -> list[SampleFigures]:
    """The :class:`SampleFigures` of many runs at once, each from its own samples only.

    Args:
        results: The runs.
        rows: Each run's signal row (:func:`signal_row`).
        path: The tool frame's origins [m] at every run's samples from its signal row on,
            stacked in the runs' order, shape (S, 3).
        speed: Its speeds there [m/s], shape (S,).

    Each figure is formed sample by sample over the stack (the same products as run by run,
    so the same bits) and reduced per run: maxima by segment, a path's length by its own
    sum. They do not depend on which runs are computed together.
    """
    counts = np.array([len(r.t) - i for r, i in zip(results, rows, strict=True)])
    firsts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int)
    lasts = firsts + counts - 1
    t = np.concatenate([r.t[i:] for r, i in zip(results, rows, strict=True)])
    v = np.concatenate([r.v[i:] for r, i in zip(results, rows, strict=True)])
    rest = np.array(
        [r.stop.rest_speed if r.stop is not None else DEFAULT_REST_SPEED for r in results]
    )
    rest_times = _rest_times(t, v, rest, firsts, counts)
    away = np.linalg.norm(path - np.repeat(path[firsts], counts, axis=0), axis=1)
    reach, peak = np.maximum.reduceat(away, firsts), np.maximum.reduceat(speed, firsts)
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
    return [
        SampleFigures(
            rest_times[r],
            float(away[lasts[r]]),
            float(np.sum(steps[firsts[r] : lasts[r]])),
            float(peak[r]),
            float(reach[r]),
        )
        for r in range(len(results))
    ]


def signal_row(result: SimulationResult) -> int:
    """The first sample at or after the stop signal (0 for a run without a stop)."""
    t_signal = result.stop.t if result.stop is not None else 0.0
    return int(np.argmax(result.t >= t_signal))


def tool_motion(robot: Robot, result: SimulationResult, tool_frame: str | None) -> ToolMotion:
    """The :class:`ToolMotion` of one run, from its stop signal on."""
    i0 = signal_row(result)
    return _motion(robot, result.q[i0:], result.v[i0:], tool_frame)


def _motion(robot: Robot, q: np.ndarray, v: np.ndarray, tool_frame: str | None) -> ToolMotion:
    """The :class:`ToolMotion` of samples (q [rad], v [rad/s]), shape (k, n)."""
    placements, path, speed = frame_motion(robot, q, v, tool_frame)
    return ToolMotion(placements, path, speed)


def tool_motions(
    runs: Sequence[tuple[Robot, SimulationResult, str | None]],
) -> list[ToolMotion]:
    """The :class:`ToolMotion` of many runs (robot, result, tool frame), in their order.

    Runs whose robots place their joints alike (:func:`~vtm_pin.physics.kinematics.
    kinematics_key`: payload variants of one arm) and whose tool frames sit alike are computed
    together: their samples stacked, one pass of the forward kinematics for all
    (:func:`~vtm_pin.physics.kinematics.frame_motion`; a study case has ~80 samples, where one
    pass per case costs mostly its fixed overhead), and their :class:`SampleFigures` with it.
    The kinematics are sample by sample, so each run's motion is its own pass's to round-off. So
    are what a report reads at the signal (the tool's Jacobian, the arm's points' speeds)
    and the arm's largest displacement (:attr:`ToolMotion.arm`), for the runs whose robots
    share their arm points. Those three are left None for a model whose joints the NumPy
    kinematics do not take.
    """
    rows = [signal_row(result) for _, result, _ in runs]
    groups: dict[tuple[object, ...], list[int]] = {}
    for r, (robot, _, frame) in enumerate(runs):
        tool = robot.model.frames[robot.model.getFrameId(frame or robot.tool_frame)]
        key = (kinematics_key(robot), int(tool.parentJoint), tool.placement.translation.tobytes())
        groups.setdefault(key, []).append(r)
    parts: list[tuple[Any, ...]] = [()] * len(runs)  # each run's motion but its arm's
    for members in groups.values():
        robot, _, frame = runs[members[0]]
        q = np.concatenate([runs[r][1].q[rows[r] :] for r in members])
        v = np.concatenate([runs[r][1].v[rows[r] :] for r in members])
        stacked = _motion(robot, q, v, frame)
        (R, p), path, speed = stacked.placements, stacked.path, stacked.speed
        ends = np.cumsum([len(runs[r][1].t) - rows[r] for r in members])
        firsts = ends - [len(runs[r][1].t) - rows[r] for r in members]
        norms = None
        if cached_chain(robot) is not None:
            norms = tool_column_norms(robot, (R[firsts], p[firsts]), frame)
        figures = sample_figures(
            [runs[r][1] for r in members], [rows[r] for r in members], path, speed
        )
        for c, (r, first, stop) in enumerate(zip(members, firsts, ends, strict=True)):
            mine = slice(int(first), int(stop))
            column = None if norms is None else norms[c]
            parts[r] = ((R[mine], p[mine]), path[mine], speed[mine], column, figures[c])
    arms, speeds = _at_the_arm([part[0] for part in parts], runs, rows)
    return [
        ToolMotion(placements, path, speed, arm, arm_speed, column, figures)
        for (placements, path, speed, column, figures), arm, arm_speed in zip(
            parts, arms, speeds, strict=True
        )
    ]


def _at_the_arm(
    placements: Sequence[tuple[np.ndarray, np.ndarray]],
    runs: Sequence[tuple[Robot, SimulationResult, str | None]],
    rows: Sequence[int],
) -> tuple[list[ArmDisplacement | None], list[float | None]]:
    """Each run's arm's largest displacement and fastest point's speed at the signal [m/s].

    From the joints' ``placements`` at its samples from the signal on; those of the runs
    that share one set of arm points together; None for a model whose joints the NumPy
    kinematics do not take.
    """
    groups: dict[int, list[int]] = {}
    points = {}
    for r, (robot, _, _) in enumerate(runs):
        if cached_chain(robot) is None:
            continue
        mine = sample_arm_points(robot)
        points[id(mine)] = mine
        groups.setdefault(id(mine), []).append(r)
    arms: list[ArmDisplacement | None] = [None] * len(runs)
    speeds: list[float | None] = [None] * len(runs)
    for key, members in groups.items():
        found = max_displacements(points[key], [placements[r] for r in members])
        R = np.stack([placements[r][0][0] for r in members])
        p = np.stack([placements[r][1][0] for r in members])
        v = np.stack([runs[r][1].v[rows[r]] for r in members])
        fastest = fastest_point_speeds(runs[members[0]][0], points[key], (R, p), v)
        for r, arm, speed in zip(members, found, fastest, strict=True):
            arms[r], speeds[r] = arm, float(speed)
    return arms, speeds


def compute_stopping_report(
    robot: Robot,
    result: SimulationResult,
    brakes: tuple[Brake, ...] = (),
    tool_frame: str | None = None,
    motion: ToolMotion | None = None,
) -> StoppingReport:
    """Derive the stopping report of a simulated stop (or of a run with prescribed locks).

    Args:
        robot: The robot simulated.
        result: The simulation.
        brakes: Its brakes (for the static limits of the holding margin).
        tool_frame: Frame to follow; the robot's tool frame by default.
        motion: The run's :class:`ToolMotion` (of this robot and tool frame), if it was
            computed with other runs' (:func:`tool_motions`); computed here if None.

    Raises:
        ValueError: ``motion`` has not one sample per sample of the run from its signal on.
    """
    t_signal = result.stop.t if result.stop is not None else 0.0
    i0 = signal_row(result)
    v = result.v[i0:]
    # The joints' placements from the signal on, once: the tool's path here, the arm's points
    # in stop_figures (kept in the report).
    if motion is None:
        motion = tool_motion(robot, result, tool_frame)
    elif len(motion.path) != len(v):
        raise ValueError(f"motion has {len(motion.path)} samples; the run {len(v)} from its signal")
    path, speed = motion.path, motion.speed
    rest_speed = result.stop.rest_speed if result.stop is not None else DEFAULT_REST_SPEED
    figures = motion.figures or sample_figures([result], [i0], path, speed)[0]
    stop_time = figures.rest_times - t_signal
    all_stopped = float(np.max(stop_time)) if np.isfinite(stop_time).all() else float("nan")
    return StoppingReport(
        signal_time=t_signal,
        names=tuple(robot.joints),
        stop_times=stop_time,
        stop_angles=result.q[-1] - result.q[i0],
        rest_speed=rest_speed,
        end_time=float(result.t[-1]),
        all_stopped_time=all_stopped,
        tool_frame=tool_frame or robot.tool_frame,
        tcp_path=path,
        tcp_distance=figures.distance,
        tcp_path_length=figures.length,
        tcp_peak_speed=figures.peak_speed,
        tcp_reach=figures.reach,
        placements=motion.placements,
        motion=motion,
        source=(robot, result, tuple(brakes)),
    )


def _event_figures(
    robot: Robot, result: SimulationResult, t_signal: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per joint: latch time [s], peak surge [rad/s], lock impulse [N m s] (:class:`JointStop`)."""
    n = robot.nv
    last = result.modes[-1]
    locked_for_good = (last == BrakeMode.STUCK) | (last == BrakeMode.LOCKED) | ~result.free[-1]
    index = {name: j for j, name in enumerate(robot.joints)}
    latch_time = np.full(n, np.nan)
    lock_impulse = np.zeros(n)
    events = result.events
    if not events:
        return latch_time, np.zeros(n), lock_impulse
    held = np.zeros((len(events), n), dtype=bool)  # locked after each event
    joints, impulses = [], []
    for e, event in enumerate(events):
        for name in event.lock:
            j = index[name]
            if locked_for_good[j]:
                latch_time[j] = max(0.0, event.t - t_signal)  # locked before: at once
        for name in event.locked_before + event.lock:
            held[e, index[name]] = True
        for label, impulse in zip(event.rows, -event.transition.Lambda, strict=True):
            if label.kind is RowKind.JOINT:
                joints.append(index[label.name])
                impulses.append(impulse)
    np.add.at(lock_impulse, joints, impulses)  # one after the other, in event order
    v_plus = np.array([event.v_plus for event in events])
    v_minus = np.array([event.v_minus for event in events])
    gain = np.where(held, -np.inf, np.abs(v_plus) - np.abs(v_minus))  # of the joints left free
    return latch_time, np.maximum(0.0, np.max(gain, axis=0)), lock_impulse


def _holding_figures(
    robot: Robot, result: SimulationResult, brakes: tuple[Brake, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """Per joint: peak holding torque and holding margin [N m] (see :class:`JointStop`)."""
    n = robot.nv
    hold = result.holding
    known = np.isfinite(hold)
    size = np.abs(hold)
    locked = ~result.free & known
    peak_hold = np.where(
        locked.any(axis=0), np.max(np.where(locked, size, -np.inf), axis=0), np.nan
    )
    margin = np.full(n, np.nan)
    stuck = (result.modes == BrakeMode.STUCK) & known
    ever = stuck.any(axis=0)
    engaging = (BrakeEventKind.ENGAGE, BrakeEventKind.LOCK)
    columns, limits = [], []  # joints whose static limit is one number (no ramp)
    for brake in brakes:
        j = robot.joint_index(brake.joint)
        ratio = float(robot.gear_ratio[j])
        if brake.ideal:
            margin[j] = np.inf
        elif not ever[j]:
            continue
        elif brake.friction.ramp == 0.0:  # full normal force from engagement: one limit
            columns.append(j)
            limits.append(brake.static(0.0, ratio))
        else:
            times = [
                e.t for e in result.brake_events if e.kind in engaging and e.joint == brake.joint
            ]
            t0 = times[-1]  # its last engagement
            rows = stuck[:, j]
            ramp = np.array([brake.static(t - t0, ratio) for t in result.t[rows]])
            margin[j] = float(np.min(ramp - size[rows, j]))
    if columns:
        spare = np.where(stuck[:, columns], np.array(limits) - size[:, columns], np.inf)
        margin[columns] = np.min(spare, axis=0)
    return peak_hold, margin


def rest_times(t: np.ndarray, v: np.ndarray, rest_speed: float) -> np.ndarray:
    """Per column of ``v`` [rad/s], shape (T, n): when |v| falls below ``rest_speed`` for good.

    As a stopping report has them (:attr:`SampleFigures.rest_times`) [s]; NaN where it does not
    by the last sample. ``t``: the samples' times [s], shape (T,).
    """
    one = np.zeros(1, dtype=int)
    return _rest_times(t, v, np.array([rest_speed]), one, np.array([len(t)]))[0]


def _rest_times(
    t: np.ndarray, v: np.ndarray, rest_speed: np.ndarray, firsts: np.ndarray, counts: np.ndarray
) -> np.ndarray:
    """Per run and joint: when |v| falls below the run's ``rest_speed`` for good [s] (NaN: not yet).

    Runs' samples stacked (times ``t`` [s], rates ``v`` [rad/s], shape (S, n)), run r's
    ``counts[r]`` of them from row ``firsts[r]``; ``rest_speed`` [rad/s] per run. Between the
    last sample above and the next one, |v| is interpolated linearly; at an event (two samples
    at one time) the speed drops at the event time. Shape (runs, n).
    """
    speed = np.abs(v)
    above = speed > np.repeat(rest_speed, counts)[:, None]
    last = np.maximum.reduceat(np.where(above, np.arange(len(t))[:, None], -1), firsts, axis=0)
    out = np.where(last >= 0, np.nan, t[firsts][:, None])
    run, col = np.nonzero(
        (last >= 0) & (last < (firsts + counts - 1)[:, None])
    )  # at rest by the end
    a = last[run, col]  # the last sample above
    span = t[a + 1] - t[a]
    slope = speed[a, col] - speed[a + 1, col]
    ends = span > 0.0
    fraction = (speed[a, col][ends] - rest_speed[run][ends]) / slope[ends]
    out[run, col] = t[a]
    out[run[ends], col[ends]] = t[a][ends] + fraction * span[ends]
    return out
