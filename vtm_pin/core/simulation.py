"""Hybrid simulation: integrate to the next event, apply the transition, continue.

Time events (prescribed locks, the stop signal, brake engagement, ends of ramps) are hit
exactly: every integration interval ends on the next one. State events (a sliding joint's rate
reaching zero, a stuck joint's holding torque reaching its static limit) are located by the
integrator on its own solution. Each lock, prescribed or by sticking, goes through the chosen
transition rule with J1 the joints already locked and J2 the ones locking now.
"""

from __future__ import annotations

import dataclasses
import functools
import heapq
import time
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, NamedTuple

import numpy as np
import pinocchio as pin

from ..exceptions import SimulationError
from ..numerics.constraints import check_independent, lock_jacobian
from ..numerics.dynamics import compute_energy, compute_M
from ..numerics.integrators import Integrator, Rhs, Segment
from ..numerics.integrators.base import writer
from ..numerics.transitions import TRANSITIONS, TransitionResult
from ..numerics.transitions.recursive import (
    at_rest,
    compute_joint_lock_transition,
    compute_joint_lock_transition_dense,
    joint_lock_at_rest,
    require_finite,
)
from ..physics.brakes import (
    Brake,
    BrakeEvent,
    BrakeEventKind,
    BrakeMachine,
    BrakeMode,
    mode_of_motion,
)
from ..physics.drives import (
    DriveHold,
    DriveLaw,
    DriveOff,
    DriveRamp,
    ShortCircuit,
    short_circuit,
)
from ..physics.robot import Robot
from ..physics.stop import Stop
from .holonomic import (
    FrameConstraint,
    check_activation,
    compute_kinematics,
    project_initial_state,
    stack,
)
from .phase import WORKS, Phase, full_accelerations, locked_torques, undriven_torques
from .problem import LockEvent, Problem, check_transition
from .results import (
    EventRecord,
    LockKind,
    LockRecords,
    RowKind,
    RowLabel,
    SimulationResult,
)
from .topology import Topology, full_data, lock_indices, reduced_model, weightless_model


def momentum(
    robot: Robot, data: pin.Data, q: np.ndarray, v: np.ndarray, reduced: bool
) -> np.ndarray:
    """M v [N m s] by RNEA (neither M nor a solve), at (q [rad], v [rad/s]).

    On the weightless model if ``reduced`` (the reduced loops' transitions use it anyway:
    then equal to theirs to the bit); else (the batched engine's loops, which build no
    weightless model per robot) RNEA(q, 0, v) on the full model with its ``data``, less its
    gravity load g(q) (equal to round-off, ~1e-16 relative to g).
    """
    zero = np.zeros(robot.nv)
    if reduced:
        model, weightless_data = weightless_model(robot)
        return pin.rnea(model, weightless_data, q, zero, v)
    gravity = pin.computeGeneralizedGravity(robot.model, data, q).copy()
    return pin.rnea(robot.model, data, q, zero, v) - gravity


class _RestLock(NamedTuple):
    """A lock at rest, its :class:`EventRecord` made when first read (a ``PendingRecord``).

    The record is :func:`joint_lock_at_rest` at the lock's state, with the momentum
    :func:`momentum` computes there: what the loop's lock would have recorded at once.
    """

    t: float
    joints: tuple[int, ...]
    before: tuple[int, ...]
    q: np.ndarray
    v: np.ndarray
    kind: LockKind
    robot: Robot
    reduced: bool
    labels: tuple[RowLabel, ...]
    activate: tuple[str, ...] = ()

    def record(self) -> EventRecord:
        """The lock's record."""
        p = momentum(self.robot, full_data(self.robot), self.q, self.v, self.reduced)
        names = self.robot.joints
        return EventRecord(
            t=self.t,
            lock=tuple([names[i] for i in self.joints]),
            locked_before=tuple([names[i] for i in self.before]),
            q=self.q,
            v_minus=self.v,
            transition=joint_lock_at_rest(p, self.v, self.before, self.joints),
            kind=self.kind,
            rows=tuple([self.labels[i] for i in (*self.before, *self.joints)]),
        )


def motor_shorts(robot: Robot) -> ShortCircuit | None:
    """The motors' short-circuit braking (:func:`short_circuit`), kept in the robot's cache.

    A kinematic entry: the robot's payload variants share it (their drives and gear ratios
    are its own). Kept in a 1-tuple: the cache takes None for an entry not kept, and most
    robots' motors do not brake.
    """
    kept: tuple[ShortCircuit | None] = robot.cache.get(
        "short_circuit", lambda: (short_circuit(robot),), kinematic=True
    )
    return kept[0]


