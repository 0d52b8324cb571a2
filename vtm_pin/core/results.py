"""Results of a simulation: the sampled motion, the locks with their jumps, the brake events.

Frozen records only: the hybrid loop (:mod:`vtm_pin.core.simulation`) builds them, and analysis,
reports, plots and drawings read them without importing the loop.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Any, Protocol, overload

import numpy as np

from ..exceptions import SimulationError
from ..numerics.transitions import TransitionResult
from ..physics.brakes import BrakeEvent
from ..physics.stop import Stop


class _Word(str, Enum):
    """An enum whose members read as their word: in f-strings, str() and JSON alike."""

    def __str__(self) -> str:
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(str(self.value), spec)


class LockKind(_Word):
    """What caused a lock event (the value is the word used in summary.json)."""

    LOCK = "lock"  # a prescribed lock, or an ideal brake
    STICK = "stick"  # a sliding brake came to rest and holds
    ACTIVATE = "activate"  # frame constraints activate (maybe with locks)


class RowKind(_Word):
    """What a row of the constraint Jacobian J+ = [J1; J2] holds."""

    JOINT = "lock"  # a locked joint's unit row
    FRAME = "frame"  # one axis of a frame constraint


@dataclass(frozen=True)
class RowLabel:
    """A constraint row: a locked joint, or one axis of a named frame constraint.

    Attributes:
        kind: Joint lock or frame constraint.
        name: The joint's or the constraint's name.
        axis: The constraint's axis (``x`` ... ``rz``); "" for a joint lock.
    """

    kind: RowKind
    name: str
    axis: str = ""

    def __str__(self) -> str:
        """``lock joint2`` or ``dock.x``, as in messages and summary.json."""
        if self.kind is RowKind.JOINT:
            return f"lock {self.name}"
        return f"{self.name}.{self.axis}"


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
    kind: LockKind = LockKind.LOCK
    activate: tuple[str, ...] = ()
    rows: tuple[RowLabel, ...] = ()

    @property
    def v_plus(self) -> np.ndarray:
        """Velocity just after [rad/s]."""
        return self.transition.v_plus


class PendingRecord(Protocol):
    """A lock whose :class:`EventRecord` is made when it is first read (:class:`LockRecords`)."""

    @property
    def t(self) -> float:
        """Event time [s]."""

    @property
    def activate(self) -> tuple[str, ...]:
        """Names of the frame constraints activated."""

    def record(self) -> EventRecord:
        """The lock's record."""


class LockRecords(Sequence[EventRecord]):
    """A run's lock records, in time order; some are made only when first read.

    The hybrid loop keeps a lock at rest (every locked rate 0: no jump; a brake that sticks,
    six times a study case) as a :class:`PendingRecord`. Its record's transition needs the
    momentum M v, that is RNEA passes; it is made, with the others, when the records are first
    read, and then kept. A study's records read none of them: 4-6 % of a UR10 case's time
    (issue 27). The records are those the loop would have made at once, to the bit. Equal to
    the tuple of the records; pickled as that tuple.
    """

    def __init__(self, items: Iterable[EventRecord | PendingRecord] = ()) -> None:
        self._items: tuple[EventRecord | PendingRecord, ...] = tuple(items)
        self._records: tuple[EventRecord, ...] | None = None

    def _made(self) -> tuple[EventRecord, ...]:
        if self._records is None:
            self._records = tuple(
                item if isinstance(item, EventRecord) else item.record() for item in self._items
            )
            self._items = self._records  # the pending locks' states are no longer needed
        return self._records

    def __len__(self) -> int:
        return len(self._items)

    @overload
    def __getitem__(self, index: int) -> EventRecord: ...

    @overload
    def __getitem__(self, index: slice) -> tuple[EventRecord, ...]: ...

    def __getitem__(self, index: int | slice) -> EventRecord | tuple[EventRecord, ...]:
        return self._made()[index]

    def __iter__(self) -> Iterator[EventRecord]:
        return iter(self._made())

    def __eq__(self, other: object) -> bool:
        if isinstance(other, LockRecords):
            other = other._made()
        return self._made() == other if isinstance(other, tuple) else NotImplemented

    __hash__ = None  # type: ignore[assignment]  # as mutable as the records' arrays

    def __repr__(self) -> str:
        return repr(self._made())

    def __reduce__(self) -> tuple[Any, ...]:
        return (LockRecords, (self._made(),))


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
        short_circuit_work: Work dissipated by the motors' short-circuit braking since t = 0
            [J], shape (k,); never decreases.
        brake_impulse: Friction impulse each brake delivered to its joint [N m s], shape (n,).
        holding: Torque each lock exerts to hold its joint [N m], shape (k, n); NaN where the
            joint is free, and everywhere in runs without brakes or run with
            ``holding=False`` (not computed: a study's runs).
        drift: Constraint drift of the active frame constraints per sample, shape (k, 2):
            max |h| [m or rad] and max |J v| [m/s or rad/s]; NaN where none is active.
        events: One record per lock, in time order (from the hybrid loop, a
            :class:`LockRecords`, which makes the records of locks at rest when first read).
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
    short_circuit_work: np.ndarray
    brake_impulse: np.ndarray
    holding: np.ndarray
    drift: np.ndarray
    events: Sequence[EventRecord]
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
