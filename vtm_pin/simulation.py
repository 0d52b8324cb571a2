"""Hybrid simulation: integrate to the next event, apply the transition, continue.

Time events (prescribed locks, the stop signal, brake engagement, ends of ramps) are hit
exactly: every integration interval ends on the next one. State events (a sliding joint's rate
reaching zero, a stuck joint's holding torque reaching its static limit) are located by the
integrator on its own solution. Each lock, prescribed or by sticking, goes through the chosen
transition rule with J1 the joints already locked and J2 the ones locking now.
"""

from __future__ import annotations

import heapq
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .brakes import Brake, BrakeMode, mode_of_load, mode_of_motion
from .constraints import check_independent, lock_jacobian
from .dynamics import compute_energy, compute_M
from .exceptions import SimulationError
from .holonomic import FrameConstraint, compute_kinematics, project_initial_state, stack
from .integrators import Integrator, Rhs, Segment
from .phase import DriveLaw, Phase
from .robot import Robot
from .stop import Stop
from .topology import Topology
from .transitions import TRANSITIONS, TransitionResult

#: Default Baumgarte gains (alpha, beta) [1/s] for frame constraints between events.
DEFAULT_BAUMGARTE = (10.0, 10.0)


@dataclass(frozen=True)
class LockEvent:
    """Constraints that activate ideally (instantly) at a given time.

    Attributes:
        t: Event time [s].
        lock: Names of the joints that lock at ``t``.
        activate: Frame constraints (loop closures, dockings) that activate at ``t``; a
            docking without target holds the frame where it is at ``t``.
    """

    t: float
    lock: tuple[str, ...]
    activate: tuple[FrameConstraint, ...] = ()


@dataclass(frozen=True)
class EventRecord:
    """A lock: joints added to the locked set, with the transition applied.

    Attributes:
        t: Event time [s].
        lock: Joints newly locked.
        locked_before: Joints already locked before the event (the persistent constraints J1).
        q: Configuration at the event [rad].
        v_minus: Velocity just before [rad/s].
        transition: The transition result (v_plus, Lambda, energy loss, momenta).
        kind: ``"lock"`` (prescribed lock or ideal brake), ``"stick"`` (a sliding brake
            came to rest and holds) or ``"activate"`` (frame constraints, maybe with locks).
        activate: Names of the frame constraints activated.
        rows: Label of each row of J+ = [J1; J2] (``"lock joint2"``, ``"dock.x"``), the
            order of ``transition.Lambda``.
    """

    t: float
    lock: tuple[str, ...]
    locked_before: tuple[str, ...]
    q: np.ndarray
    v_minus: np.ndarray
    transition: TransitionResult
    kind: str = "lock"
    activate: tuple[str, ...] = ()
    rows: tuple[str, ...] = ()

    @property
    def v_plus(self) -> np.ndarray:
        """Velocity just after [rad/s]."""
        return self.transition.v_plus


@dataclass(frozen=True)
class BrakeEvent:
    """A change of one brake's state.

    Attributes:
        t: Time [s].
        joint: Joint name.
        kind: ``"engage"``, ``"stick"``, ``"reverse"`` (reached v = 0 but could not hold),
            ``"slip"`` (stuck joint broke loose) or ``"lock"`` (ideal brake).
        v: The joint's rate at the event as integrated, before it is set to 0 [rad/s].
        holding_torque: Torque needed to hold the joint at the event [N m] (NaN if unused).
        static_torque: Static limit at the event, joint side [N m] (NaN if unused).
    """

    t: float
    joint: str
    kind: str
    v: float
    holding_torque: float = float("nan")
    static_torque: float = float("nan")