def joint_labels(robot: Robot) -> tuple[RowLabel, ...]:
    """The joints' constraint-row labels, in joint order (kept in the robot's cache)."""
    labels: tuple[RowLabel, ...] = robot.cache.get(
        "joint_rows",
        lambda: tuple(RowLabel(RowKind.JOINT, name) for name in robot.joints),
        kinematic=True,
    )
    return labels


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
        reduced: bool = True,
    ) -> None:
        self.robot = robot
        self.reduced = reduced
        n = robot.nv
        self.q, self.v = q, v
        self.extras = np.zeros(WORKS + n)
        self.locked: list[int] = []
        self.brakes = {robot.joint_index(b.joint): b for b in brakes}
        self.machine = BrakeMachine(self.brakes, robot.joints, robot.gear_ratio)
        self.stop = stop
        self.drive: DriveLaw = DriveOff() if stop is None else DriveHold()
        self.drive_on = np.full(n, stop is not None)
        #: The motors' short-circuit braking (the robot's, kept in its cache with the entries
        #: its payload variants share: their drives and gear ratios are its own), and per
        #: joint whether its motor is shorted now.
        self.dynamic = motor_shorts(robot) if stop is not None else None
        self.dynamic_on = np.zeros(n, dtype=bool)
        self.rule = TRANSITIONS[rule]
        self.rule_name = rule
        self.frames: list[FrameConstraint] = []
        self.baumgarte = (0.0, 0.0)
        self.events: list[EventRecord | _RestLock] = []
        self._labels = joint_labels(robot)
        #: Built when first asked for (a stop's events at t = 0 replace it before that).
        self._phase: Phase | None = None

    @property
    def data(self) -> pin.Data:
        """The full model's Pinocchio Data (the robot's, made when first asked for)."""
        return full_data(self.robot)

    @property
    def phase(self) -> Phase:
        """The current phase, built when first asked for (at the start, after a rested stick)."""
        if self._phase is None:
            self._phase = self.new_phase()
        return self._phase

    @phase.setter
    def phase(self, phase: Phase) -> None:
        self._phase = phase

    def new_phase(self, locked: Sequence[int] | None = None) -> Phase:
        topology = Topology(self.robot, self.locked if locked is None else locked, self.q)
        return Phase(
            self.robot,
            topology,
            self.machine if self.brakes else None,
            self.drive,
            self.drive_on,
            tuple(self.frames),
            self.baumgarte,
            full=not self.reduced,
            dynamic=self.dynamic,
            dynamic_on=self.dynamic_on,
        )

    def lock(
        self,
        t: float,
        joints: Sequence[int],
        kind: LockKind,
        frames: Sequence[FrameConstraint] = (),
    ) -> None:
        """Apply the transition rule for ``joints`` locking and ``frames`` activating at ``t``.

        J1 stacks the locked joints' rows and the active frame constraints; J2 the new ones.
        """
        names = self.robot.joints
        for i in joints:
            if i in self.locked:
                raise SimulationError(f"Joint '{names[i]}' is locked twice (again at t = {t} s)")
        pure = not (frames or self.frames) and len(set(joints)) == len(joints)
        if pure and self.rule_name == "kkt" and at_rest(self.v, self.locked, joints):
            self._lock_at_rest(t, joints, kind)
            return
        frames = [f.latch(self.robot.model, self.data, self.q) for f in frames]
        if (frames or self.frames) and self.rule_name == "naive":
            raise SimulationError("The naive rule is defined for joint locks only")
        labels = [
            *(self._labels[i] for i in self.locked),
            *(RowLabel(RowKind.FRAME, f.name, a) for f in self.frames for a in f.axes),
            *(self._labels[i] for i in joints),
            *(RowLabel(RowKind.FRAME, f.name, a) for f in frames for a in f.axes),
        ]
        if pure and self.rule_name == "kkt" and self.reduced:
            result = self.joint_lock(joints)
        elif pure and self.rule_name == "kkt":
            M = compute_M(self.robot.model, self.data, self.q)
            result = compute_joint_lock_transition_dense(M, self.v, self.locked, joints)
        else:
            result = self.transition(joints, frames, labels)
        self.events.append(
            EventRecord(
                t=t,
                lock=tuple(names[i] for i in joints),
                locked_before=tuple(names[i] for i in self.locked),
                q=self.q.copy(),
                v_minus=self.v.copy(),
                transition=result,
                kind=LockKind.ACTIVATE if frames else kind,
                activate=tuple(f.name for f in frames),
                rows=tuple(labels),
            )
        )
        self.locked = self.locked + list(joints)
        self.frames = self.frames + frames
        self.v = result.v_plus.copy()
        self.v[self.locked] = 0.0

    def _lock_at_rest(self, t: float, joints: Sequence[int], kind: LockKind) -> None:
        """:meth:`lock` of distinct joints whose rates, and the locked ones', are exactly 0.

        The kkt rule's jump is then the identity (:func:`joint_lock_at_rest`): no
        constraint is stacked, no M is formed; a brake sticking at rest takes this path,
        six times a study case. Its record, whose transition needs the momentum M v, is made
        when the run's records are first read (:class:`_RestLock`).
        """
        before = self.locked
        v_minus = self.v.copy()
        require_finite(v_minus)  # v+ = v-: checked now, as the jump would be
        self.events.append(
            _RestLock(
                t,
                tuple(joints),
                tuple(before),
                self.q.copy(),
                v_minus,
                kind,
                self.robot,
                self.reduced,
                self._labels,
            )
        )
        self.locked = [*before, *joints]
        self.v = v_minus.copy()
        self.v[self.locked] = 0.0  # -0.0 as 0.0, as the general path

    def joint_lock(self, joints: Sequence[int]) -> TransitionResult:
        """The kkt rule's jump for pure joint locks, in O(n) without forming M.

        Distinct unit rows are independent, so no rank check is needed; the reduced models
        come from the robot's cache (the next phase reuses the one with gravity).
        """
        robot = self.robot
        locked = tuple(sorted([*self.locked, *joints]))
        model, data = weightless_model(robot)
        reduced, reduced_data = reduced_model(robot, locked, self.q[list(locked)], weightless=True)
        return compute_joint_lock_transition(
            model, self.q, self.v, self.locked, joints, reduced, data, reduced_data
        )

    def transition(
        self, joints: Sequence[int], frames: Sequence[FrameConstraint], labels: Sequence[RowLabel]
    ) -> TransitionResult:
        """The rule's jump from the dense M and the stacked J1 (locks, frames) and J2 (new)."""
        model, n = self.robot.model, self.robot.nv
        if self.frames or frames:
            compute_kinematics(model, self.data, self.q, self.v)
        _, F1, _ = stack(tuple(self.frames), model, self.data)
        _, F2, _ = stack(tuple(frames), model, self.data)
        J1 = np.vstack([lock_jacobian(n, self.locked), F1])
        J2 = np.vstack([lock_jacobian(n, joints), F2])
        check_independent(np.vstack([J1, J2]), [str(label) for label in labels])
        M = compute_M(model, self.data, self.q)
        return self.rule(M, J1, J2, self.v)

    def drop_out(self, joints: np.ndarray | list[int] | slice) -> None:
        """The drives of ``joints`` drop out: their motors, if they brake, are shorted."""
        self.drive_on[joints] = False
        if self.dynamic is not None:
            self.dynamic_on[joints] = self.dynamic.present[joints]

    def engage(self, t: float, i: int, ideal_locks: list[int]) -> None:
        """Brake ``i`` engages: its drive drops out; an ideal brake's joint locks now."""
        self.drop_out([i])
        if self.machine.engage(t, i, float(self.v[i]), i in self.locked):
            ideal_locks.append(i)

    def settle(self, t: float, due: Sequence[int] = ()) -> None:
        """Let the brakes decide stick or slip at ``t``, then build the next phase."""
        if self.brakes:
            self.machine.settle(t, self, due)
        self.phase = self.new_phase()

    # The brake state machine's view of the loop (vtm_pin.physics.brakes.BrakeWorld).

    def holding_torque(self, t: float, locked: Sequence[int]) -> np.ndarray:
        """Holding torques [N m] with ``locked`` held and the brakes' current modes."""
        if self._undriven_full():
            locked_index, _, free, free_block = self._indices(locked)
            q, v, a = self._full_accelerations(t, locked_index, free, free_block)
            out = np.zeros(self.robot.nv)
            out[locked_index] = locked_torques(self.robot, q, v, locked_index, a)
            return out
        trial = self.new_phase(locked)
        return trial.holding_torque(t, trial.pack(self.q, self.v, self.extras))

    def _undriven_full(self) -> bool:
        """Whether the full model's dynamics with no drive and no frame hold: the direct path.

        Then the brakes' trial lock sets are answered from the full model's M and b without
        building a trial :class:`Phase`, bit for bit as that phase would answer.
        """
        return not (self.reduced or self.frames or (self.drive.acts and self.drive_on.any()))

    def _indices(self, locked: Sequence[int]) -> tuple[np.ndarray, ...]:
        """The lock set's index arrays (:func:`~vtm_pin.core.topology.lock_indices`)."""
        return lock_indices(self.robot.nv, tuple(sorted(int(i) for i in locked)))

    def _full_accelerations(
        self, t: float, locked: np.ndarray, free: np.ndarray, free_block: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, v with 0 at ``locked``, accelerations) of the full model with ``locked`` held."""
        v = self.v.copy()
        v[locked] = 0.0
        if not free.size:
            return self.q, v, np.zeros(self.robot.nv)
        tau = undriven_torques(t, v, free, self.machine, self.dynamic, self.dynamic_on)
        return self.q, v, full_accelerations(self.robot, self.q, v, free, free_block, tau)

    def accelerations(self, t: float) -> np.ndarray:
        """Joint accelerations [rad/s^2] with the current locks and modes."""
        if self._undriven_full():
            locked, _, free, free_block = self._indices(self.locked)
            return self._full_accelerations(t, locked, free, free_block)[2]
        phase = self.new_phase()
        y = phase.pack(self.q, self.v, self.extras)
        if phase.full:
            return phase.accelerations(t, y)
        k = phase.k
        a = np.zeros(self.robot.nv)
        a[phase.topology.free] = phase.rhs(t, y)[k : 2 * k]
        return a

    def stick(self, t: float, joints: Sequence[int]) -> None:
        """Brakes that hold their joints at rest: one momentum-consistent lock."""
        self.lock(t, joints, LockKind.STICK)

    def stick_rested(self, t: float, joint: int, hold: np.ndarray) -> None:
        """Sliding ``joint`` reached rest and every brake at rest holds: it sticks.

        The decision was taken by the integrator (:class:`Rested`). The next phase is built
        when it is asked for: the integrator may hand more rested intervals first, which need
        none.
        """
        self.machine.stick_rested(t, self, joint, hold)
        self._phase = None


@dataclass(frozen=True)
class SegmentRequest:
    """What the hybrid loop asks an integrator for: one interval of one phase.

    The hybrid loop (:func:`hybrid_run`) yields these and is sent back the
    :class:`~vtm_pin.numerics.integrators.Segment`; :func:`simulate` answers each at once with the
    scenario's integrator, the batched engine (:mod:`vtm_pin.core.batch`) answers many runs'
    requests together.

    Attributes:
        phase: The phase (topology, modes, torques, state events).
        rhs: Its right-hand side (with progress reporting if asked for).
        t0: Start [s].
        y0: Phase state at ``t0`` (:meth:`Phase.pack`).
        t1: End [s]: the next time event or the run's end.
        integrator: The integrator to use (dense output dropped when nothing moves).
    """

    phase: Phase
    rhs: Rhs
    t0: float
    y0: np.ndarray
    t1: float
    integrator: Integrator

    def integrate(self) -> Segment:
        """The interval integrated by the scalar integrator.

        A frozen state (``y0`` empty: every joint locked, nothing accumulating) is given no
        state events, which the phase would otherwise build only to be left unwatched
        (:class:`~vtm_pin.numerics.integrators.base.Integrator`); it ends every study case.
        """
        events = [e.event for e in self.phase.events] if self.y0.size else []
        return self.integrator.integrate(
            self.rhs, self.t0, self.y0, self.t1, events, n_q=self.phase.k
        )


@dataclass(frozen=True)
class Rested:
    """An interval ended by a sliding joint reaching rest, with the brakes' decision taken.

    The batched engine takes the common decision across its lanes, as
    :meth:`~vtm_pin.physics.brakes.BrakeMachine.settle` would: no other braked joint is at
    rest or reverses, and every braked joint at rest holds with the arrived one locked (its
    holding torques ``hold`` are within the static limits). The arrived joint then sticks
    (:meth:`~vtm_pin.physics.brakes.BrakeMachine.stick_rested`); the engine goes on
    integrating the next interval without handing the run's hybrid loop anything.

    Its samples are of all joints (the batched engine's padded layout), so that the loop needs
    no phase to record them: the locked joints' q at their lock values and v exactly 0.

    Attributes:
        t: Sample times [s]; t[-1] is the rest.
        y: States at those times, of all n joints: (q, v, W_brake, W_drive, W_short, P_brake),
            shape (len(t), 3 n + 3) [rad, rad/s, J, N m s].
        holding: Holding torques at the samples [N m], NaN at free joints, shape (len(t), n);
            None if the run keeps none.
        rhs_evals: Right-hand-side evaluations of the interval.
        steps: Its accepted steps.
        joint: Index of the joint that reached rest.
        hold: Holding torques [N m] of every joint with it locked (0 where free), at t[-1].
    """

    t: np.ndarray
    y: np.ndarray
    holding: np.ndarray | None
    rhs_evals: int
    steps: int
    joint: int
    hold: np.ndarray


#: What the hybrid loop is sent for its request: the interval, or (the batched engine) the
#: intervals since, each but the last a :class:`Rested` one, the last possibly not.
Reply = Segment | tuple[Segment | Rested, ...]


def simulate(
    problem: Problem,
    integrator: Integrator,
    *,
    transition: str = "kkt",
    progress: Callable[[float], None] | None = None,
    holding: bool = True,
) -> SimulationResult:
    """Simulate a problem: prescribed locks, and brakes after a stop signal.

    Without a stop no joint torque acts (drives off). With a stop, the drives hold the joint
    rates constant until the signal, then act as its category says, and each brake engages
    after its delay, never in category 2, whose drives hold the arm (see
    :mod:`vtm_pin.physics.stop` and :mod:`vtm_pin.physics.brakes`). Frame constraints active
    from t = 0 get q0 and v0 projected onto them first, with a :class:`VtmWarning` if that
    moves them by more than 1e-6.

    Args:
        problem: What to simulate (validated when it was built).
        integrator: How to integrate between events.
        transition: Name in :data:`vtm_pin.numerics.transitions.TRANSITIONS`.
        progress: Called with the simulated time t [s] at every right-hand-side evaluation
            and at the end of every segment, for progress display; it must not change
            anything (the results do not depend on it).
        holding: False: the locks' holding torques at the samples are not computed (NaN in
            the result's ``holding``), for a caller that reads none (a study's records);
            the brakes' decisions compute their own and do not change.

    Returns:
        The sampled motion and event records.

    Raises:
        SimulationError: An unknown transition rule, or the state became non-finite.
    """
    run = hybrid_run(problem, integrator, transition=transition, progress=progress, holding=holding)
    request = next(run)
    while True:
        try:
            request = run.send(request.integrate())
        except StopIteration as done:
            result: SimulationResult = done.value
            return result


def hybrid_run(
    problem: Problem,
    integrator: Integrator,
    *,
    transition: str = "kkt",
    progress: Callable[[float], None] | None = None,
    reduced_models: bool = True,
    holding: bool = True,
) -> Generator[SegmentRequest, Reply, SimulationResult]:
    """The hybrid loop of :func:`simulate` as a generator of integration requests.

    It yields a :class:`SegmentRequest` for every interval between events and must be sent
    the integrated :class:`~vtm_pin.numerics.integrators.Segment` (or, from the batched
    engine, a :data:`Reply` of several); it returns the result (as the value of its
    ``StopIteration``). The wall time it reports runs from its start to its end,
    so it includes the integration of its intervals, whoever did it (the batched engine
    replaces it with the run's share of its batch). Without ``reduced_models`` the loop's
    own dynamics (brake decisions, holding torques, joint-lock jumps by the dense kkt rule)
    use the full model only, for an integrator that does not evaluate the phases' reduced
    models. Without ``holding`` the samples' holding torques are left NaN (see
    :func:`simulate`).

    Raises:
        SimulationError: As :func:`simulate`.
    """
    if transition not in TRANSITIONS:
        raise SimulationError(
            f"Unknown transition '{transition}'; allowed: {', '.join(sorted(TRANSITIONS))}"
        )
    check_transition(problem, transition)
    robot, duration, stop = problem.robot, problem.duration, problem.stop
    n = robot.nv
    start = time.perf_counter()
    h = _Hybrid(
        robot,
        problem.q0.copy(),
        problem.v0.copy(),
        problem.brakes,
        stop,
        transition,
        reduced_models,
    )
    h.baumgarte = problem.baumgarte
    if problem.constraints:
        h.frames = [c.latch(robot.model, h.data, h.q) for c in problem.constraints]
        h.q, h.v = project_initial_state(robot, h.q, h.v, h.frames)
        h.phase = h.new_phase()
    queue = _time_events(problem.events, h.brakes, stop, duration)
    trace = _Trace(n, h.extras.size, holding=holding and bool(h.brakes))
    if queue and queue[0].t <= 0.0:
        trace.add_state(0.0, h)  # the state before the events at t = 0
    counts = _Counts()
    t = 0.0
    while True:
        # Events due now (t = 0 or a time event just reached) are applied before integrating.
        if _apply_time_events(h, queue, t):
            h.settle(t)
            if t >= duration:
                trace.add_state(t, h)  # the state after the events at t = duration
        if t >= duration:
            break
        t_end = min(queue[0].t, duration) if queue else duration
        phase = h.phase
        reply = yield SegmentRequest(
            phase,
            phase.rhs if progress is None else _Reporting(phase.rhs, progress),
            t,
            phase.pack(h.q, h.v, h.extras),
            t_end,
            _sampling(integrator, phase),
        )
        pieces = reply if isinstance(reply, tuple) else (reply,)
        last = pieces[-1]
        rests = pieces if isinstance(last, Rested) else pieces[:-1]
        if rests:
            t = _take_rests(h, trace, rests, counts, duration, progress)  # type: ignore[arg-type]
        if not isinstance(last, Rested):
            t = _take(h, trace, last, counts, integrator, duration, progress)
    return trace.result(
        robot,
        (h.events, h.machine.events, h.rule_name, h.stop),
        integrator=integrator.name,
        rhs_evals=counts.rhs_evals,
        steps=counts.steps,
        wall_time=time.perf_counter() - start,
    )


@dataclass
class _Counts:
    """The hybrid loop's counts: right-hand-side evaluations, steps and state events."""

    rhs_evals: int = 0
    steps: int = 0
    state_events: int = 0


