"""What to simulate, validated once: robot, initial state, duration, locks, brakes, stop, loops.

A :class:`Problem` is checked when it is built, and :func:`vtm_pin.core.simulation.simulate` trusts
it. Run settings (integrator, transition rule, progress display) are not part of it. A
variant (another speed, brake torque or stop) is a cheap :meth:`Problem.replace` that reuses
the loaded robot model. Errors are :class:`~vtm_pin.exceptions.ProblemError` naming the key
in a scenario file's terms (``events[1].lock``, ``brakes``, ``stop.t``), which the scenario
reader turns into a message naming the file.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..exceptions import ProblemError, excerpt
from ..physics.brakes import Brake
from ..physics.robot import Robot
from ..physics.stop import Stop
from .holonomic import FrameConstraint

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
class Problem:
    """A validated simulation problem.

    Attributes:
        robot: The robot (drives applied).
        q0: Initial joint positions [rad], shape (n,).
        v0: Initial joint velocities [rad/s], shape (n,); with a stop, the rates the drives
            hold until the signal.
        duration: End time [s], > 0.
        events: Ideal lock events with 0 <= t <= duration; a joint locks at most once.
        brakes: One brake per braked joint; they act only after a stop signal.
        stop: The emergency stop, if any.
        constraints: Frame constraints active from t = 0 (loop closures, dockings).
        baumgarte: Gains (alpha, beta) [1/s] of the Baumgarte stabilisation of the frame
            constraints between events; (0, 0) integrates the bare index-1 equations.

    Raises:
        ProblemError: Something the simulation cannot run, naming the key.
    """

    robot: Robot
    q0: np.ndarray
    v0: np.ndarray
    duration: float
    events: tuple[LockEvent, ...] = ()
    brakes: tuple[Brake, ...] = ()
    stop: Stop | None = None
    constraints: tuple[FrameConstraint, ...] = ()
    baumgarte: tuple[float, float] = DEFAULT_BAUMGARTE

    def __post_init__(self) -> None:
        n = self.robot.nv
        for name, key in (("q0", "initial.q"), ("v0", "initial.v")):
            value = np.array(getattr(self, name), dtype=float).reshape(-1)
            if value.size != n:
                raise ProblemError(key, f"has {value.size} values but the robot has {n} joints")
            if not np.isfinite(value).all():
                raise ProblemError(key, "values must be finite numbers")
            value.flags.writeable = False
            object.__setattr__(self, name, value)
        for name in ("events", "brakes", "constraints"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        if not (self.duration > 0.0) or not math.isfinite(self.duration):
            raise ProblemError("duration", f"{self.duration} is not a finite number of s > 0")
        _check_events(self)
        _check_brakes(self)

    def replace(self, **changes: Any) -> Problem:
        """A variant with some fields changed (validated again; the robot is reused)."""
        return dataclasses.replace(self, **changes)

    @property
    def frames(self) -> tuple[FrameConstraint, ...]:
        """Every frame constraint: active from t = 0, and activated by events."""
        return self.constraints + tuple(c for e in self.events for c in e.activate)


def check_transition(problem: Problem, transition: str) -> None:
    """Refuse a transition rule the problem cannot use (the naive rule with frames).

    Raises:
        ProblemError: Naming the ``transition`` key.
    """
    if transition == "naive" and problem.frames:
        raise ProblemError("transition", "naive is defined for joint locks only")


def _check_events(problem: Problem) -> None:
    """Event times within the run, known joints, each joint locked at most once."""
    joints = problem.robot.joints
    locked: set[str] = set()
    order = sorted(range(len(problem.events)), key=lambda k: problem.events[k].t)
    for k in order:
        event = problem.events[k]
        if not 0.0 <= event.t <= problem.duration:
            raise ProblemError(
                f"events[{k}].t", f"{event.t} s is outside [0, duration = {problem.duration}] s"
            )
        if not event.lock and not event.activate:
            raise ProblemError(f"events[{k}]", "needs 'lock' or 'activate' (or both)")
        for joint in event.lock:
            _check_joint(joints, joint, f"events[{k}].lock")
            if joint in locked:
                raise ProblemError(
                    f"events[{k}].lock",
                    f"joint '{excerpt(joint)}' locks again at t = {event.t} s but is already "
                    "locked",
                )
            locked.add(joint)


def _check_brakes(problem: Problem) -> None:
    """Known joints, one brake each, a stop to engage them, no frame constraints with them."""
    seen: set[str] = set()
    joints = problem.robot.joints
    for brake in problem.brakes:
        if brake.joint not in joints or brake.joint in seen:
            key = f"brakes.{excerpt(brake.joint)}"
            _check_joint(joints, brake.joint, key)
            raise ProblemError(key, "a joint has one brake")
        seen.add(brake.joint)
    if problem.brakes and problem.stop is None:
        raise ProblemError("brakes", "brakes act after a stop signal: add a 'stop' key")
    if problem.brakes and problem.frames:
        raise ProblemError(
            "brakes", "brakes together with loop closures or dockings are not supported"
        )
    stop = problem.stop
    if stop is not None and stop.t > problem.duration:
        raise ProblemError(
            "stop.t", f"{stop.t} s is after the end (duration = {problem.duration} s)"
        )
    if stop is not None and stop.torque_limit is not None:
        if np.shape(stop.torque_limit) != (problem.robot.nv,):
            raise ProblemError("stop.torque_limit", f"needs one value per joint ({_of(problem)})")


def _check_joint(joints: Sequence[str], joint: str, key: str) -> None:
    if joint not in joints:
        raise ProblemError(
            key, f"unknown joint '{excerpt(joint)}'; the joints are: {', '.join(joints)}"
        )


def _of(problem: Problem) -> str:
    return f"{problem.robot.nv}: {', '.join(problem.robot.joints)}"