@dataclass(frozen=True)
class SimulationResult:
    """A simulated motion with its events.

    Attributes:
        joints: Joint names, the columns of ``q`` and ``v``.
        t: Sample times [s], shape (k,). An event time appears twice: before and after it.
        q: Joint positions [rad], shape (k, n).
        v: Joint velocities [rad/s], shape (k, n).
        free: Which joints are free at each sample, shape (k, n), bool.
        modes: :class:`BrakeMode` code per joint and sample, shape (k, n).
        brake_work: Work dissipated by sliding brakes since t = 0 [J], shape (k,).
        drive_work: Work done by the drives since t = 0 [J], shape (k,).
        brake_impulse: Friction impulse each brake delivered to its joint [N m s], shape (n,).
        holding: Torque each lock exerts to hold its joint [N m], shape (k, n); NaN where the
            joint is free, and everywhere in runs without brakes (not computed).
        drift: Constraint drift of the active frame constraints per sample, shape (k, 2):
            max |h| [m or rad] and max |J v| [m/s or rad/s]; NaN where none is active.
        events: One record per lock, in time order.
        brake_events: Brake state changes, in time order.
        transition: Name of the transition rule used.
        integrator: Name of the integrator used.
        rhs_evals: Right-hand-side evaluations.
        steps: Integrator steps.
        wall_time: Seconds spent in the simulation loop [s].
        stop: The emergency stop simulated, if any.
    """

    joints: tuple[str, ...]
    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    free: np.ndarray
    modes: np.ndarray
    brake_work: np.ndarray
    drive_work: np.ndarray
    brake_impulse: np.ndarray
    holding: np.ndarray
    drift: np.ndarray
    events: tuple[EventRecord, ...]
    brake_events: tuple[BrakeEvent, ...]
    transition: str
    integrator: str
    rhs_evals: int
    steps: int
    wall_time: float
    stop: Stop | None = None

    def q_at(self, times: Sequence[float] | np.ndarray) -> np.ndarray:
        """Joint positions at the given times [s], linearly interpolated between samples.

        Exact at sample times; q is continuous across events, so an event time is well
        defined. Returns shape (len(times), n) [rad].

        Raises:
            SimulationError: A time lies outside the simulated interval.
        """
        times = np.atleast_1d(np.asarray(times, dtype=float))
        outside = times[(times < self.t[0]) | (times > self.t[-1])]
        if outside.size:
            raise SimulationError(
                f"t = {outside[0]} s is outside the simulated [{self.t[0]}, {self.t[-1]}] s"
            )
        return np.column_stack([np.interp(times, self.t, col) for col in self.q.T])