def _take(
    h: _Hybrid,
    trace: _Trace,
    segment: Segment,
    counts: _Counts,
    integrator: Integrator,
    duration: float,
    progress: Callable[[float], None] | None,
) -> float:
    """Record one interval of the current phase and apply the state event ending it; its end [s].

    The event goes to the brakes' :meth:`~vtm_pin.physics.brakes.BrakeMachine.settle`.
    """
    phase = h.phase
    counts.rhs_evals += segment.rhs_evals
    counts.steps += segment.steps
    _check_energy(h, phase, segment.y, segment.t, integrator)
    h.q, h.v, h.extras = trace.add_segment(phase, segment, h)
    t = float(segment.t[-1])
    if progress is not None:
        progress(t)
    if segment.event is not None:
        counts.state_events += 1
        _check_chatter(counts.state_events, t)
        h.settle(t, due=[phase.event_specs[segment.event].joint])
        if t >= duration:
            trace.add_state(t, h)
    return t


def _take_rests(
    h: _Hybrid,
    trace: _Trace,
    rests: Sequence[Rested],
    counts: _Counts,
    duration: float,
    progress: Callable[[float], None] | None,
) -> float:
    """:func:`_take` for consecutive :class:`Rested` intervals: their joints stick in turn.

    No phase is built. Their samples are checked and recorded as one block (each interval
    keeps its own row of free joints and brake modes); each stick is recorded as it would be
    alone. Returns the last one's end [s].
    """
    y = _rested_states(rests)
    n = trace.n
    ends = y[np.cumsum([piece.t.size for piece in rests]) - 1]  # each one's last state, a copy
    t = 0.0
    for piece, end in zip(rests, ends, strict=True):
        counts.rhs_evals += piece.rhs_evals
        counts.steps += piece.steps
        trace.add_rows(h, piece.t.size)  # its free joints and modes, before its stick
        h.q, h.v, h.extras = end[:n], end[n : 2 * n], end[2 * n :]
        t = float(piece.t[-1])
        if progress is not None:
            progress(t)
        counts.state_events += 1
        _check_chatter(counts.state_events, t)
        h.stick_rested(t, piece.joint, piece.hold)
    trace.add_arrays(
        t=rests[0].t if len(rests) == 1 else np.concatenate([piece.t for piece in rests]),
        q=y[:, :n],
        v=y[:, n : 2 * n],
        extras=y[:, 2 * n :],
        hold=np.concatenate([p.holding for p in rests]) if trace.holding else None,
    )
    if t >= duration:  # not from the batched engine, whose rests fall before its intervals' ends
        trace.add_state(t, h)
    return t


