"""The stopping report: where and when each joint stops, and how hard brakes and gears are hit.

A joint's **stopping time** is the time from the stop signal until its speed falls below the
rest speed (``stop.rest_speed``, default 1e-3 rad/s) for good, as a safety engineer measures
it (ISO 13855's T). It is not the instant the brake latches (sticks, or locks ideally),
which is reported beside it as the **latch time**: in a category-1 stop the drives' ramp ends
the motion before the brakes engage.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.results import RowKind, SimulationResult
from ..physics.brakes import Brake, BrakeEventKind, BrakeMode
from ..physics.kinematics import compute_tool_jacobian, compute_tool_motion
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

    Attributes:
        signal_time: When the stop button was pressed [s].
        joints: One :class:`JointStop` per joint, in model order.
        rest_speed: Speed below which a joint counts as stopped [rad/s].
        end_time: End of the run [s].
        all_stopped_time: Time from the signal until every joint is at rest for good [s]
            (NaN if some joint was still moving at the end: see ``moving``).
        tool_frame: Frame followed.
        tcp_path: Tool-frame positions from the signal on [m], shape (k, 3).
        tcp_distance: Straight-line distance from the signal position to the final one [m].
        tcp_path_length: Length of the swept path after the signal [m].
        tcp_peak_speed: Largest tool-frame speed after the signal [m/s].
        tcp_peak_surge: Largest jump of the tool-frame speed at a lock [m/s].
    """

    signal_time: float
    joints: tuple[JointStop, ...]
    rest_speed: float
    end_time: float
    all_stopped_time: float
    tool_frame: str
    tcp_path: np.ndarray
    tcp_distance: float
    tcp_path_length: float
    tcp_peak_speed: float
    tcp_peak_surge: float

    @property
    def moving(self) -> tuple[str, ...]:
        """Joints still moving (above the rest speed) at the end of the run."""
        return tuple(j.joint for j in self.joints if not j.stopped)


def compute_stopping_report(
    robot: Robot,
    result: SimulationResult,
    brakes: tuple[Brake, ...] = (),
    tool_frame: str | None = None,
) -> StoppingReport:
    """Derive the stopping report of a simulated stop (or of a run with prescribed locks).

    Args:
        robot: The robot simulated.
        result: The simulation.
        brakes: Its brakes (for the static limits of the holding margin).
        tool_frame: Frame to follow; the robot's tool frame by default.
    """
    t_signal = result.stop.t if result.stop is not None else 0.0
    after = result.t >= t_signal
    i0 = int(np.argmax(after))
    n = robot.nv
    locked_for_good = (
        np.isin(result.modes[-1], (BrakeMode.STUCK, BrakeMode.LOCKED)) | ~result.free[-1]
    )

    latch_time = np.full(n, np.nan)
    surge = np.zeros(n)
    lock_impulse = np.zeros(n)
    for event in result.events:
        for name in event.lock:
            j = robot.joint_index(name)
            if locked_for_good[j]:
                latch_time[j] = max(0.0, event.t - t_signal)  # locked before: at once
        for label, impulse in zip(event.rows, -event.transition.Lambda, strict=True):
            if label.kind is RowKind.JOINT:
                lock_impulse[robot.joint_index(label.name)] += impulse
        order = [robot.joint_index(name) for name in event.locked_before + event.lock]
        free_after = [j for j in range(n) if j not in order]
        if free_after:
            gain = np.abs(event.v_plus[free_after]) - np.abs(event.v_minus[free_after])
            surge[free_after] = np.maximum(surge[free_after], gain)

    hold = result.holding
    by_joint = {robot.joint_index(b.joint): b for b in brakes}
    engaging = (BrakeEventKind.ENGAGE, BrakeEventKind.LOCK)
    engaged = {e.joint: e.t for e in result.brake_events if e.kind in engaging}
    peak_hold = np.full(n, np.nan)
    margin = np.full(n, np.nan)
    for j in range(n):
        locked = ~result.free[:, j] & np.isfinite(hold[:, j])
        if locked.any():
            peak_hold[j] = float(np.max(np.abs(hold[locked, j])))
        brake = by_joint.get(j)
        stuck = (result.modes[:, j] == BrakeMode.STUCK) & np.isfinite(hold[:, j])
        if brake is not None and brake.ideal:
            margin[j] = np.inf
        elif brake is not None and stuck.any():
            t0 = engaged[robot.joints[j]]
            ratio = float(robot.gear_ratio[j])
            if brake.friction.ramp == 0.0:  # full normal force from engagement: one limit
                limits = np.full(int(stuck.sum()), brake.static(0.0, ratio))
            else:
                limits = np.array([brake.static(t - t0, ratio) for t in result.t[stuck]])
            margin[j] = float(np.min(limits - np.abs(hold[stuck, j])))

    path, speed = compute_tool_motion(robot, result.q, result.v, tool_frame)
    tcp_surge = 0.0
    events = result.events
    if events:
        jacobians = compute_tool_jacobian(robot, np.array([e.q for e in events]), tool_frame)
        for event, jac in zip(events, jacobians, strict=True):
            jump = np.linalg.norm(jac @ event.v_plus) - np.linalg.norm(jac @ event.v_minus)
            tcp_surge = max(tcp_surge, float(jump))
    rest_speed = result.stop.rest_speed if result.stop is not None else DEFAULT_REST_SPEED
    stop_time = [
        _rest_time(result.t[i0:], result.v[i0:, j], rest_speed) - t_signal for j in range(n)
    ]
    joints = tuple(
        JointStop(
            joint=name,
            stop_time=float(stop_time[j]),
            latch_time=float(latch_time[j]),
            stop_angle=float(result.q[-1, j] - result.q[i0, j]),
            stop_angle_motor=float((result.q[-1, j] - result.q[i0, j]) * robot.gear_ratio[j]),
            peak_surge=float(surge[j]),
            friction_impulse=float(result.brake_impulse[j]),
            lock_impulse=float(lock_impulse[j]),
            peak_holding_torque=float(peak_hold[j]),
            holding_margin=float(margin[j]),
        )
        for j, name in enumerate(robot.joints)
    )
    all_stopped = float(np.max(stop_time)) if np.all(np.isfinite(stop_time)) else float("nan")
    tcp = path[i0:]
    return StoppingReport(
        signal_time=t_signal,
        joints=joints,
        rest_speed=rest_speed,
        end_time=float(result.t[-1]),
        all_stopped_time=all_stopped,
        tool_frame=tool_frame or robot.tool_frame,
        tcp_path=tcp,
        tcp_distance=float(np.linalg.norm(tcp[-1] - tcp[0])),
        tcp_path_length=float(np.sum(np.linalg.norm(np.diff(tcp, axis=0), axis=1))),
        tcp_peak_speed=float(np.max(speed[i0:])),
        tcp_peak_surge=tcp_surge,
    )


def _rest_time(t: np.ndarray, v: np.ndarray, rest_speed: float) -> float:
    """When |v| falls below ``rest_speed`` for good [s]; NaN if it is above at the end.

    Between the last sample above and the next one, |v| is interpolated linearly; at an
    event (two samples at one time) the speed drops at the event time.
    """
    speed = np.abs(v)
    above = np.flatnonzero(speed > rest_speed)
    if above.size == 0:
        return float(t[0])
    a = int(above[-1])
    if a == speed.size - 1:
        return float("nan")
    span = t[a + 1] - t[a]
    if span <= 0.0:
        return float(t[a])
    fraction = (speed[a] - rest_speed) / (speed[a] - speed[a + 1])
    return float(t[a] + fraction * span)