class _Hybrid:
    """Mutable state of the hybrid loop (kept out of the public result)."""

    def __init__(
        self,
        robot: Robot,
        q: np.ndarray,
        v: np.ndarray,
        brakes: Sequence[Brake],
        stop: Stop | None,
        rule: str,
    ) -> None:
        self.robot = robot
        n = robot.nv
        self.q, self.v = q, v
        self.extras = np.zeros(2 + n)
        self.locked: list[int] = []
        self.modes = [BrakeMode.FREE] * n
        self.brakes = {robot.joint_index(b.joint): b for b in brakes}
        self.engaged: dict[int, float] = {}
        self.stop = stop
        self.drive = DriveLaw.OFF if stop is None else DriveLaw.HOLD
        self.drive_on = np.full(n, stop is not None)
        self.v_signal: np.ndarray | None = None
        self.rule = TRANSITIONS[rule]
        self.rule_name = rule
        self.frames: list[FrameConstraint] = []
        self.baumgarte = (0.0, 0.0)
        self.data = robot.model.createData()
        self.events: list[EventRecord] = []
        self.brake_events: list[BrakeEvent] = []
        self._v_event: dict[int, float] = {}  # rates of the resting joints before zeroing
        self.phase = self.new_phase()

    def new_phase(self, locked: Sequence[int] | None = None) -> Phase:
        topology = Topology(self.robot, self.locked if locked is None else locked, self.q)
        return Phase(
            self.robot,
            topology,
            self.modes,
            self.brakes,
            self.engaged,
            self.drive,
            self.drive_on,
            self.stop,
            self.v_signal,
            tuple(self.frames),
            self.baumgarte,
        )

    def lock(
        self,
        t: float,
        joints: Sequence[int],
        kind: str,
        frames: Sequence[FrameConstraint] = (),
    ) -> None:
        """Apply the transition rule for ``joints`` locking and ``frames`` activating at ``t``.

        J1 stacks the locked joints' rows and the active frame constraints; J2 the new ones.
        """
        names = self.robot.joints
        for i in joints:
            if i in self.locked:
                raise SimulationError(f"Joint '{names[i]}' is locked twice (again at t = {t} s)")
        model, n = self.robot.model, self.robot.nv
        frames = [f.latch(model, self.data, self.q) for f in frames]
        if (frames or self.frames) and self.rule_name == "naive":
            raise SimulationError("The naive rule is defined for joint locks only")
        if self.frames or frames:
            compute_kinematics(model, self.data, self.q, self.v)
        _, F1, _ = stack(tuple(self.frames), model, self.data)
        _, F2, _ = stack(tuple(frames), model, self.data)
        J1 = np.vstack([lock_jacobian(n, self.locked), F1])
        J2 = np.vstack([lock_jacobian(n, joints), F2])
        labels = [f"lock {names[i]}" for i in [*self.locked, *joints]]
        labels = (
            labels[: len(self.locked)]
            + [f"{f.name}.{a}" for f in self.frames for a in f.axes]
            + labels[len(self.locked) :]
            + [f"{f.name}.{a}" for f in frames for a in f.axes]
        )
        check_independent(np.vstack([J1, J2]), labels)
        M = compute_M(model, self.data, self.q)
        result = self.rule(M, J1, J2, self.v)
        self.events.append(
            EventRecord(
                t=t,
                lock=tuple(names[i] for i in joints),
                locked_before=tuple(names[i] for i in self.locked),
                q=self.q.copy(),
                v_minus=self.v.copy(),
                transition=result,
                kind="activate" if frames else kind,
                activate=tuple(f.name for f in frames),
                rows=tuple(labels),
            )
        )
        self.locked = self.locked + list(joints)
        self.frames = self.frames + frames
        self.v = result.v_plus.copy()
        self.v[self.locked] = 0.0

    def engage(self, t: float, i: int, ideal_locks: list[int]) -> None:
        """Brake ``i`` engages: its drive goes off, and it locks (ideal) or starts braking.

        A joint moving faster than :data:`vtm_pin.brakes.REST_RATE` starts sliding against
        its motion; a joint at rest is left to :meth:`settle`, which decides stick or slip
        once every event of this instant has been applied.
        """
        brake = self.brakes[i]
        name = self.robot.joints[i]
        self.drive_on[i] = False
        self.engaged[i] = t
        if i in self.locked:
            return
        if brake.ideal:
            self.modes[i] = BrakeMode.LOCKED
            ideal_locks.append(i)
            self.brake_events.append(BrakeEvent(t, name, "lock", float(self.v[i])))
            return
        self.brake_events.append(BrakeEvent(t, name, "engage", float(self.v[i])))
        self.modes[i] = mode_of_motion(float(self.v[i])) or BrakeMode.FREE

    def settle(self, t: float, due: Sequence[int] = ()) -> None:
        """Bring every engaged brake's mode in line with the state at ``t``; build the phase.

        One rule for every braked joint (Modelica's ``Brake``), applied to all of them at
        once, as an active set for Coulomb friction:

        1. A sliding joint whose rate a jump reversed slides the other way.
        2. Every joint at rest (engaged at rest, slid to rest, or stuck) is held; while some
           holding torque exceeds its static limit, the worst-loaded joint (largest
           |hold| / limit) is released to slide in the direction of its load, and the
           others are held again. Those still held stick, in one consistent lock.
        3. A released joint must then accelerate the way it slides, now that the others
           slide too; if it would not, it slides the other way, or, if neither direction
           is consistent, its static friction holds it and it sticks.

        A released joint stays released at this instant, so the decisions end.

        Args:
            t: Time [s].
            due: Joints whose state event fired now (reached v = 0, or hit the static
                limit): a stuck one among them is released even within round-off of it.
        """
        self._follow_reversals(t)
        resting = self._resting()
        if resting:
            forced = {i for i in due if i in self.locked}  # at the static limit now
            released = self._hold_or_release(t, resting, forced)
            self._check_released(t, released)
        self.phase = self.new_phase()

    def _hold_or_release(self, t: float, resting: list[int], forced: set[int]) -> list[int]:
        """Step 2 of :meth:`settle`: release the worst-loaded joints, lock the rest."""
        limits = {i: self.brakes[i].static(t - self.engaged[i]) for i in resting}
        released = []
        while True:
            trial = self.new_phase(sorted({*self.locked, *resting}))
            hold = trial.holding_torque(t, trial.pack(self.q, self.v, self.extras))
            i = _worst_loaded(resting, hold, limits, forced)
            if i is None:
                break
            self._release(t, i, float(hold[i]), limits[i])
            resting.remove(i)
            forced.discard(i)
            released.append(i)
        self._stick(t, [i for i in resting if i not in self.locked], hold, limits)
        return released

    def _check_released(self, t: float, released: list[int]) -> None:
        """Step 3 of :meth:`settle`: flip or stick released joints that would not slide."""
        for _ in range(2 * len(released)):
            wrong = self._against_motion(t, released)
            if wrong is None:
                return
            self.modes[wrong] = mode_of_motion(-self.modes[wrong].sign) or BrakeMode.FREE
            if self._against_motion(t, [wrong]) is None:
                name = self.robot.joints[wrong]
                self.brake_events.append(BrakeEvent(t, name, "reverse", 0.0))
                continue
            trial = self.new_phase([*self.locked, wrong])
            hold = trial.holding_torque(t, trial.pack(self.q, self.v, self.extras))
            limit = self.brakes[wrong].static(t - self.engaged[wrong])
            self._stick(t, [wrong], hold, {wrong: limit})

    def _against_motion(self, t: float, joints: Sequence[int]) -> int | None:
        """The first of ``joints`` (free, sliding from rest) accelerating against its mode."""
        phase = self.new_phase()
        k = phase.k
        a = np.zeros(self.robot.nv)
        a[phase.topology.free] = phase.rhs(t, phase.pack(self.q, self.v, self.extras))[k : 2 * k]
        for i in joints:
            if i not in self.locked and a[i] * self.modes[i].sign < 0.0:
                return i
        return None

    def _stick(
        self, t: float, joints: Sequence[int], hold: np.ndarray, limits: Mapping[int, float]
    ) -> None:
        """Joints at rest whose brakes hold them stick: one consistent lock."""
        for i in joints:
            name = self.robot.joints[i]
            self.brake_events.append(
                BrakeEvent(t, name, "stick", self._v_event[i], float(hold[i]), limits[i])
            )
            self.modes[i] = BrakeMode.STUCK
        if joints:
            self.lock(t, joints, "stick")

    def _follow_reversals(self, t: float) -> None:
        """Sliding joints whose rate has the other sign (after a jump) slide the other way."""
        for i in self.engaged:
            mode, moving = self.modes[i], mode_of_motion(float(self.v[i]))
            if i not in self.locked and moving is not None and mode is not moving:
                if mode.sliding or mode is BrakeMode.FREE:
                    self.modes[i] = moving
                    self.brake_events.append(
                        BrakeEvent(t, self.robot.joints[i], "reverse", float(self.v[i]))
                    )

    def _resting(self) -> list[int]:
        """Braked joints at rest that need the stick/slip decision (their rates set to 0).

        Stuck joints, and engaged joints at rest (|v| <= REST_RATE) that are free or
        sliding; not ideal brakes, nor joints locked by a prescribed lock.
        """
        resting = []
        self._v_event.clear()
        for i in sorted(self.engaged):
            mode = self.modes[i]
            if mode is BrakeMode.LOCKED or (i in self.locked and mode is not BrakeMode.STUCK):
                continue
            at_rest = mode_of_motion(float(self.v[i])) is None
            if mode is BrakeMode.STUCK or at_rest:
                resting.append(i)
                self._v_event[i] = float(self.v[i])
                self.v[i] = 0.0
        return resting

    def _release(self, t: float, i: int, hold: float, limit: float) -> None:
        """Joint ``i`` cannot be held: it slides in the direction of its load."""
        if i in self.locked:
            kind = "slip"
            self.locked = [j for j in self.locked if j != i]
        else:
            kind = "reverse" if self.modes[i].sliding else "start"
        self.modes[i] = mode_of_load(hold)
        name = self.robot.joints[i]
        self.brake_events.append(BrakeEvent(t, name, kind, self._v_event[i], hold, limit))