def plain_stop(problem: Problem, transition: str, holding: bool) -> float | None:
    """The instant [s] a plain stop's brakes engage; None for any other run.

    A plain stop is the life of a study case: a category-0 stop signalled at t = 0, every
    joint braked by friction without a normal-force ramp, all the brakes engaging at one
    instant before the end, no frame constraint and no prescribed lock, the kkt rule, and no
    holding torques kept at the samples. The batched engine runs its life after its first
    interval itself (:class:`PlainStop`), as long as the stop stays plain: every joint slides
    when the brakes engage and every rest sticks.

    Args:
        problem: The run.
        transition: Its transition rule.
        holding: Whether its samples' holding torques are kept (see :func:`simulate`).
    """
    stop, robot, brakes = problem.stop, problem.robot, problem.brakes
    if transition != "kkt" or holding or problem.events or problem.constraints:
        return None
    if stop is None or stop.category != 0 or stop.t != 0.0 or len(brakes) != robot.nv:
        return None
    if len({robot.joint_index(b.joint) for b in brakes}) != robot.nv:
        return None
    if len({b.delay for b in brakes}) != 1 or any(b.ideal or b.friction.ramp for b in brakes):
        return None
    t = stop.brake_signal + brakes[0].delay
    return t if 0.0 < t < problem.duration else None


