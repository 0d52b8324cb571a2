"""Joint brakes: the Modelica ``Rotational.Components.Brake`` state machine, per joint.

A brake is ``free`` until it engages (stop signal + delay). It then ``slides`` (``forward`` for
v > 0, ``backward`` for v < 0) with the kinetic torque -tau_slide sign(v), which only ever
opposes the motion. A braked joint at rest, whether it engaged at rest, slid to rest or is
stuck, goes through one decision (Modelica's start-forward / start-backward conditions): it
is ``stuck`` (a joint lock) while the torque needed to hold it is within the static torque,
else it starts sliding in the direction the load drives it (:func:`mode_of_load`). A stuck
joint whose holding torque exceeds the static torque ``slips`` back to sliding. The torques
come from the brake's friction law (:mod:`vtm_pin.physics.friction`: Coulomb or Stribeck, with a
normal-force ramp); an ideal brake (:class:`~vtm_pin.physics.friction.IdealLock`) locks its joint at
engagement with the paper's momentum-consistent jump.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import Enum, IntEnum
from typing import NamedTuple, Protocol

import numpy as np

from ..exceptions import BrakeError
from ..numerics.integrators.base import StateEvent
from .friction import FrictionLaw, IdealLock


class BrakeEventKind(str, Enum):
    """A change of one brake's state (the value is the word used in summary.json)."""

    def __str__(self) -> str:
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(str(self.value), spec)

    ENGAGE = "engage"
    LOCK = "lock"  # an ideal brake locks
    STICK = "stick"
    START = "start"  # engaged at rest and cannot hold: starts sliding
    REVERSE = "reverse"  # slides the other way (reached rest and cannot hold, or a jump)
    SLIP = "slip"  # a stuck joint breaks loose


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
    kind: BrakeEventKind
    v: float
    holding_torque: float = float("nan")
    static_torque: float = float("nan")


#: Rate below which a braked joint counts as at rest [rad/s, m/s for prismatic joints]: well
#: above the integrator's round-off and event-location residuals (<= 1e-12 rad/s measured),
#: far below any rate that moves a joint measurably (1e-9 rad in a second).
REST_RATE = 1e-9
#: Relative round-off of torques and accelerations in the stick/slip decisions [-].
ROUNDOFF = 1e-9


class BrakeMode(IntEnum):
    """State of a joint's brake (codes stored per sample in simulation results)."""

    FREE = 0
    FORWARD = 1
    BACKWARD = 2
    STUCK = 3
    LOCKED = 4  # ideal lock: a prescribed lock or an ideal brake

    # Both read the mode as the int it is, not through Enum's ``value`` descriptor (~300 against
    # 70-85 ns a call, measured): they are asked for dozens of times a study case.

    @property
    def sliding(self) -> bool:
        """Whether the brake is sliding (kinetic friction acts)."""
        return 1 <= self <= 2  # FORWARD, BACKWARD

    @property
    def sign(self) -> float:
        """+1 when sliding forward, -1 backward, 0 otherwise."""
        return _SIGNS[self]


#: BrakeMode.sign by the mode's value.
_SIGNS = (0.0, 1.0, -1.0, 0.0, 0.0)


@dataclass(frozen=True)
class Brake:
    """One joint's brake: when it engages, and the friction law it follows (motor side).

    Attributes:
        joint: Joint name.
        delay: Engagement delay after the brake signal [s], >= 0.
        friction: The friction law, motor side (:class:`~vtm_pin.physics.friction.Coulomb`,
            :class:`~vtm_pin.physics.friction.Stribeck`);
            :class:`~vtm_pin.physics.friction.IdealLock` (the default) locks the joint at
            engagement.

    Joint-side torques are the law's times the joint's gear ratio, which the robot holds
    (:attr:`vtm_pin.physics.robot.Robot.gear_ratio`) and the methods below take as an argument.

    Raises:
        BrakeError: The delay is out of range.
    """

    joint: str
    delay: float = 0.0
    friction: FrictionLaw = field(default_factory=IdealLock)

    def __post_init__(self) -> None:
        if not (self.delay >= 0.0) or not math.isfinite(self.delay):
            raise BrakeError(
                f"Brake on '{self.joint}': delay {self.delay} s is not a finite number >= 0"
            )

    @property
    def ideal(self) -> bool:
        """The joint locks at engagement (an ideal lock, not a friction law)."""
        return isinstance(self.friction, IdealLock)

    def sliding(self, elapsed: float, v: float, ratio: float) -> float:
        """Joint-side kinetic torque magnitude [N m], ``elapsed`` s after engagement.

        Args:
            elapsed: Time since engagement [s].
            v: Joint rate in the direction of sliding [rad/s] (>= 0 while it slides; an
                integrator stepping past the instant it reaches rest sees it slightly below
                0, where the law continues smoothly); the law sees the motor speed ratio v.
            ratio: The joint's gear ratio [-].
        """
        return ratio * self.friction.sliding(elapsed, ratio * v)

    def static(self, elapsed: float, ratio: float) -> float:
        """Joint-side static (holding) torque limit [N m], ``elapsed`` s after engagement."""
        return ratio * self.friction.breakaway(elapsed)