def _worst_loaded(
    resting: Sequence[int], hold: np.ndarray, limits: Mapping[int, float], forced: set[int]
) -> int | None:
    """The held joint to release first: a forced one, else the largest |hold| / limit > 1."""
    if forced:
        return min(forced)
    worst, ratio = None, 1.0
    for i in resting:
        if abs(hold[i]) > limits[i]:
            r = math.inf if limits[i] == 0.0 else abs(hold[i]) / limits[i]
            if worst is None or r > ratio:
                worst, ratio = i, r
    return worst


def simulate(
    robot: Robot,
    q0: np.ndarray,
    v0: np.ndarray,
    duration: float,
    events: Sequence[LockEvent],
    integrator: Integrator,
    transition: str = "kkt",
    brakes: Sequence[Brake] = (),
    stop: Stop | None = None,
    constraints: Sequence[FrameConstraint] = (),
    baumgarte: tuple[float, float] = DEFAULT_BAUMGARTE,
    progress: Callable[[float], None] | None = None,
) -> SimulationResult:
    """Simulate the robot from (q0, v0) with prescribed locks, and brakes after a stop signal.

    Without a stop no joint torque acts (drives off). With a stop, the drives hold the joint
    rates constant until the signal, then act as its category says, and each brake engages
    after its delay (see :mod:`vtm_pin.stop` and :mod:`vtm_pin.brakes`).

    Args:
        robot: The robot.
        q0: Initial joint positions [rad], shape (n,).
        v0: Initial joint velocities [rad/s], shape (n,).
        duration: End time [s], > 0.
        events: Ideal lock events with 0 <= t <= duration; a joint may lock only once.
        integrator: How to integrate between events.
        transition: Name in :data:`vtm_pin.transitions.TRANSITIONS`.
        brakes: One brake per braked joint; they act only after a stop signal.
        stop: The emergency stop, if any.
        constraints: Frame constraints active from t = 0 (loop closures, dockings); q0 and
            v0 are projected onto them first, with a :class:`VtmWarning` if that moves them
            by more than 1e-6.
        baumgarte: Gains (alpha, beta) [1/s] of the Baumgarte stabilisation of the frame
            constraints between events; (0, 0) integrates the bare index-1 equations.
        progress: Called with the simulated time t [s] at every right-hand-side evaluation
            and at the end of every segment, for progress display; it must not change
            anything (the results do not depend on it).

    Returns:
        The sampled motion and event records.

    Raises:
        SimulationError: Bad arguments, or the state became non-finite.
        JointNotFound: An event or brake names an unknown joint.
    """
    _check_arguments(robot, duration, events, transition, brakes, stop, constraints)
    n = robot.nv
    start = time.perf_counter()
    h = _Hybrid(
        robot,
        np.array(q0, dtype=float).reshape(n),
        np.array(v0, dtype=float).reshape(n),
        brakes,
        stop,
        transition,
    )
    h.baumgarte = baumgarte
    if constraints:
        h.frames = [c.latch(robot.model, h.data, h.q) for c in constraints]
        h.q, h.v = project_initial_state(robot, h.q, h.v, h.frames)
        h.phase = h.new_phase()
    queue = _time_events(robot, events, h.brakes, stop, duration)
    trace = _Trace(n, h.extras.size)
    if queue and queue[0][0] <= 0.0:
        trace.add_state(0.0, h)  # the state before the events at t = 0
    rhs_evals = steps = 0
    t = 0.0
    while True:
        # Events due now (t = 0 or a time event just reached) are applied before integrating.
        if _apply_time_events(h, queue, t):
            h.settle(t)
            if t >= duration:
                trace.add_state(t, h)  # the state after the events at t = duration
        if t >= duration:
            break
        t_end = min(queue[0][0], duration) if queue else duration
        phase = h.phase
        segment = integrator.integrate(
            phase.rhs if progress is None else _reporting(phase.rhs, progress),
            t,
            phase.pack(h.q, h.v, h.extras),
            t_end,
            [e.event for e in phase.events],
            n_q=phase.k,
        )
        rhs_evals += segment.rhs_evals
        steps += segment.t.size - 1
        _check_energy(h, phase, segment.y, segment.t, integrator)
        h.q, h.v, h.extras = trace.add_segment(phase, segment, h, bool(brakes))
        t = float(segment.t[-1])
        if progress is not None:
            progress(t)
        if segment.event is not None:
            h.settle(t, due=[phase.events[segment.event].joint])
            if t >= duration:
                trace.add_state(t, h)
    return trace.result(
        robot,
        h,
        integrator=integrator.name,
        rhs_evals=rhs_evals,
        steps=steps,
        wall_time=time.perf_counter() - start,
    )