class PlainStop:
    """The hybrid loop's records of a plain stop (:func:`plain_stop`) whose life the engine ran.

    After the stop's first interval the batched engine takes its decisions itself, across its
    lanes: the brakes engage with every joint sliding (each against its motion), then each
    joint that reaches rest sticks (:class:`Rested`), until every joint is stuck. From what
    the engine hands it, this makes the records that :func:`hybrid_run` makes of the same
    life, to the bit: the state before the events at t = 0, the samples with their free joints
    and brake modes, the brakes' engage and stick events, the locks at rest, and the frozen
    interval to the end (tests/test_batch_plain.py compares the two). It makes no phase
    and no decision: with the engine's own start and engagement (:mod:`vtm_pin.core.batch`), a
    UR10 study case takes 11-14 % less time (issue 27, ``benchmarks/interleaved.py``).

    Args:
        problem: The run.
        integrator: Its integrator's name.
        first: The first interval's samples: times [s], the last the brakes' engagement, and
            states of all joints (the engine's padded layout: q, v, then the accumulators,
            0 if the interval was passive).
        counts: Its right-hand-side evaluations and accepted steps.
    """

    def __init__(
        self,
        problem: Problem,
        integrator: str,
        first: tuple[np.ndarray, np.ndarray],
        counts: tuple[int, int],
    ) -> None:
        robot = problem.robot
        n = robot.nv
        t, y = first
        self.problem = problem
        self.integrator = integrator
        self.rhs_evals, self.steps = counts
        self.brakes = {robot.joint_index(b.joint): b for b in problem.brakes}
        self.trace = _Trace(n, WORKS + n, holding=False)
        self.modes = [BrakeMode.FREE] * n
        free = np.ones(n, dtype=bool)
        self.trace._rows(free, self.modes, 1)  # the state before the events at t = 0
        self.trace.add_arrays(
            t=np.zeros(1),
            q=problem.q0[None].copy(),
            v=problem.v0[None].copy(),
            extras=np.zeros((1, WORKS + n)),
        )
        self.trace._rows(free, self.modes, t.size)  # the first interval
        self.trace.add_arrays(t=t, q=y[:, :n], v=y[:, n : 2 * n], extras=y[:, 2 * n :])
        self.engaged = float(t[-1])
        self.brake_events: list[BrakeEvent] = []
        for i, name in enumerate(robot.joints):  # in joint order, as the loop's time events
            rate = float(y[-1, n + i])
            self.brake_events.append(BrakeEvent(self.engaged, name, BrakeEventKind.ENGAGE, rate))
            mode = mode_of_motion(rate)
            assert mode is not None, "the engine engages plain stops' brakes on moving joints"
            self.modes[i] = mode

    def result(self, rests: Sequence[Rested], duration: float) -> SimulationResult | None:
        """The run's result, its joints stuck in turn by ``rests``; None if it is not plain.

        A rest whose lock is not at rest (a locked rate not exactly 0) is not: the run must
        go through its own loop.

        Args:
            rests: The intervals after the engagement, each ended by a joint sticking; the
                last one sticks the last free joint.
            duration: The run's end [s].

        Raises:
            SimulationError: A state is not finite (as :func:`hybrid_run`).
        """
        robot, brakes = self.problem.robot, self.brakes
        n = robot.nv
        y = _rested_states(rests)
        joints = [piece.joint for piece in rests]
        ends = y[np.cumsum([piece.t.size for piece in rests]) - 1]  # each one's last state
        # Before rest k the joints of rests 0..k-1 are locked: free, and (the transition's
        # test) their rates must be exactly 0 there.
        before, after = _stick_order(len(rests))
        free = np.ones((len(rests), n), dtype=bool)
        free[:, joints] = after
        if ends[:, n : 2 * n][:, joints][before].any():
            return None
        locked: list[int] = []
        events: list[_RestLock] = []
        labels = joint_labels(robot)
        for k, (piece, j) in enumerate(zip(rests, joints, strict=True)):
            self.rhs_evals += piece.rhs_evals
            self.steps += piece.steps
            self.trace._rows(free[k], self.modes, piece.t.size)  # before its stick
            end = ends[k]
            t, v = float(piece.t[-1]), end[n : 2 * n]
            rate = float(v[j])
            v[j] = 0.0
            limit = brakes[j].static(t - self.engaged, float(robot.gear_ratio[j]))
            hold = float(piece.hold[j])
            self.brake_events.append(
                BrakeEvent(t, robot.joints[j], BrakeEventKind.STICK, rate, hold, limit)
            )
            self.modes[j] = BrakeMode.STUCK
            events.append(
                _RestLock(
                    t, (j,), tuple(locked), end[:n], v.copy(), LockKind.STICK, robot, False, labels
                )
            )
            locked.append(j)
        t_end = np.concatenate([piece.t for piece in rests]) if len(rests) > 1 else rests[0].t
        self.trace.add_arrays(t=t_end, q=y[:, :n], v=y[:, n : 2 * n], extras=y[:, 2 * n :])
        # Every joint stuck: the frozen interval to the end, one step and no evaluation, its
        # ends sampled (as DOP853 integrates a phase with nothing to integrate).
        self.steps += 1
        self.trace._rows(np.zeros(n, dtype=bool), self.modes, 2)
        last = ends[-1]
        self.trace.add_arrays(
            t=np.array([float(rests[-1].t[-1]), duration]),
            q=np.repeat(last[None, :n], 2, axis=0),
            v=np.zeros((2, n)),
            extras=np.repeat(last[None, 2 * n :], 2, axis=0),
        )
        return self.trace.result(
            robot,
            (events, self.brake_events, "kkt", self.problem.stop),
            integrator=self.integrator,
            rhs_evals=self.rhs_evals,
            steps=self.steps,
            wall_time=0.0,  # the engine's share replaces it
        )