def mode_of_motion(v: float) -> BrakeMode | None:
    """The sliding mode of a braked joint moving at rate ``v``; None if it is at rest.

    Args:
        v: The joint's rate [rad/s]; |v| <= :data:`REST_RATE` counts as rest.
    """
    if v > REST_RATE:
        return BrakeMode.FORWARD
    if v < -REST_RATE:
        return BrakeMode.BACKWARD
    return None


def mode_of_load(hold: float) -> BrakeMode:
    """The direction a joint at rest starts sliding in when released: that of its load.

    Args:
        hold: Torque needed to hold the joint at rest [N m]; the load acts against it.
    """
    return BrakeMode.BACKWARD if hold > 0.0 else BrakeMode.FORWARD


class StateEventKind(Enum):
    """The brake state events of a phase."""

    ZERO_VELOCITY = "zero_velocity"  # a sliding joint reaches v = 0
    SLIP = "slip"  # a stuck joint's holding torque reaches its static limit


@dataclass(frozen=True)
class BrakeStateEvent:
    """A brake state event of a phase and what it means.

    Attributes:
        kind: ``ZERO_VELOCITY`` (a sliding joint reaches v = 0) or ``SLIP`` (a stuck
            joint's holding torque reaches its static limit).
        joint: Index of the joint concerned.
        event: The event function for the integrator.
    """

    kind: StateEventKind
    joint: int
    event: StateEvent


class EventSpec(NamedTuple):
    """What a brake state event of a phase watches, without its event function.

    Attributes:
        kind: ``ZERO_VELOCITY`` or ``SLIP`` (see :class:`BrakeStateEvent`).
        joint: Index of the joint concerned.
        direction: The crossing that fires it (:class:`StateEvent`'s direction).
    """

    kind: StateEventKind
    joint: int
    direction: int


class BrakeWorld(Protocol):
    """What the brake state machine needs from the hybrid loop at one instant.

    Attributes:
        v: Joint rates [rad/s]; the machine zeroes those of joints it finds at rest.
        locked: Indices of the locked joints; the machine removes a joint that slips.
    """

    v: np.ndarray
    locked: list[int]

    def holding_torque(self, t: float, locked: Sequence[int]) -> np.ndarray:
        """Torques [N m] the locks of ``locked`` exert, with the current modes (0 if free)."""
        ...

    def accelerations(self, t: float) -> np.ndarray:
        """Joint accelerations [rad/s^2] with the current locks and modes (0 if locked)."""
        ...

    def stick(self, t: float, joints: Sequence[int]) -> None:
        """Lock ``joints`` (at rest) with the momentum-consistent transition rule."""
        ...