def _check_arguments(
    robot: Robot,
    duration: float,
    events: Sequence[LockEvent],
    transition: str,
    brakes: Sequence[Brake],
    stop: Stop | None,
    constraints: Sequence[FrameConstraint],
) -> None:
    """Refuse arguments :func:`simulate` cannot run, with a one-line reason."""
    if transition not in TRANSITIONS:
        raise SimulationError(
            f"Unknown transition '{transition}'; allowed: {', '.join(sorted(TRANSITIONS))}"
        )
    if not duration > 0.0:
        raise SimulationError(f"Duration {duration} is not a positive number of seconds")
    for lock_event in events:
        if not 0.0 <= lock_event.t <= duration:
            raise SimulationError(f"Event at t = {lock_event.t} s is outside [0, {duration}] s")
    if brakes and stop is None:
        raise SimulationError("Brakes act only after a stop signal: give a stop")
    activated = list(constraints) + [c for e in events for c in e.activate]
    if brakes and activated:
        raise SimulationError("Brakes together with loop closures or dockings are not supported")
    for constraint in activated:
        constraint.check(robot.model)


def _apply_time_events(
    h: _Hybrid, queue: list[tuple[float, int, int, str, object]], t: float
) -> bool:
    """Apply the time events due at ``t`` (in heap order); whether there were any."""
    ideal: list[int] = []
    frames: list[FrameConstraint] = []
    changed = False
    while queue and queue[0][0] <= t:
        _, _, _, kind, payload = heapq.heappop(queue)
        changed = True
        if kind == "lock":
            assert isinstance(payload, LockEvent)
            ideal.extend(h.robot.joint_indices(payload.lock))
            frames.extend(payload.activate)
        elif kind == "signal":
            assert h.stop is not None
            if h.stop.category == 0:
                h.drive, h.drive_on[:] = DriveLaw.OFF, False
            else:
                h.drive, h.v_signal = DriveLaw.RAMP, h.v.copy()
        elif kind == "brake_signal":
            h.drive_on[[i for i in range(h.robot.nv) if i not in h.brakes]] = False
        elif kind == "engage":
            assert isinstance(payload, int)
            h.engage(t, payload, ideal)
    if ideal or frames:
        h.lock(t, ideal, "lock", frames)
    return changed