@functools.lru_cache(maxsize=64)
def _stick_order(count: int) -> tuple[np.ndarray, np.ndarray]:
    """Which of ``count`` rests' joints stick before each (strictly lower triangle), and not.

    Kept per count (read-only): a study's cases stick the same number of joints.
    """
    before = np.tri(count, k=-1, dtype=bool)
    after = ~before
    before.flags.writeable = after.flags.writeable = False
    return before, after


def _rested_states(rests: Sequence[Rested]) -> np.ndarray:
    """The samples' states of consecutive :class:`Rested` intervals, as one array.

    Raises:
        SimulationError: A state is not finite.
    """
    y = rests[0].y if len(rests) == 1 else np.concatenate([piece.y for piece in rests])
    if not np.isfinite(y).all():
        bad = next(piece for piece in rests if not np.isfinite(piece.y).all())
        raise SimulationError(
            f"The state became non-finite between t = {bad.t[0]:.6g} s and "
            f"{bad.t[-1]:.6g} s: the step is too large for these dynamics; reduce it"
        )
    return y


class TimeKind(IntEnum):
    """Kinds of time events, in the order they apply at one instant."""

    SIGNAL = 0  # the stop button: drives off (category 0) or ramping (categories 1 and 2)
    BRAKE_SIGNAL = 1  # category 1: drives of joints without a brake go off
    ENGAGE = 2  # one brake engages (payload: joint index)
    LOCK = 3  # prescribed locks and activations (payload: LockEvent)
    KINK = 4  # a ramp ends: the torques have a kink, the integrator restarts there


class TimeEvent(NamedTuple):
    """A time event of the hybrid loop, ordered by time, then kind, then creation.

    A tuple: the heap compares its events in C. ``order`` differs between the events of a
    run, so ``payload`` is never compared.

    Attributes:
        t: Time [s].
        kind: What happens.
        order: Creation order (ties at equal time and kind).
        payload: The lock event or the joint index the kind needs.
    """

    t: float
    kind: TimeKind
    order: int
    payload: LockEvent | int | None = None


#: Most brake state events (a joint reaching rest, a stuck joint slipping) in one run: a
#: safety net against chatter (Zeno behaviour), far above a real stop's few dozen.
MAX_STATE_EVENTS = 10_000


def _check_chatter(count: int, t: float) -> None:
    """Stop a run whose brakes stick and slip without end."""
    if count > MAX_STATE_EVENTS:
        raise SimulationError(
            f"More than {MAX_STATE_EVENTS} brake state events by t = {t:.6g} s: the brakes "
            "stick and slip without end (chatter); check the brake torques against the loads"
        )


