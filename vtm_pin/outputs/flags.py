"""Honest flags: where a stopping figure rests on assumptions that break.

A figure a safety engineer signs must not silently describe something else than a stop:

* ``brake_cannot_hold``: a brake's static torque (joint side, full normal force; 0 for a joint
  without a brake that no prescribed lock holds) is below the gravity load of its joint with
  the arm held, at the signal or at some instant of the stop. Such an arm cannot be held on
  its brakes: it collapses, and its tested joint's angle understates what moves (the tool's
  drop is quoted);
* ``brake_cannot_stop``: a brake's least kinetic torque (what is left to stop a moving joint)
  is below its joint's gravity load: a joint that moves slides on under its own weight (to
  the speed at which a speed-dependent brake balances it), whatever its static torque holds;
* ``drive_cannot_hold``: in a category-2 stop (the drives hold the arm, no brake engages), a
  joint's gravity load after the ramp exceeds its drive torque limit: the drives cannot hold
  the arm at rest and it sags (the brake flags above are not checked: no brake acts);
* ``joint_slips``: the engaged brake of a joint other than the tested one gave way (it could
  not hold its joint at rest: it started sliding from rest, or slipped when stuck), so the
  arm moved where the test says only one joint moves;
* ``payload_above_rated``: a payload above the robot data file's rated payload;
* ``payload_implausible``: a payload heavier than the arm itself, or whose centre of mass is
  further from its frame than the arm is long (the robot has no rated payload to compare);
* ``tool_speed_implausible``: a peak tool speed during the stop above what the drives could
  give from the pose at the signal, every joint at its URDF velocity limit (the arm falls or
  is whipped by a lock);
* ``not_stopped``: some joint still moves at the end of the run;
* ``worn_brake_cannot_hold``: with the bounds' brake wear, a brake cannot hold the load (set by
  :func:`vtm_pin.outputs.figures.bounded`): the upper bounds describe a collapsing arm;
* ``bounds_not_stopped``: a run the bounds need (worn brakes, a moved calibrated figure) still
  moves at the end: no upper bound is given (set by :func:`vtm_pin.outputs.figures.bounded`).

Flags are a case's record, never a failure: the figures stay, with the flag beside them.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ..core.results import SimulationResult
from ..files.model_cache import ModelCache
from ..physics.brakes import Brake, BrakeEventKind
from ..physics.kinematics import (
    cached_chain,
    compute_tool_jacobian,
    kinematics_key,
    pinocchio_data,
)
from ..physics.payload import Payload, attachment, body_parameters
from ..physics.robot import Robot
from .stopping import StoppingReport

#: The flag kinds, in the order reports list them.
KINDS = (
    "brake_cannot_hold",
    "brake_cannot_stop",
    "drive_cannot_hold",
    "worn_brake_cannot_hold",
    "bounds_not_stopped",
    "joint_slips",
    "not_stopped",
    "payload_above_rated",
    "payload_implausible",
    "tool_speed_implausible",
)
#: Relative slack of the holding check and the rated payload (round-off, not a margin) [-].
SLACK = 1e-9
#: States of a stop at which the brakes' torques are checked against the gravity loads.
LOAD_SAMPLES = 50

#: :func:`arm_length` of the robots seen, by kinematics.
_LENGTHS = ModelCache(16)


@dataclass(frozen=True)
class Flag:
    """A broken assumption behind a case's figures.

    Attributes:
        kind: One of :data:`KINDS`.
        message: What broke, one line, with the figures.
        joints: The joints concerned.
        value: The figure that broke (a holding margin [N m], a mass [kg], a speed [m/s]).
        limit: What it was checked against, in the same unit.
    """

    kind: str
    message: str
    joints: tuple[str, ...] = ()
    value: float = math.nan
    limit: float = math.nan


def static_torques(robot: Robot, brakes: Sequence[Brake]) -> np.ndarray:
    """Each joint's static brake torque at full normal force, joint side [N m].

    NaN for joints without a brake, +inf for ideal brakes.
    """
    static = np.full(robot.nv, np.nan)
    for brake in brakes:
        i = robot.joint_index(brake.joint)
        static[i] = math.inf if brake.ideal else brake.static(math.inf, float(robot.gear_ratio[i]))
    return static


def gravity_loads(robot: Robot, q: np.ndarray) -> np.ndarray:
    """|g(q)|: the torque each joint's lock gives to hold the arm still [N m], shape (k, n).

    Args:
        robot: The robot (payload attached).
        q: Configurations [rad], shape (k, n).
    """
    model = robot.model
    data = pinocchio_data(robot)
    rows = np.atleast_2d(q)
    loads = np.empty((len(rows), model.nv))
    for i, row in enumerate(rows):
        loads[i] = pin.computeGeneralizedGravity(model, data, row)
    return np.abs(loads)


def kinetic_torques(robot: Robot, brakes: Sequence[Brake]) -> np.ndarray:
    """Each joint's least kinetic brake torque at full normal force, joint side [N m].

    What is left to stop a moving joint (a Stribeck brake's far from rest). NaN without a
    brake, +inf for ideal brakes.
    """
    kinetic = np.full(robot.nv, np.nan)
    for brake in brakes:
        i = robot.joint_index(brake.joint)
        ratio = float(robot.gear_ratio[i])
        kinetic[i] = math.inf if brake.ideal else ratio * brake.friction.least_kinetic
    return kinetic


def holding_flags(
    robot: Robot, brakes: Sequence[Brake], result: SimulationResult, report: StoppingReport
) -> list[Flag]:
    """``brake_cannot_hold`` and ``brake_cannot_stop`` from the signal on (see the module).

    The loads are checked at the signal, at the end and at :data:`LOAD_SAMPLES` states evenly
    between (a gravity load changes smoothly with the pose; every sample would cost a study's
    case about 2 ms). Where every brake's torque is at least its joint's load in any pose
    (:func:`gravity_bounds`), no load can exceed it: neither flag is raised, and the loads are
    not computed (~0.06 ms of a UR10 study case). A payload copy's bound is bounded from its
    robot's (:func:`_payload_bounds`), so a drawn payload's case computes none.
    """
    static, kinetic, above = _brake_torques(robot, brakes, result.free[-1])
    if above:
        return []
    after = np.flatnonzero(result.t >= report.signal_time)
    if after.size == 0:
        return []
    checks = (
        ("brake_cannot_hold", static, "hold the arm's weight", "the arm collapses"),
        (
            "brake_cannot_stop",
            kinetic,
            "stop its joint once it moves",
            "a moving arm slides on under its own weight",
        ),
    )
    loads = gravity_loads(robot, result.q[after[load_rows(after.size)]])
    out = []
    for kind, torques, what, consequence in checks:
        flag = _load_flag(robot, report, loads, torques, kind, what, consequence)
        if flag is not None:
            out.append(flag)
    return out


def _brake_torques(
    robot: Robot, brakes: Sequence[Brake], free: np.ndarray
) -> tuple[np.ndarray, np.ndarray, bool]:
    """The brakes' static and least kinetic torques [N m] checked against the loads.

    A joint without a brake holds nothing (0), unless a prescribed lock holds it to the end
    (not ``free``: NaN, not checked). Also whether every brake's torques are at least its
    joint's largest load over every pose (:func:`gravity_bounds`). Kept in the robot's cache
    by the brakes and ``free`` (a study's cases share them): read-only arrays. The torques
    depend on the brakes and the gear ratios only, so the robots that differ from it in a
    payload share them (a drawn payload's case computes only its bound).
    """

    def torques() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        static, kinetic = static_torques(robot, brakes), kinetic_torques(robot, brakes)
        for each in (static, kinetic):
            each[np.isnan(each) & free] = 0.0
            each.flags.writeable = False
        return static, kinetic, np.fmin(static, kinetic)  # NaN where both are (not checked)

    def above(weakest: np.ndarray) -> bool:
        bounds = _payload_bounds(robot)
        if bounds is None:
            bounds = gravity_bounds(robot)
        return bounds is not None and _above(weakest, bounds)

    key = ("brake_torques", tuple(brakes), free.tobytes())
    try:
        hash(key)
    except TypeError:  # a friction law of the caller's own with an unhashable field: not kept
        static, kinetic, weakest = torques()
        return static, kinetic, above(weakest)
    static, kinetic, weakest = robot.cache.get(key, torques, kinematic=True)
    return (
        static,
        kinetic,
        robot.cache.get(("brakes_above", *key[1:]), lambda: above(weakest)),
    )


def _above(torques: np.ndarray, bounds: np.ndarray) -> bool:
    """Whether every brake torque (NaN: no brake, not checked) is at least its bound [N m]."""
    return bool((np.isnan(torques) | (torques >= bounds)).all())


def gravity_bounds(robot: Robot) -> np.ndarray | None:
    """An upper bound of each joint's gravity load |g_j(q)| over every pose [N m], or None.

    A turning joint j with axis a_j carries a subtree whose first moment about its origin is
    h_j = sum_b m_b (c_b - o_j) (bodies b: mass m_b, centre of mass c_b); its load is
    |a_j . (h_j x g)| <= |g x a_j| |P_j h_j|, with P_j the projection across a_j. In joint
    j's own frame h_j = v_j + sum_k h_k over its child joints k, where
    v_j = m_j c_j + sum_k M_k t_k is fixed (c_j its body's centre of mass, M_k and t_k a
    child's subtree mass and offset) and each h_k turns: |P_j h_j| <= |P_j v_j| + sum_k H_k,
    with H_k = |v_k| + sum H over k's children. |g x a_j| is at most |g|, and is itself for a
    joint on the base, whose axis does not move. None for a model with a sliding joint or a
    joint the NumPy kinematics do not take. Kept in the robot's cache (it depends on the
    bodies' inertias, a payload's included).
    """
    return robot.cache.get("gravity_bounds", lambda: (_gravity_bounds(robot),))[0]


def _gravity_bounds(robot: Robot) -> np.ndarray | None:
    chain = cached_chain(robot)
    if chain is None or not all(chain.revolute[1:]):
        return None
    return _bounds_of(robot, body_parameters(robot))


def _bounds_of(robot: Robot, parameters: np.ndarray) -> np.ndarray:
    """:func:`gravity_bounds` of the robot's kinematics with these bodies' parameters."""
    chain = cached_chain(robot)
    assert chain is not None
    parents, factor, index = robot.cache.get(
        "gravity_bound_factors", lambda: _bound_factors(robot), kinematic=True
    )
    mass = parameters[:, 0].tolist()
    subtree = list(mass)  # M_k: the mass each joint carries [kg]
    for j in range(len(mass) - 1, 0, -1):
        subtree[parents[j]] += subtree[j]
    fixed = parameters[:, 1:4].copy()  # m_j c_j, then v_j [kg m]
    np.add.at(fixed, parents[1:], np.array(subtree[1:])[:, None] * chain.translations[1:])
    norms = np.sqrt(np.einsum("ji,ji->j", fixed, fixed))
    turning = norms.tolist()  # H_j: the bound of |h_j| [kg m], children added below
    for j in range(len(mass) - 1, 0, -1):
        turning[parents[j]] += turning[j]
    children = np.array(turning) - norms  # the sum of H_k of each joint's children
    across = fixed - np.einsum("ji,ji->j", fixed, chain.axes)[:, None] * chain.axes
    out = np.zeros(robot.nv)
    out[index] = (factor * (np.sqrt(np.einsum("ji,ji->j", across, across)) + children))[1:]
    return out


def _payload_bounds(robot: Robot) -> np.ndarray | None:
    """An upper bound of a payload copy's :func:`gravity_bounds` from its robot's [N m], or None.

    The bound is a sum of norms of quantities linear in the bodies' parameters, so the bound
    of a sum of parameters is at most the sum of their bounds: the robot's, and the payload's
    alone (mass m at lever c in its joint's frame). That is at most m (U + |c| W), U the bound
    of a unit mass at the joint's origin and W |g x a_j| (or |g|) for the joint and each joint
    it hangs from. No per-case bound is computed then (a drawn payload's case: ~0.03 ms); a
    slack of :data:`SLACK` times the largest bound or 1 N m, whichever is larger, covers the
    round-off (bounds near 0 round to either side of each other). None for a robot without an
    :func:`~vtm_pin.physics.payload.attachment`, or whose robot has no bound.
    """
    made = attachment(robot)
    base = None if made is None else made.robot()
    bounds = None if base is None else gravity_bounds(base)
    if made is None or bounds is None:
        return None
    terms = robot.cache.get(
        ("gravity_bound_unit", made.joint), lambda: _unit_bounds(robot, made.joint), kinematic=True
    )
    mass, moment = made.mass, made.mass * math.hypot(*made.lever)
    # Six floats a UR10: plain Python costs half NumPy's small-array calls.
    upper = [b + mass * u + moment * w for b, (u, w) in zip(bounds.tolist(), terms, strict=True)]
    slack = SLACK * max(1.0, *upper)  # [N m], as _load_flag's
    return np.array([each * (1.0 + SLACK) + slack for each in upper])


def _unit_bounds(robot: Robot, joint: int) -> tuple[tuple[float, float], ...]:
    """U and W of :func:`_payload_bounds` for a payload on ``joint``'s body, per coordinate.

    [N m / kg, N / kg], as pairs of floats.
    """
    parents, factor, index = robot.cache.get(
        "gravity_bound_factors", lambda: _bound_factors(robot), kinematic=True
    )
    unit = np.zeros((len(parents), 10))
    unit[joint, 0] = 1.0
    hanging = np.zeros(len(parents))
    while joint != 0:
        hanging[joint] = factor[joint]
        joint = int(parents[joint])
    lever = np.zeros(robot.nv)
    lever[index] = hanging[1:]
    return tuple(zip(_bounds_of(robot, unit).tolist(), lever.tolist(), strict=True))


def _bound_factors(robot: Robot) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What :func:`gravity_bounds` takes from the kinematics, kept in the robot's cache.

    Returns:
        Each joint's parent; |g x a_j| for a joint on the base (its axis in the world), |g|
        for the others (joint 0, the world, first; unused); each joint's coordinate.
    """
    chain = cached_chain(robot)
    assert chain is not None
    parents = np.array(chain.parents)
    g = np.asarray(robot.model.gravity.linear, dtype=float)
    world = np.einsum("jab,jb->ja", chain.rotations, chain.axes)  # a base joint's axis
    on_base = np.linalg.norm(np.cross(g, world), axis=1)
    factor = np.where(parents == 0, on_base, np.linalg.norm(g))
    return parents, factor, np.array(chain.index[1:])


@functools.lru_cache(maxsize=256)
def load_rows(count: int) -> np.ndarray:
    """Which of ``count`` states the loads are checked at (indices, read-only).

    :data:`LOAD_SAMPLES` evenly spaced, the first and the last included (all of them if
    fewer), in order; kept per count, as a stop's sample counts repeat across a study.
    """
    rows = np.unique(np.linspace(0, count - 1, LOAD_SAMPLES).round().astype(int))
    rows.flags.writeable = False
    return rows


def _load_flag(
    robot: Robot,
    report: StoppingReport,
    loads: np.ndarray,
    torques: np.ndarray,
    kind: str,
    what: str,
    consequence: str,
) -> Flag | None:
    """A flag if some joint's brake ``torques`` are below its gravity ``loads`` [N m]."""
    margins = torques - loads
    slack = SLACK * max(1.0, float(loads.max()))
    worst = np.fmin.reduce(margins, axis=0, initial=math.inf)  # NaN (no brake) ignored
    if not worst.min() < -slack:
        return None
    weak = [i for i in range(robot.nv) if worst[i] < -slack]
    j = min(weak, key=lambda i: worst[i])
    names = tuple(robot.joints[i] for i in weak)
    when = "at the signal" if margins[0, j] < -slack else "during the stop"
    load = float(np.max(loads[:, j]))
    return Flag(
        kind,
        f"the brake of {', '.join(names)} cannot {what} {when} ({robot.joints[j]}: "
        f"{'static' if kind == 'brake_cannot_hold' else 'sliding'} torque {torques[j]:.4g} N m"
        f"{' (no brake)' if torques[j] == 0.0 else ''} against a gravity load of up to "
        f"{load:.4g} N m, joint side): {consequence}; the tool drops {tool_drop(report):.3g} m, "
        "more than the tested joint's angle says",
        names,
        float(worst[j]),
        0.0,
    )


def drive_flag(robot: Robot, result: SimulationResult, report: StoppingReport) -> Flag | None:
    """``drive_cannot_hold``: a category-2 stop whose drives cannot hold the gravity load.

    The loads |g(q)| are checked against ``stop.torque_limit`` at :data:`LOAD_SAMPLES` states
    from the end of the ramp (when the drives start to hold) to the end of the run; the last
    state if the run ends before the ramp does. The ramp itself may need more than the
    holding torque; a ramp the limit slows shows in the stopping time, not here.
    """
    stop = result.stop
    if stop is None or stop.category != 2 or stop.torque_limit is None:
        return None
    assert stop.ramp_time is not None
    hold = np.flatnonzero(result.t >= stop.t + stop.ramp_time)
    if hold.size == 0:
        hold = np.array([result.t.size - 1])
    loads = gravity_loads(robot, result.q[hold[load_rows(hold.size)]])
    limit = np.asarray(stop.torque_limit, dtype=float)
    margins = limit - loads
    slack = SLACK * max(1.0, float(np.max(loads)))
    worst = np.min(margins, axis=0)
    weak = [i for i in range(robot.nv) if worst[i] < -slack]
    if not weak:
        return None
    j = min(weak, key=lambda i: worst[i])
    names = tuple(robot.joints[i] for i in weak)
    return Flag(
        "drive_cannot_hold",
        f"the drives of {', '.join(names)} cannot hold the arm's weight after the category-2 "
        f"ramp ({robot.joints[j]}: torque limit {limit[j]:.4g} N m against a gravity load of "
        f"up to {float(np.max(loads[:, j])):.4g} N m, joint side): the arm sags on its drives; "
        f"the tool drops {tool_drop(report):.3g} m",
        names,
        float(worst[j]),
        0.0,
    )


def tool_drop(report: StoppingReport) -> float:
    """How far the tool frame falls below its height at the signal during the stop [m]."""
    path = report.tcp_path
    return float(max(0.0, path[0, 2] - np.min(path[:, 2]))) if len(path) else 0.0


def slip_flag(result: SimulationResult, tested: str | None) -> Flag | None:
    """``joint_slips`` if the engaged brake of a joint other than ``tested`` gave way.

    Only the tested joint moves in an Annex-B test. A joint whose brake could not hold it at
    rest (it started sliding from rest, or slipped when stuck) breaks that. Motion before a
    brake engages (the joints fall or swing during the brake delay) and the slide to rest
    after it are not slips; their size is the ``other_travel`` figure.
    """
    giving = (BrakeEventKind.START, BrakeEventKind.SLIP)
    slid = {e.joint for e in result.brake_events if e.kind in giving}
    names = tuple(j for j in result.joints if j != tested and j in slid)
    if not names:
        return None
    i0 = 0 if result.stop is None else int(np.argmax(result.t >= result.stop.t))
    travel = [
        float(
            np.max(
                np.abs(result.q[i0:, result.joints.index(n)] - result.q[i0, result.joints.index(n)])
            )
        )
        for n in names
    ]
    shown = ", ".join(f"{n} {x:.3g}" for n, x in zip(names, travel, strict=True))
    return Flag(
        "joint_slips",
        f"the brake of {', '.join(names)} gave way (it could not hold its joint at rest; travel "
        f"after the signal: {shown} rad or m), so more than the "
        f"{'tested joint' if tested else 'stop alone'} moved",
        names,
        max(travel),
    )


def _arm_mass(robot: Robot, payload: Payload) -> float:
    """The arm's mass without the payload [kg]: its bodies', the fixed base's included.

    Summed over the model's inertias only where it is compared (no rated payload): ~10 us a
    case.
    """
    return float(sum(inertia.mass for inertia in robot.model.inertias)) - payload.mass


def payload_flags(robot: Robot, payload: Payload | None) -> list[Flag]:
    """``payload_above_rated`` and ``payload_implausible`` of a case's payload."""
    if payload is None:
        return []
    flags = []
    rated = robot.rated_payload
    if rated is not None and payload.mass > rated * (1.0 + SLACK):
        flags.append(
            Flag(
                "payload_above_rated",
                f"the payload of {payload.mass:g} kg is above the rated payload of {rated:g} kg "
                f"(robot data of {robot.name})",
                value=payload.mass,
                limit=rated,
            )
        )
    arm_mass = _arm_mass(robot, payload) if rated is None else math.inf
    if payload.mass > arm_mass:
        flags.append(
            Flag(
                "payload_implausible",
                f"the payload of {payload.mass:g} kg is heavier than the arm itself "
                f"({arm_mass:.3g} kg) and the robot data give no rated payload",
                value=payload.mass,
                limit=arm_mass,
            )
        )
    length = arm_length(robot)
    com = np.asarray(payload.com, dtype=float)
    offset = math.sqrt(float(com.dot(com)))  # np.linalg.norm's own sum, without its checks
    if offset > length:
        flags.append(
            Flag(
                "payload_implausible",
                f"the payload's centre of mass is {offset:.3g} m from its frame, more than the "
                f"arm is long ({length:.3g} m)",
                value=offset,
                limit=length,
            )
        )
    return flags


def arm_length(robot: Robot) -> float:
    """Sum of the distances between consecutive joint origins and to the tool frame [m].

    Kept per kinematics (a study's payload copies of one robot share it).
    """
    key = (robot.source, robot.tool_frame, kinematics_key(robot))
    return _LENGTHS.get(key, lambda: _arm_length(robot))


def _arm_length(robot: Robot) -> float:
    model = robot.model
    total = sum(float(np.linalg.norm(p.translation)) for p in list(model.jointPlacements)[1:])
    tool = model.frames[model.getFrameId(robot.tool_frame)] if robot.tool_frame else None
    return total + (float(np.linalg.norm(tool.placement.translation)) if tool is not None else 0.0)


def speed_flag(
    robot: Robot, result: SimulationResult, report: StoppingReport, tool_frame: str
) -> Flag | None:
    """``tool_speed_implausible``: a peak tool speed the drives could not give from the pose.

    The bound is sum_j |J_j(q_signal)| v_lim,j, the tool speed of every joint at its URDF
    velocity limit in the worst combination; robots without velocity limits are not checked.
    """
    limits = robot.cache.get("velocity_limits", lambda: _velocity_limits(robot), kinematic=True)
    if limits is None:
        return None
    norms = report.motion.column_norms if report.motion is not None else None
    if norms is None:
        i0 = int(np.argmax(result.t >= report.signal_time))
        norms = np.linalg.norm(
            compute_tool_jacobian(robot, result.q[i0][None], tool_frame)[0], axis=0
        )
    bound = float(norms @ limits)
    if report.tcp_peak_speed <= bound * (1.0 + SLACK):
        return None
    return Flag(
        "tool_speed_implausible",
        f"the tool reaches {report.tcp_peak_speed:.3g} m/s during the stop, more than the "
        f"{bound:.3g} m/s every joint at its velocity limit could give from the pose at the "
        "signal: the arm falls, or a lock whips it",
        value=report.tcp_peak_speed,
        limit=bound,
    )


def _velocity_limits(robot: Robot) -> np.ndarray | None:
    """The joints' URDF velocity limits [rad/s or m/s] (read only); None unless all are > 0."""
    limits = np.array(robot.model.velocityLimit, dtype=float)
    if not (np.isfinite(limits) & (limits > 0.0)).all():
        return None
    limits.flags.writeable = False
    return limits


def case_flags(
    robot: Robot,
    brakes: Sequence[Brake],
    payload: Payload | None,
    result: SimulationResult,
    report: StoppingReport,
    tested: str | None,
    tool_frame: str,
) -> tuple[Flag, ...]:
    """Every flag of one stop, in the order of :data:`KINDS`.

    Args:
        robot: The robot simulated (payload attached).
        brakes: Its brakes.
        payload: The payload, if any.
        result: The simulation.
        report: Its stopping report.
        tested: The joint under test (Annex-B cases), else None.
        tool_frame: The frame the report follows.
    """
    category_2 = result.stop is not None and result.stop.category == 2
    found = [
        *(holding_flags(robot, brakes, result, report) if not category_2 else ()),
        drive_flag(robot, result, report),
        slip_flag(result, tested),
        None
        if not report.moving
        else Flag(
            "not_stopped",
            f"{', '.join(report.moving)} still moving at the end of the run "
            f"(t = {report.end_time:g} s): the stopping figures are lower bounds",
            report.moving,
        ),
        *payload_flags(robot, payload),
        speed_flag(robot, result, report, tool_frame),
    ]
    flags = [f for f in found if f is not None]
    return tuple(sorted(flags, key=lambda f: KINDS.index(f.kind)))