class _Trace:
    """The samples of a run, collected block by block (a segment, or one state)."""

    def __init__(self, n: int, n_extras: int) -> None:
        self.n = n
        self.n_extras = n_extras
        self.blocks: dict[str, list[np.ndarray]] = {
            key: [] for key in ("t", "q", "v", "free", "modes", "extras", "hold", "drift")
        }

    def _append(self, **arrays: np.ndarray) -> None:
        for key, value in arrays.items():
            self.blocks[key].append(value)

    def add_state(self, t: float, h: _Hybrid) -> None:
        """One sample of the hybrid state as it is now (before or after events at ``t``)."""
        free = np.ones(self.n, dtype=bool)
        free[h.locked] = False
        self._append(
            t=np.array([t]),
            q=h.q[None].copy(),
            v=h.v[None].copy(),
            free=free[None],
            modes=np.array(h.modes, dtype=np.int8)[None],
            extras=h.extras[None].copy(),
            hold=np.full((1, self.n), np.nan),
            drift=np.full((1, 2), np.nan),
        )

    def add_segment(
        self, phase: Phase, segment: Segment, h: _Hybrid, holding: bool
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Record a segment; returns the full (q, v, extras) at its end."""
        n, k, size = self.n, phase.k, segment.t.size
        topology = phase.topology
        q = np.empty((size, n))
        v = np.zeros((size, n))
        q[:, topology.locked] = topology.q_locked
        q[:, topology.free] = segment.y[:, :k]
        v[:, topology.free] = segment.y[:, k : 2 * k]
        mask = np.zeros(n, dtype=bool)
        mask[topology.free] = True
        hold = np.full((size, n), np.nan)
        if holding and topology.locked:
            locked = list(topology.locked)
            for r in range(size):
                hold[r, locked] = phase.holding_torque(segment.t[r], segment.y[r])[locked]
        extras = phase.unpack_extras(segment.y, h.extras)
        self._append(
            t=segment.t,
            q=q,
            v=v,
            free=np.broadcast_to(mask, (size, n)),
            modes=np.broadcast_to(np.array(h.modes, dtype=np.int8), (size, n)),
            extras=extras,
            hold=hold,
            drift=phase.constraint_drift(segment.y),
        )
        return q[-1].copy(), v[-1].copy(), extras[-1].copy()

    def result(
        self,
        robot: Robot,
        h: _Hybrid,
        *,
        integrator: str,
        rhs_evals: int,
        steps: int,
        wall_time: float,
    ) -> SimulationResult:
        """The collected samples and the events as a :class:`SimulationResult`."""
        rows = {key: np.concatenate(blocks) for key, blocks in self.blocks.items()}
        work = rows["extras"]
        return SimulationResult(
            joints=robot.joints,
            t=rows["t"],
            q=rows["q"],
            v=rows["v"],
            free=rows["free"],
            modes=rows["modes"],
            brake_work=work[:, 0],
            drive_work=work[:, 1],
            brake_impulse=work[-1, 2:].copy(),
            holding=rows["hold"],
            drift=rows["drift"],
            events=tuple(h.events),
            brake_events=tuple(h.brake_events),
            transition=h.rule_name,
            integrator=integrator,
            rhs_evals=rhs_evals,
            steps=steps,
            wall_time=wall_time,
            stop=h.stop,
        )


#: Largest energy-balance error of one interval, as a fraction of the energy it moved. A
#: blow-up detector, not an accuracy monitor: the balance residual is in summary.json.
ENERGY_TOLERANCE = 0.1
_ENERGY_SAMPLES = 9  # states per interval at which the energy is evaluated


def _check_energy(
    h: _Hybrid, phase: Phase, y: np.ndarray, t: np.ndarray, integrator: Integrator
) -> None:
    """Raise if an interval started off its new constraints or broke the energy balance.

    A frame constraint activated at the interval's start must hold there (the frames meet, a
    docked frame is at its target): otherwise the error names it and the distance. Between
    events T + V changes only by the brakes' and drives' work; a step far too large makes it
    grow or collapse (or go non-finite) long before anything else is visibly wrong.
    """
    from .holonomic import check_activation  # here: this function is all that imports it

    last = h.events[-1] if h.events else None
    if last is not None and last.activate and last.t == t[0]:
        q_start, _ = phase.topology.merge(y[0, : 2 * phase.k])
        new = [f for f in h.frames if f.name in last.activate]
        check_activation(new, h.robot.model, h.data, q_start, float(t[0]))
    finite = np.all(np.isfinite(y), axis=1)
    if not np.all(finite):
        row = int(np.argmin(finite))
        bad = np.flatnonzero(~np.isfinite(y[row, : 2 * phase.k])) % max(phase.k, 1)
        names = dict.fromkeys(h.robot.joints[phase.topology.free[i]] for i in bad)
        raise SimulationError(
            f"The state of {', '.join(names) or 'the brakes'} became non-finite at "
            f"t = {t[row]:.6g} s with {_settings(integrator)}: the step is too large for "
            "these dynamics; reduce it"
        )
    if phase.k == 0 or not hasattr(integrator, "dt"):
        return  # nothing moves, or an error-controlled method that cannot blow up silently
    energies, works = [], []
    rows = np.unique(np.linspace(0, len(y) - 1, min(len(y), _ENERGY_SAMPLES)).astype(int))
    for row in y[rows]:
        q, v = phase.topology.merge(row[: 2 * phase.k])
        energies.append(compute_energy(h.robot.model, h.data, q, v))
        works.append(phase.unpack_extras(row, h.extras)[:2])
    (t0, v0), (t1, v1) = energies[0], energies[-1]
    brake = works[-1][0] - works[0][0]
    drive = works[-1][1] - works[0][1]
    residual = (t0 + v0) - (t1 + v1) - (brake - drive)
    # Energy moved: the largest kinetic energy and potential change seen, and the work done.
    kinetic = max(e[0] for e in energies)
    potential = max(e[1] for e in energies) - min(e[1] for e in energies)
    moved = max(kinetic, potential, abs(brake), abs(drive))
    if moved > 1e-12 and abs(residual) > ENERGY_TOLERANCE * moved:
        raise SimulationError(
            f"Energy balance broken by {residual:.3g} J ({100 * abs(residual) / moved:.0f} % of "
            f"the energy moved) between t = {t[0]:g} s and {t[-1]:g} s with "
            f"{_settings(integrator)}: the step is too large for these dynamics; reduce it"
        )


def _reporting(rhs: Rhs, progress: Callable[[float], None]) -> Rhs:
    """The right-hand side ``rhs``, telling ``progress`` the time of each evaluation."""

    def f(t: float, y: np.ndarray) -> np.ndarray:
        progress(t)
        return rhs(t, y)

    return f


def _settings(integrator: Integrator) -> str:
    dt = getattr(integrator, "dt", None)
    if dt is not None:
        return f"{integrator.name} dt = {dt:g} s"
    rtol = getattr(integrator, "rtol", float("nan"))
    atol = getattr(integrator, "atol", float("nan"))
    return f"{integrator.name} rtol = {rtol:g}, atol = {atol:g}"


def _time_events(
    robot: Robot,
    events: Sequence[LockEvent],
    brakes: dict[int, Brake],
    stop: Stop | None,
    duration: float,
) -> list[tuple[float, int, int, str, object]]:
    """Heap of (t, order, count, kind, payload); at equal t: signal, engage, lock, kink."""
    items: list[tuple[float, int, str, object]] = []
    for event in events:
        robot.joint_indices(event.lock)  # unknown names fail before the run
        items.append((event.t, 2, "lock", event))
    if stop is not None:
        items.append((stop.t, 0, "signal", None))
        if stop.category == 1:
            assert stop.ramp_time is not None
            items.append((stop.t + stop.ramp_time, 3, "kink", None))
            items.append((stop.brake_signal, 1, "brake_signal", None))
        for i, brake in sorted(brakes.items()):
            t_engage = stop.brake_signal + brake.delay
            items.append((t_engage, 1, "engage", i))
            if brake.ramp > 0.0:
                items.append((t_engage + brake.ramp, 3, "kink", None))
    queue = [
        (t, order, count, kind, payload)
        for count, (t, order, kind, payload) in enumerate(items)
        if t <= duration
    ]
    heapq.heapify(queue)
    return queue