def _apply_time_events(h: _Hybrid, queue: list[TimeEvent], t: float) -> bool:
    """Apply the time events due at ``t`` (in heap order); whether there were any."""
    ideal: list[int] = []
    frames: list[FrameConstraint] = []
    changed = False
    while queue and queue[0].t <= t:
        event = heapq.heappop(queue)
        changed = True
        match event.kind, event.payload:
            case TimeKind.LOCK, LockEvent() as lock:
                ideal.extend(h.robot.joint_indices(lock.lock))
                frames.extend(lock.activate)
            case TimeKind.SIGNAL, _:
                assert h.stop is not None
                if h.stop.category == 0:
                    h.drive = DriveOff()
                    h.drop_out(slice(None))
                else:
                    h.drive = DriveRamp(h.stop, h.v.copy())
            case TimeKind.BRAKE_SIGNAL, _:
                h.drop_out([i for i in range(h.robot.nv) if i not in h.brakes])
            case TimeKind.ENGAGE, int() as joint:
                h.engage(t, joint, ideal)
    if ideal or frames:
        h.lock(t, ideal, LockKind.LOCK, frames)
    return changed


class _Trace:
    """The samples of a run, collected block by block (a segment, or one state).

    Per block, what varies by sample is kept as arrays; the free mask and the brakes' modes,
    constant over a block, as one row each, repeated once at the end (:meth:`result`). The
    constraint drift is kept for the blocks with frame constraints only (NaN elsewhere).
    """

    def __init__(self, n: int, n_extras: int, holding: bool = True) -> None:
        self.n = n
        self.n_extras = n_extras
        #: Whether the locks' holding torques are kept at the samples (NaN if not: no block
        #: of them is kept, the result's are made at once).
        self.holding = holding
        self.blocks: dict[str, list[np.ndarray]] = {
            key: [] for key in ("t", "q", "v", "extras", "hold")[: 5 if holding else 4]
        }
        self.sizes: list[int] = []
        self.free: list[np.ndarray] = []  # a row per block
        self.modes: list[bytes] = []  # a row per block, a byte a mode
        self.drift: list[tuple[int, np.ndarray]] = []  # (first sample, drift) of some blocks
        self.samples = 0
        self._all_free = np.ones(n, dtype=bool)

    def _append(
        self,
        free: np.ndarray,
        modes: Sequence[int],
        drift: np.ndarray | None = None,
        **arrays: Any,
    ) -> None:
        self.add_arrays(**arrays)
        self._rows(free, modes, len(arrays["t"]), drift)

    def add_arrays(self, **arrays: Any) -> None:
        """The arrays of a block's samples (``hold`` kept only with :attr:`holding`)."""
        for key, blocks in self.blocks.items():
            blocks.append(arrays[key])

    def _rows(
        self, free: np.ndarray, modes: Sequence[int], size: int, drift: np.ndarray | None = None
    ) -> None:
        """The free mask and modes of ``size`` samples (and their constraint drift)."""
        self.sizes.append(size)
        self.free.append(free)
        self.modes.append(bytes(modes))
        if drift is not None:
            self.drift.append((self.samples, drift))
        self.samples += size

    def add_rows(self, h: _Hybrid, size: int) -> None:
        """The free mask and modes of the loop now, for ``size`` samples of a block."""
        self._rows(self._free(h), h.machine.modes, size)

    def _free(self, h: _Hybrid) -> np.ndarray:
        free = self._all_free.copy()  # a copy of a template: np.ones costs ~3x as much
        free[h.locked] = False
        return free

    def add_state(self, t: float, h: _Hybrid) -> None:
        """One sample of the hybrid state as it is now (before or after events at ``t``)."""
        self._append(
            self._free(h),
            h.machine.modes,
            t=np.array([t]),
            q=h.q[None].copy(),
            v=h.v[None].copy(),
            extras=h.extras[None].copy(),
            hold=np.full((1, self.n), np.nan) if self.holding else None,
        )

    def add_segment(
        self, phase: Phase, segment: Segment, h: _Hybrid
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Record a segment; returns the full (q, v, extras) at its end."""
        n, k, size = self.n, phase.k, segment.t.size
        topology = phase.topology
        q = np.empty((size, n))
        v = np.zeros((size, n))
        q[:, topology.locked_index] = topology.q_locked
        q[:, topology.free] = segment.y[:, :k]
        v[:, topology.free] = segment.y[:, k : 2 * k]
        hold = np.full((size, n), np.nan) if self.holding else None
        if hold is not None and topology.locked and segment.holding is not None:
            locked = list(topology.locked)
            hold[:, locked] = segment.holding[:, locked]
        elif hold is not None and topology.locked:
            locked = list(topology.locked)
            for r in range(size):
                hold[r, locked] = phase.holding_torque(segment.t[r], segment.y[r])[locked]
        extras = phase.unpack_extras(segment.y, h.extras)
        self._append(
            topology.free_mask,
            h.machine.modes,
            phase.constraint_drift(segment.y) if phase.constraints else None,
            t=segment.t,
            q=q,
            v=v,
            extras=extras,
            hold=hold,
        )
        return q[-1].copy(), v[-1].copy(), extras[-1].copy()

    def result(
        self,
        robot: Robot,
        records: tuple[list[Any], list[BrakeEvent], str, Stop | None],
        *,
        integrator: str,
        rhs_evals: int,
        steps: int,
        wall_time: float,
    ) -> SimulationResult:
        """The collected samples and the events as a :class:`SimulationResult`.

        ``records``: the run's lock records (some pending), brake events, transition rule and
        stop.
        """
        events, brake_events, transition, stop = records
        rows = {key: np.concatenate(blocks) for key, blocks in self.blocks.items()}
        if not self.holding:
            rows["hold"] = np.full((self.samples, self.n), np.nan)
        sizes = np.array(self.sizes)
        drift = np.full((self.samples, 2), np.nan)
        for first, block in self.drift:
            drift[first : first + len(block)] = block
        work = rows["extras"]
        modes_rows = np.frombuffer(b"".join(self.modes), np.int8).reshape(len(self.modes), self.n)
        return SimulationResult(
            joints=robot.joints,
            t=rows["t"],
            q=rows["q"],
            v=rows["v"],
            free=np.repeat(np.array(self.free), sizes, axis=0),
            modes=np.repeat(modes_rows, sizes, axis=0),
            brake_work=work[:, 0],
            drive_work=work[:, 1],
            short_circuit_work=work[:, 2],
            brake_impulse=work[-1, WORKS:].copy(),
            holding=rows["hold"],
            drift=drift,
            events=LockRecords(events),
            brake_events=tuple(brake_events),
            transition=transition,
            integrator=integrator,
            rhs_evals=rhs_evals,
            steps=steps,
            wall_time=wall_time,
            stop=stop,
        )


#: Largest energy-balance error of one interval, as a fraction of the energy it moved. A
#: blow-up detector, not an accuracy monitor: the balance residual is in summary.json.
ENERGY_TOLERANCE = 0.1
_ENERGY_SAMPLES = 9  # states per interval at which the energy is evaluated
#: Relative round-off of the mechanical energy T + V [-]: an interval that moves less than
#: this much of it cannot be judged (measured: 4e-13 to 2e-9 J residuals on ~10 J runs).
ENERGY_ROUNDOFF = 1e-9


def _check_energy(
    h: _Hybrid, phase: Phase, y: np.ndarray, t: np.ndarray, integrator: Integrator
) -> None:
    """Raise if an interval started off its new constraints or broke the energy balance.

    A frame constraint activated at the interval's start must hold there (the frames meet, a
    docked frame is at its target): otherwise the error names it and the distance. Between
    events T + V changes only by the brakes' and drives' work; a step far too large makes it
    grow or collapse (or go non-finite) long before anything else is visibly wrong.
    """
    last = h.events[-1] if h.events else None
    if last is not None and last.activate and last.t == t[0]:
        q_start, _ = phase.topology.merge(y[0, : 2 * phase.k])
        new = [f for f in h.frames if f.name in last.activate]
        check_activation(new, h.robot.model, h.data, q_start, float(t[0]))
    if not np.isfinite(y).all():
        row = int(np.argmin(np.isfinite(y).all(axis=1)))
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
        works.append(phase.unpack_extras(row, h.extras)[:WORKS])
    (t0, v0), (t1, v1) = energies[0], energies[-1]
    brake, drive, short = works[-1] - works[0]
    residual = (t0 + v0) - (t1 + v1) - (brake + short - drive)
    # Energy moved: the largest kinetic energy and potential change seen, and the work done.
    kinetic = max(e[0] for e in energies)
    potential = max(e[1] for e in energies) - min(e[1] for e in energies)
    moved = max(kinetic, potential, abs(brake), abs(drive), abs(short))
    # Round-off of T + V itself (|V| may be large while little moves) is no blow-up.
    roundoff = ENERGY_ROUNDOFF * max(1.0, abs(t0) + abs(v0))
    if abs(residual) > max(ENERGY_TOLERANCE * moved, roundoff):
        raise SimulationError(
            f"Energy balance broken by {residual:.3g} J ({100 * abs(residual) / moved:.0f} % of "
            f"the energy moved) between t = {t[0]:g} s and {t[-1]:g} s with "
            f"{_settings(integrator)}: the step is too large for these dynamics; reduce it"
        )


def _sampling(integrator: Integrator, phase: Phase) -> Integrator:
    """The integrator for ``phase``: without dense output when every joint is locked.

    Nothing moves then (the state holds only work integrals, which stay constant), so samples
    at ``output_dt`` would repeat one state; the phase's ends are recorded instead.
    """
    if phase.k == 0 and getattr(integrator, "output_dt", None) is not None:
        unsampled: Integrator = dataclasses.replace(integrator, output_dt=None)  # type: ignore[type-var]
        return unsampled
    return integrator


class _Reporting:
    """The right-hand side ``rhs``, telling ``progress`` the time of each evaluation.

    It writes into the integrator's buffers as ``rhs`` does (see
    :data:`~vtm_pin.numerics.integrators.base.RhsInto`).
    """

    def __init__(self, rhs: Rhs, progress: Callable[[float], None]) -> None:
        self.rhs = rhs
        self.progress = progress
        self._into = writer(rhs)

    def __call__(self, t: float, y: np.ndarray) -> np.ndarray:
        """f(t, y), after telling ``progress`` the time t [s]."""
        self.progress(t)
        return self.rhs(t, y)

    def into(self, t: float, y: np.ndarray, out: np.ndarray) -> None:
        """f(t, y) into ``out``, after telling ``progress`` the time t [s]."""
        self.progress(t)
        self._into(t, y, out)


def _settings(integrator: Integrator) -> str:
    dt = getattr(integrator, "dt", None)
    if dt is not None:
        return f"{integrator.name} dt = {dt:g} s"
    rtol = getattr(integrator, "rtol", float("nan"))
    atol = getattr(integrator, "atol", float("nan"))
    return f"{integrator.name} rtol = {rtol:g}, atol = {atol:g}"


def _time_events(
    events: Sequence[LockEvent],
    brakes: dict[int, Brake],
    stop: Stop | None,
    duration: float,
) -> list[TimeEvent]:
    """Heap of the run's time events up to ``duration``."""
    items: list[tuple[float, TimeKind, LockEvent | int | None]] = []
    for event in events:
        items.append((event.t, TimeKind.LOCK, event))
    if stop is not None:
        items.append((stop.t, TimeKind.SIGNAL, None))
        if stop.category in (1, 2):
            assert stop.ramp_time is not None
            items.append((stop.t + stop.ramp_time, TimeKind.KINK, None))
        if stop.category == 2:
            brakes = {}  # the drives hold the arm: no brake is signalled
        if stop.category == 1:
            items.append((stop.brake_signal, TimeKind.BRAKE_SIGNAL, None))
        for i, brake in sorted(brakes.items()):
            t_engage = stop.brake_signal + brake.delay
            items.append((t_engage, TimeKind.ENGAGE, i))
            if brake.friction.ramp > 0.0:
                items.append((t_engage + brake.friction.ramp, TimeKind.KINK, None))
    queue = [
        TimeEvent(t, kind, count, payload)
        for count, (t, kind, payload) in enumerate(items)
        if t <= duration
    ]
    heapq.heapify(queue)
    return queue