class BrakeMachine:
    """The brakes of one run: their modes, engagement times and events, and their rules.

    Modelica's ``Brake`` for every braked joint, decided together at each event (see
    :meth:`settle`); the state events that end a phase come from :meth:`state_events`.

    Args:
        brakes: Brake per joint index.
        joints: Joint names (for the events).
        ratio: Gear ratio per joint [-] (the robot's).
    """

    def __init__(
        self, brakes: Mapping[int, Brake], joints: Sequence[str], ratio: np.ndarray
    ) -> None:
        self.brakes = dict(brakes)
        self.joints = tuple(joints)
        self.ratio = np.asarray(ratio, dtype=float)
        self.modes = [BrakeMode.FREE] * len(self.joints)
        self.engaged: dict[int, float] = {}
        self.events: list[BrakeEvent] = []
        self._v_event: dict[int, float] = {}  # rates of the resting joints before zeroing

    def engage(self, t: float, i: int, v: float, locked: bool) -> bool:
        """Brake ``i`` engages at rate ``v`` [rad/s]; whether the joint must lock ideally.

        A joint moving faster than :data:`REST_RATE` starts sliding against its motion; a
        joint at rest is left to :meth:`settle`, which decides stick or slip once every
        event of this instant has been applied. A joint already ``locked`` stays locked.
        """
        self.engaged[i] = t
        if locked:
            return False
        name = self.joints[i]
        if self.brakes[i].ideal:
            self.modes[i] = BrakeMode.LOCKED
            self.events.append(BrakeEvent(t, name, BrakeEventKind.LOCK, v))
            return True
        self.events.append(BrakeEvent(t, name, BrakeEventKind.ENGAGE, v))
        self.modes[i] = mode_of_motion(v) or BrakeMode.FREE
        return False

    def static(self, t: float, i: int) -> float:
        """Joint ``i``'s static torque limit at ``t``, joint side [N m]."""
        return self.brakes[i].static(t - self.engaged[i], float(self.ratio[i]))

    def settle(self, t: float, world: BrakeWorld, due: Sequence[int] = ()) -> None:
        """Bring every engaged brake's mode in line with the state at ``t``.

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
        4. Every stuck joint must still hold under the loads of the final modes; one that
           cannot slips, worst-loaded first.

        A released joint stays released at this instant, so the decisions end.

        Args:
            t: Time [s].
            world: The hybrid loop's state and dynamics.
            due: Joints whose state event fired now (reached v = 0, or hit the static
                limit): a stuck one among them is released even within round-off of it.
        """
        self._held_by_motion: set[int] = set()  # stuck in step 3, by the acceleration test
        # A sliding joint whose zero-velocity event fired now is at rest, whatever rate its
        # event location left (|a| times the located instant's error: a stiff brake on a light
        # joint leaves more than REST_RATE, which would read as a reversal and chatter).
        arrived = {i for i in due if self.modes[i].sliding}
        self._follow_reversals(t, world, arrived)
        resting = self._resting(world, arrived)
        if resting:
            forced = {i for i in due if i in world.locked}  # at the static limit now
            released = self._hold_or_release(t, world, resting, forced)
            self._check_released(t, world, released)
            self._verify_stuck(t, world)

    def stick_rested(self, t: float, world: BrakeWorld, joint: int, hold: np.ndarray) -> None:
        """:meth:`settle`'s most common outcome, decided by the caller: ``joint`` sticks.

        Sliding ``joint`` reached rest (its zero-velocity event), no other braked joint is at
        rest or slides against its mode, and the holding torques ``hold`` [N m] with it
        locked are within every stuck joint's static limit and its own. :meth:`settle`
        would then set its rate to 0, stick it with these records and verify the stuck
        joints under unchanged loads: nothing more. The batched engine decides this across
        its lanes (:class:`vtm_pin.core.simulation.Rested`).
        """
        self._v_event = {joint: float(world.v[joint])}
        world.v[joint] = 0.0
        self._stick(t, world, [joint], hold, {joint: self.static(t, joint)})

    def _verify_stuck(self, t: float, world: BrakeWorld) -> None:
        """Step 4 of :meth:`settle`: stuck joints must hold under the final modes' loads.

        Step 3 changes sliding directions and sticks joints, which changes the loads on the
        joints stuck in step 2; one that can no longer be held slips (worst-loaded first).
        """
        for _ in range(len(self.joints)):
            stuck = [
                i
                for i in world.locked
                if self.modes[i] is BrakeMode.STUCK and i not in self._held_by_motion
            ]
            if not stuck:
                return
            hold = world.holding_torque(t, world.locked)
            limits = {i: self.static(t, i) for i in stuck}
            i = _worst_loaded(stuck, hold, limits, set())
            if i is None:
                return
            self._v_event.setdefault(i, 0.0)
            self._release(t, world, i, float(hold[i]), limits[i])
            self._check_released(t, world, [i])

    def event_specs(self, free: Sequence[int], locked: Sequence[int]) -> list[EventSpec]:
        """What :meth:`state_events` watches, in its order: sliding joints, then stuck ones.

        Args:
            free: Free joint indices, in the order of the phase state y = (q_f, v_f, ...).
            locked: Locked joint indices.
        """
        specs = []
        for j in free:
            mode = self.modes[j]
            if mode.sliding:
                # Sliding forward ends when v falls through 0; backward when it rises.
                direction = -1 if mode is BrakeMode.FORWARD else 1
                specs.append(EventSpec(StateEventKind.ZERO_VELOCITY, int(j), direction))
        for j in locked:
            brake = self.brakes.get(j)
            if self.modes[j] is BrakeMode.STUCK and brake is not None and not brake.ideal:
                specs.append(EventSpec(StateEventKind.SLIP, int(j), -1))
        return specs

    def state_events(
        self,
        free: Sequence[int],
        locked: Sequence[int],
        holding: Callable[[float, np.ndarray], np.ndarray],
    ) -> list[BrakeStateEvent]:
        """The state events that end a phase: sliding joints reaching rest, stuck ones slipping.

        Args:
            free: Free joint indices, in the order of the phase state y = (q_f, v_f, ...).
            locked: Locked joint indices.
            holding: Holding torques [N m] of all joints at (t, y) in this phase.
        """
        events = []
        k = len(free)
        position = {int(j): f for f, j in enumerate(free)}
        for kind, j, direction in self.event_specs(free, locked):
            if kind is StateEventKind.ZERO_VELOCITY:

                def rate(t: float, y: np.ndarray, i: int = k + position[j]) -> float:
                    return float(y[i])

                events.append(BrakeStateEvent(kind, j, StateEvent(rate, direction)))
            else:

                def margin(t: float, y: np.ndarray, j: int = j) -> float:
                    return self.slip_margin(t, j, holding(t, y))

                events.append(BrakeStateEvent(kind, j, StateEvent(margin, direction)))
        return events

    def slip_margin(self, t: float, j: int, hold: np.ndarray) -> float:
        """Stuck joint ``j``'s margin [N m] to slipping, given the holding torques ``hold``.

        The stick decision's own test (with its round-off), so a joint that stuck starts with
        a margin >= 0 and its slip is always a crossing of 0 from above.
        """
        scale = max(1.0, float(np.abs(hold).max()))
        return self.static(t, j) + ROUNDOFF * scale - abs(hold[j])

    def _hold_or_release(
        self, t: float, world: BrakeWorld, resting: list[int], forced: set[int]
    ) -> list[int]:
        """Step 2 of :meth:`settle`: release the worst-loaded joints, lock the rest."""
        limits = {i: self.static(t, i) for i in resting}
        released = []
        while True:
            hold = world.holding_torque(t, sorted({*world.locked, *resting}))
            i = _worst_loaded(resting, hold, limits, forced)
            if i is None:
                break
            self._release(t, world, i, float(hold[i]), limits[i])
            resting.remove(i)
            forced.discard(i)
            released.append(i)
        self._stick(t, world, [i for i in resting if i not in world.locked], hold, limits)
        return released

    def _check_released(self, t: float, world: BrakeWorld, released: list[int]) -> None:
        """Step 3 of :meth:`settle`: flip or stick released joints that would not slide.

        A joint that accelerates against its sliding direction (beyond round-off, now that
        the others slide too) slides the other way if that is consistent; if neither
        direction is, a friction torque between the two sliding torques holds it: it sticks.
        """
        for _ in range(2 * len(released)):
            wrong = self._against_motion(t, world, released)
            if wrong is None:
                return
            mode = self.modes[wrong]
            self.modes[wrong] = mode_of_motion(-mode.sign) or BrakeMode.FREE
            if self._against_motion(t, world, [wrong]) is None:
                self.events.append(BrakeEvent(t, self.joints[wrong], BrakeEventKind.REVERSE, 0.0))
                continue
            # Neither direction: the acceleration changes sign between the two sliding
            # torques, so a friction torque within them holds the joint (even where the
            # trial lock's multiplier, which the drives' computed torque shifts, says more).
            hold = world.holding_torque(t, [*world.locked, wrong])
            self._stick(t, world, [wrong], hold, {wrong: self.static(t, wrong)})
            self._held_by_motion.add(wrong)
            released = [i for i in released if i != wrong]

    def _against_motion(self, t: float, world: BrakeWorld, joints: Sequence[int]) -> int | None:
        """The first of ``joints`` (free, sliding from rest) accelerating against its mode.

        Accelerations within round-off (1e-9 of the largest) count as none.
        """
        a = world.accelerations(t)
        tolerance = ROUNDOFF * max(1.0, float(np.abs(a).max())) if a.size else 0.0
        for i in joints:
            if i not in world.locked and a[i] * self.modes[i].sign < -tolerance:
                return i
        return None

    def _stick(
        self,
        t: float,
        world: BrakeWorld,
        joints: Sequence[int],
        hold: np.ndarray,
        limits: Mapping[int, float],
    ) -> None:
        """Joints at rest whose brakes hold them stick: one consistent lock."""
        for i in joints:
            self.events.append(
                BrakeEvent(
                    t,
                    self.joints[i],
                    BrakeEventKind.STICK,
                    self._v_event[i],
                    float(hold[i]),
                    limits[i],
                )
            )
            self.modes[i] = BrakeMode.STUCK
        if joints:
            world.stick(t, joints)

    def _follow_reversals(self, t: float, world: BrakeWorld, arrived: set[int]) -> None:
        """Sliding joints whose rate has the other sign (after a jump) slide the other way.

        Joints that ``arrived`` at rest now (their zero-velocity event) are not reversals.
        """
        for i in self.engaged:
            mode, moving = self.modes[i], mode_of_motion(float(world.v[i]))
            if i in world.locked or i in arrived or moving is None or mode is moving:
                continue
            if mode.sliding or mode is BrakeMode.FREE:
                self.modes[i] = moving
                v = float(world.v[i])
                self.events.append(BrakeEvent(t, self.joints[i], BrakeEventKind.REVERSE, v))

    def _resting(self, world: BrakeWorld, arrived: set[int]) -> list[int]:
        """Braked joints at rest that need the stick/slip decision (their rates set to 0).

        Stuck joints, joints that ``arrived`` at rest now, and engaged joints at rest
        (|v| <= REST_RATE) that are free or sliding; not ideal brakes, nor joints locked by a
        prescribed lock.
        """
        resting = []
        self._v_event.clear()
        for i in sorted(self.engaged):
            mode = self.modes[i]
            if mode is BrakeMode.LOCKED or (i in world.locked and mode is not BrakeMode.STUCK):
                continue
            at_rest = i in arrived or mode_of_motion(float(world.v[i])) is None
            if mode is BrakeMode.STUCK or at_rest:
                resting.append(i)
                self._v_event[i] = float(world.v[i])
                world.v[i] = 0.0
        return resting

    def _release(self, t: float, world: BrakeWorld, i: int, hold: float, limit: float) -> None:
        """Joint ``i`` cannot be held: it slides in the direction of its load."""
        if i in world.locked:
            kind = BrakeEventKind.SLIP
            world.locked = [j for j in world.locked if j != i]
        else:
            kind = BrakeEventKind.REVERSE if self.modes[i].sliding else BrakeEventKind.START
        self.modes[i] = mode_of_load(hold)
        self.events.append(BrakeEvent(t, self.joints[i], kind, self._v_event[i], hold, limit))


def _worst_loaded(
    resting: Sequence[int], hold: np.ndarray, limits: Mapping[int, float], forced: set[int]
) -> int | None:
    """The held joint to release first: a forced one, else the largest |hold| / limit > 1."""
    if forced:
        return min(forced)
    worst, ratio = None, 1.0
    for i in resting:
        if not _holdable(float(hold[i]), limits[i], hold):
            r = math.inf if limits[i] == 0.0 else abs(hold[i]) / limits[i]
            if worst is None or r > ratio:
                worst, ratio = i, r
    return worst


def _holdable(hold: float, limit: float, holds: np.ndarray) -> bool:
    """Whether a brake with static ``limit`` [N m] holds a joint needing ``hold`` [N m].

    A load within round-off (:data:`ROUNDOFF` of the largest holding torque, at least 1 N m
    times it) counts as none: a brake whose normal force is still 0 at engagement then
    holds a joint with no load, instead of starting it in the direction of a round-off sign.
    """
    scale = max(1.0, float(np.abs(holds).max())) if holds.size else 1.0
    return abs(hold) <= limit + ROUNDOFF * scale
