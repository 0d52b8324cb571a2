"""Hybrid simulation: integrate to the next lock, apply the transition, continue."""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .constraints import lock_jacobian
from .dynamics import compute_M
from .exceptions import SimulationError
from .integrators import Integrator
from .robot import Robot
from .topology import Topology
from .transitions import TRANSITIONS, TransitionResult


@dataclass(frozen=True)
class LockEvent:
    """Joints that lock at a given time.

    Attributes:
        t: Event time [s].
        lock: Names of the joints that lock at ``t``.
    """

    t: float
    lock: tuple[str, ...]


@dataclass(frozen=True)
class EventRecord:
    """What happened at one event.

    Attributes:
        t: Event time [s].
        lock: Joints newly locked.
        locked_before: Joints already locked before the event (the persistent constraints J1).
        q: Configuration at the event [rad].
        v_minus: Velocity just before [rad/s].
        transition: The transition result (v_plus, Lambda, energy loss, momenta).
    """

    t: float
    lock: tuple[str, ...]
    locked_before: tuple[str, ...]
    q: np.ndarray
    v_minus: np.ndarray
    transition: TransitionResult

    @property
    def v_plus(self) -> np.ndarray:
        """Velocity just after [rad/s]."""
        return self.transition.v_plus


@dataclass(frozen=True)
class SimulationResult:
    """A simulated motion with its events.

    Attributes:
        joints: Joint names, the columns of ``q`` and ``v``.
        t: Sample times [s], shape (k,). An event time appears twice: before and after the jump.
        q: Joint positions [rad], shape (k, n).
        v: Joint velocities [rad/s], shape (k, n).
        free: Which joints are free at each sample, shape (k, n), bool.
        events: One record per event, in time order.
        transition: Name of the transition rule used.
        integrator: Name of the integrator used.
        rhs_evals: Right-hand-side evaluations.
        steps: Integrator steps.
        wall_time: Seconds spent in the simulation loop [s].
    """

    joints: tuple[str, ...]
    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    free: np.ndarray
    events: tuple[EventRecord, ...]
    transition: str
    integrator: str
    rhs_evals: int
    steps: int
    wall_time: float


def simulate(
    robot: Robot,
    q0: np.ndarray,
    v0: np.ndarray,
    duration: float,
    events: Sequence[LockEvent],
    integrator: Integrator,
    transition: str = "kkt",
) -> SimulationResult:
    """Simulate the robot released at (q0, v0) with joints locking at the given times.

    No joint torques act (drives off); gravity is the model's. Locks are time events: every
    integration interval ends exactly on the next event time. At an event the transition rule
    maps v- to v+ with J1 the joints already locked and J2 those locking now.

    Args:
        robot: The robot.
        q0: Initial joint positions [rad], shape (n,).
        v0: Initial joint velocities [rad/s], shape (n,).
        duration: End time [s], > 0.
        events: Lock events with 0 <= t <= duration; a joint may lock only once.
        integrator: How to integrate between events.
        transition: Name in :data:`vtm_pin.transitions.TRANSITIONS`.

    Returns:
        The sampled motion and event records.

    Raises:
        SimulationError: Bad arguments, or the state became non-finite.
        JointNotFound: An event names an unknown joint.
    """
    if transition not in TRANSITIONS:
        raise SimulationError(
            f"Unknown transition '{transition}'; allowed: {', '.join(sorted(TRANSITIONS))}"
        )
    if not duration > 0.0:
        raise SimulationError(f"Duration {duration} is not a positive number of seconds")
    n = robot.nv
    q = np.array(q0, dtype=float).reshape(n)
    v = np.array(v0, dtype=float).reshape(n)
    ordered = sorted(events, key=lambda e: e.t)
    for lock_event in ordered:
        if not 0.0 <= lock_event.t <= duration:
            raise SimulationError(f"Event at t = {lock_event.t} s is outside [0, {duration}] s")
    rule = TRANSITIONS[transition]
    data = robot.model.createData()
    start = time.perf_counter()

    locked: list[int] = []
    topology = Topology(robot, locked, q)
    ts: list[np.ndarray] = []
    qs: list[np.ndarray] = []
    vs: list[np.ndarray] = []
    frees: list[np.ndarray] = []
    records: list[EventRecord] = []
    rhs_evals = 0
    steps = 0
    t = 0.0
    stops: list[tuple[float, LockEvent | None]] = [(e.t, e) for e in ordered]
    for t_end, event in [*stops, (duration, None)]:
        segment = integrator.integrate(topology.rhs, t, topology.split(q, v), t_end)
        rhs_evals += segment.rhs_evals
        steps += segment.t.size - 1
        if not np.all(np.isfinite(segment.y)):
            raise SimulationError(
                f"State became non-finite between t = {t} s and {t_end} s; "
                f"reduce the step size of {integrator.name}"
            )
        block_q = np.empty((segment.t.size, n))
        block_v = np.zeros((segment.t.size, n))
        k = topology.n_free
        block_q[:, topology.locked] = topology.q_locked
        block_q[:, topology.free] = segment.y[:, :k]
        block_v[:, topology.free] = segment.y[:, k:]
        mask = np.zeros(n, dtype=bool)
        mask[topology.free] = True
        ts.append(segment.t)
        qs.append(block_q)
        vs.append(block_v)
        frees.append(np.broadcast_to(mask, block_q.shape))
        t = t_end
        q, v = block_q[-1].copy(), block_v[-1].copy()
        if event is None:
            break
        new = robot.joint_indices(event.lock)
        for i, name in zip(new, event.lock, strict=True):
            if i in locked:
                raise SimulationError(f"Joint '{name}' is locked twice (again at t = {t} s)")
        M = compute_M(robot.model, data, q)
        result = rule(M, lock_jacobian(n, locked), lock_jacobian(n, new), v)
        records.append(
            EventRecord(
                t=t,
                lock=tuple(event.lock),
                locked_before=tuple(robot.joints[i] for i in locked),
                q=q.copy(),
                v_minus=v.copy(),
                transition=result,
            )
        )
        locked = locked + new
        topology = Topology(robot, locked, q)
        v = result.v_plus.copy()
        v[list(locked)] = 0.0
    wall_time = time.perf_counter() - start
    return SimulationResult(
        joints=robot.joints,
        t=np.concatenate(ts),
        q=np.vstack(qs),
        v=np.vstack(vs),
        free=np.vstack(frees),
        events=tuple(records),
        transition=transition,
        integrator=integrator.name,
        rhs_evals=rhs_evals,
        steps=steps,
        wall_time=wall_time,
    )
