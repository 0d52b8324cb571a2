r"""The batched engine: many runs of one robot advanced together, dynamics in one call per stage.

Every run keeps its own hybrid loop (:func:`vtm_pin.core.simulation.hybrid_run`: time events,
brake decisions, locks and their jumps, results), and so its own time, step size and events.
Only the integration between events is shared: the intervals that the runs ask for are stepped
together by the Dormand-Prince 8(5,3) step, step control and dense output of
:mod:`vtm_pin.numerics.integrators.dormand_prince` over many lanes, the code that
:class:`~vtm_pin.numerics.integrators.DOP853` runs as its one lane (and the same event location), so
a run's steps are the scalar engine's up to round-off. Each Runge-Kutta stage evaluates the
dynamics of every run of a batch in at most three batched calls:
``pinocchio.abaInParallel`` for the runs without locks, ``pinocchio.rneaInParallel`` twice for
those with.

**Rests settled across the lanes.** The most common event of a stop is a sliding joint
reaching rest while every brake at rest can hold: the brake state machine
(:meth:`~vtm_pin.physics.brakes.BrakeMachine.settle`) then only sticks that joint, whose lock
at v_j = 0 leaves v unchanged. The engine takes this decision itself, as array operations
over the lanes whose rests it located (:meth:`BatchEngine._settle_rests`): it locks the joint
in the lane, evaluates the right-hand side there (which the next interval needs anyway) and
tests every stuck joint's slip margin, the stick decision's own test. A lane that holds goes
on with its next interval at once; its run's loop is handed the interval later, as a
:class:`~vtm_pin.core.simulation.Rested` one, and writes the same records without a decision,
a trial lock set or a phase of its own. Anything else (a reversal, another joint at rest, a
brake that cannot hold, a slip) goes to the run's loop, as before.

**Plain stops run by the engine.** A study case's whole life is usually a plain stop
(:func:`~vtm_pin.core.simulation.plain_stop`: category 0 at t = 0, every joint braked by
friction without a ramp, one engagement instant, the kkt rule, no holding torques kept). Its
loop then has nothing to decide after its first interval that the engine cannot decide across
its lanes: at the engagement every joint slides against its motion (:meth:`BatchEngine._engage`),
then each rest sticks as above, until every joint is stuck. The engine leaves the loop at the
engagement and hands the records to a :class:`~vtm_pin.core.simulation.PlainStop`, which
writes the loop's own, to the bit (tests/test_batch_plain.py): no phase, request or lane load
after the first interval. With a joint at rest at the engagement the loop decides, as before;
a plain stop that is not plain later (a rest the engine does not settle, a slip, a failure)
goes back to its own loop, started again from t = 0 (:meth:`BatchEngine._return`).

**What batches together** (:func:`_groups`): runs with the same integrator settings and the
same model (:func:`model_key`), when that model has at least :data:`MIN_LANES` runs; the runs
of the other models are pooled when their models have the same joints, placements, parents,
armature and gravity, whatever their bodies' inertias (:func:`batch_key`). A payload drawn per
case (merged into one joint's body by :func:`~vtm_pin.physics.payload.attach_payload`) gives
every case its own model, and they still share a batch. A pooled batch's Pinocchio model is
the one most of its runs have; every other run carries the differences dI_j of its bodies'
spatial inertias from it (in practice the payload's joint only), whose generalised forces are
added exactly (see :class:`_Dynamics`):

.. math:: M \mathrel{+}= J_j^T\, dI_j\, J_j, \qquad
          b \mathrel{+}= J_j^T (dI_j\, c_j + v_j \times^* dI_j\, v_j),

with J_j the body Jacobian of joint j's body, v_j its spatial velocity and c_j its spatial
acceleration at a = 0 with gravity, computed over the lanes with NumPy
(:func:`~vtm_pin.physics.kinematics.body_motions`). Such a run takes the columns path below
even with no joint locked (ABA cannot take a lane's own inertias): measured (UR10, 300
lanes, a shared machine), its dynamics cost ~15 us a lane against ABA's ~2 us with no joint
locked, ~10-12 against ~4-8 us with locks (the inertia terms ~4.5 us of it), while a run
whose model is the batch's costs nothing more. Hence, on this NumPy path, a model with
enough runs for a batch of its own keeps one (the six payload classes of
``studies/ur10_envelope.yaml``: pooled, the study took 13 % more CPU time). With the compiled
kernel (the ``fast`` extra) every lane costs the same, pooled or not, and every run is pooled
(:func:`_groups`: fewer, larger batches, whose steps cost less per lane). Models with a
joint type that the NumPy chain does not compute batch with runs of the very same model only
(:func:`model_key`).

A run whose phase has joints locked is not given a reduced model (that would be one model per
run and per lock angle). Its free accelerations come from the full model instead: with L the
locked joints and f the free ones (v_L = 0, a_L = 0),

.. math:: M_{ff}\, a_f = \tau_f - b_f, \qquad \lambda_L = M_{Lf}\, a_f + b_L - \tau_L,

where b = RNEA(q, v, 0) and the free columns M e_j come from one batched RNEA call on the
model without gravity at zero velocity with a = e_j, over every (run, free joint) pair. That
is 1 + k RNEA passes (about half an ABA each) for k free joints; in a stop most joints are
locked, where the k x k solve is small. The multipliers lambda are the locks' holding
torques, which the brakes' slip events and the results need.
With Numba installed (the ``fast`` extra), these states (and those of lanes with their own
inertias) go instead to one compiled pass over the states, M, b and the solve state by state
(:mod:`vtm_pin.physics.chain_dynamics`); the NumPy path above stays the default and the
fallback.

What the batched engine steps: intervals without frame constraints or acting drives, with
Coulomb or viscous brakes (and ideal locks, which are transitions, not dynamics) and the
motors' short-circuit braking, integrated by dop853.
A run that needs anything else (see :func:`fallback_reason`) is run by the scalar engine.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import math
import time
from collections.abc import Callable, Generator, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ..exceptions import SimulationError, StepLimitError, VtmError
from ..numerics.integrators import DOP853, Segment
from ..numerics.integrators import dormand_prince as dp
from ..numerics.integrators.dop853 import _Grid
from ..numerics.integrators.fixed_step import locate
from ..numerics.transitions.recursive import weightless
from ..physics import body_kernel, chain_dynamics
from ..physics.brakes import REST_RATE, ROUNDOFF, Brake, StateEventKind
from ..physics.drives import short_circuit_torque
from ..physics.friction import Coulomb, Viscous
from ..physics.kinematics import JointChain, body_motions, cached_chain, cross, joint_chain
from ..physics.payload import body_parameters
from ..physics.robot import Robot
from .phase import WORKS
from .problem import Problem
from .results import SimulationResult
from .simulation import (
    PlainStop,
    Reply,
    Rested,
    SegmentRequest,
    hybrid_run,
    motor_shorts,
    plain_stop,
)

ENGINES = ("batched", "scalar")
#: Fewest runs of one model a study gives a batch: fewer run faster on the scalar engine.
#: Measured (issue 27, UR10 Annex-B category-0 runs, one process, OMP_NUM_THREADS=1, a shared
#: and loaded machine): a batch of n runs takes, per run, 3.2x the scalar engine's time at
#: n = 1, 1.4-1.8x at n = 4-12, 1.1x at 16, 0.95x at 24 and 0.6x at 64 (0.95x at 16 and
#: 0.75x at 64 on a quieter one).
MIN_LANES = 16
#: Why a run whose model too few runs of the batch share went to the scalar engine (models that
#: differ in their bodies' inertias only count as one: :func:`batch_key`).
FEW_LANES = "fewer than {min_lanes} runs of its model in the batch (the scalar engine is faster)"
#: Where a batch's wall time goes: the Pinocchio calls with the small solves of locked runs,
#: the runs' hybrid loops (brake decisions, locks, traces), the lanes' own bookkeeping lane by
#: lane (loading a run's phase into its lane, its slip margins from the phase's own events,
#: handing it its segment), event location on the dense output, and the rest: the vectorised
#: step control and dense output in NumPy (and the batch's set-up: its Pinocchio model pools).
#: An engine whose brake decisions were array operations would keep only the first (less the
#: decisions' share), the vectorised part of location, and stepping.
PARTS = ("dynamics", "hybrid", "lanes", "location", "stepping")
#: What a batch still does lane by lane in Python, counted (:attr:`BatchOutcome.lane_python`):
#: resumptions of a run's hybrid loop after an event or at an interval's end (its brake
#: decisions, locks and next phase; one resumption may hand it several intervals), state
#: events located with the phase's own event functions, and, for contrast, rests located
#: across the lanes, rests settled across the lanes (:meth:`BatchEngine._settle_rests`:
#: handed to the loop later, without a decision of its own) and the intervals handed
#: (as many as the scalar loop's requests); the plain stops whose lives the engine took
#: over after their first interval (:class:`~vtm_pin.core.simulation.PlainStop`), and those
#: of them it handed back to their own loops, started again (:meth:`BatchEngine._return`).
LANE_PYTHON = (
    "resumptions",
    "own_locations",
    "batched_locations",
    "settled_rests",
    "intervals",
    "plain_stops",
    "plain_returned",
)

_LANES = dp.LANES


def fallback_reason(problem: Problem, integrator: object) -> str | None:
    """Why a run cannot go through the batched engine; None if it can.

    Args:
        problem: The run.
        integrator: Its integrator.
    """
    if not isinstance(integrator, DOP853):
        name = getattr(integrator, "name", type(integrator).__name__)
        return f"integrator {name} (the batched engine steps dop853 only)"
    if problem.constraints or any(e.activate for e in problem.events):
        return "frame constraints"
    stop = problem.stop
    if stop is not None and stop.category == 1:
        return "category-1 stop (drives ramp the rates down)"
    if stop is not None and stop.category == 2:
        return "category-2 stop (drives ramp the rates down, then hold the arm)"
    if stop is not None and stop.t > 0.0:
        return "drives act before the stop signal (stop.t > 0)"
    for brake in problem.brakes:
        if not brake.ideal and type(brake.friction) not in (Coulomb, Viscous):
            return (
                f"{brake.friction.name} brake friction (the batched engine has Coulomb and viscous)"
            )
    return None


def model_key(model: pin.Model, inertias: bool = True) -> bytes:
    """Bytes equal for two models with the same dynamics (inertias, placements, armature).

    Args:
        model: The model.
        inertias: Whether the bodies' inertias are in it; without them, the bytes are equal
            for models that differ in their bodies' inertias only (see :func:`batch_key`).
    """
    key = _fixed_key(model)
    return key + _inertias_key(model) if inertias else key


def robot_model_key(robot: Robot) -> bytes:
    """:func:`model_key` of the robot's model, from the entries of its cache.

    The part without inertias is the same for the robot's payload copies (a kinematic entry),
    and costs ~0.1 ms to form; the inertias' part is its bodies' dynamic parameters
    (:func:`~vtm_pin.physics.payload.body_parameters`: a payload copy has them from
    :func:`~vtm_pin.physics.payload.attach_payload`, no inertia read again).
    """
    return _robot_fixed_key(robot) + body_parameters(robot).tobytes()


def robot_batch_key(robot: Robot) -> bytes:
    """:func:`batch_key` of the robot's model, from the entries its payload copies share.

    Its joint chain and the key's part without inertias are kinematic entries of the robot's
    cache: a payload drawn per case forms neither again (measured, issue 27: ~0.1 ms a
    drawn-payload case, when each was formed from the model).
    """
    if cached_chain(robot) is None:
        return b"model " + robot_model_key(robot)
    return b"joints " + _robot_fixed_key(robot)


def _robot_fixed_key(robot: Robot) -> bytes:
    """:func:`_fixed_key` of the robot's model, kept in its cache (a kinematic entry)."""
    key: bytes = robot.cache.get("batch_fixed_key", lambda: _fixed_key(robot.model), kinematic=True)
    return key


def _fixed_key(model: pin.Model) -> bytes:
    """:func:`model_key` without the bodies' inertias."""
    parts = [
        np.asarray(model.gravity.vector),
        np.asarray(model.armature),
        np.asarray(model.parents, dtype=float),
    ]
    for joint, placement in zip(model.joints, model.jointPlacements, strict=True):
        parts.append(np.array([joint.idx_v, joint.nv], dtype=float))
        parts.append(placement.homogeneous.ravel())
        if joint.shortname().endswith("Unaligned"):  # its axis: not in str(joint)
            parts.append(np.asarray(joint.extract().axis, dtype=float))
    return b"".join(np.ascontiguousarray(p, dtype=float).tobytes() for p in parts) + b"".join(
        str(joint).encode() for joint in model.joints
    )


def _inertias_key(model: pin.Model) -> bytes:
    """The bodies' inertias of :func:`model_key`: their dynamic parameters' bytes."""
    return _parameters(model).tobytes()


def _parameters(model: pin.Model) -> np.ndarray:
    """The model's bodies' dynamic parameters, shape (njoints, 10) (as ``body_parameters``)."""
    return np.array([inertia.toDynamicParameters() for inertia in model.inertias])


def batch_key(model: pin.Model) -> bytes:
    """Bytes equal for the models of runs that may share a batch.

    Models that differ only in their bodies' inertias (a payload's) share one, when their
    joints are all of the types the NumPy chain computes
    (:func:`~vtm_pin.physics.kinematics.body_motions`): a lane then carries its inertias'
    differences from the batch's model (:class:`_Dynamics`). Other models batch with their
    equals only (:func:`model_key`).
    """
    if joint_chain(model) is None:
        return b"model " + model_key(model)
    return b"joints " + model_key(model, inertias=False)


class _Dynamics:
    """Batched dynamics of one model: ABA, or with locks M_ff a_f = tau_f - b_f; holding torques.

    Lanes may carry their own bodies' inertias (``models``): lane r's model is the pool's with
    joint j's spatial inertia I_j + dI_rj. With J_j the body Jacobian of joint j's body, v_j
    its spatial velocity and c_j its spatial acceleration at a = 0 (gravity included, as RNEA
    has it), dI_rj adds J_j^T (dI (J_j a + c_j) + v_j x* dI v_j) to the generalised forces:
    J_j^T dI J_j to M and J_j^T (dI c_j + v_j x* dI v_j) to b. Such a lane (with a nonzero
    dI) takes the columns path, locks or not (ABA cannot take a lane's own inertias); a lane
    whose model is the pool's costs nothing more.

    **Compiled.** With Numba (the ``fast`` extra) and a model the NumPy chain computes, every
    state goes instead to one compiled pass, locks or not
    (:func:`~vtm_pin.physics.chain_dynamics.locked_dynamics`: M, b and the solve state by
    state, each lane with its own bodies' parameters), ~2.2 us a UR10 state against ~7 (the
    model's own) and ~11 us (a payload's) by the RNEA columns, and ~2 us by ABA (for a state
    without locks; one call for all, no split of the states between two algorithms).

    Args:
        model: The full model (armature included): the pool's.
        threads: Threads of Pinocchio's parallel algorithms.
        models: Each lane's model, which may differ from ``model`` in its bodies' inertias
            only (:func:`batch_key`); None if every lane's is ``model``.
    """

    def __init__(
        self, model: pin.Model, threads: int, models: Sequence[pin.Model] | None = None
    ) -> None:
        self.n = model.nv
        self.threads = threads
        self.pool = pin.ModelPool(model, threads)
        self.weightless = pin.ModelPool(weightless(model), threads)
        self.gravity = np.array(model.gravity.vector)
        #: The joints whose bodies' inertias differ in some lane; the lanes with a difference.
        self.joints: tuple[int, ...] = ()
        self.loaded = np.zeros(0 if models is None else len(models), dtype=bool)
        self.chain: JointChain | None = None
        self._model, self._models = model, models
        self._delta: np.ndarray | None = None
        each = {id(model): _parameters(model)}  # by model: a study's lanes share one per payload
        if models is not None:
            for m in models:
                if id(m) not in each:
                    each[id(m)] = _parameters(m)
            self._differences(each[id(model)], np.array([each[id(m)] for m in models]))
        #: Whether the states go to the compiled kernel; the bodies' dynamic
        #: parameters it reads, shape (P, njoints, 10): the pool model's, then one row per
        #: lane if their inertias differ (lane r's is row r + 1).
        if chain_dynamics.runs() and self.chain is None:
            self.chain = joint_chain(model)
        self.compiled = chain_dynamics.runs() and self.chain is not None
        some = [model, *(models if models is not None and self.joints else ())]
        self.parameters = np.array([each[id(m)] for m in some])
        self.armature = np.array(model.armature)
        #: Batched Pinocchio calls made, and the states they evaluated; the states the
        #: compiled kernel evaluated.
        self.calls = 0
        self.states = 0
        self.kernel_states = 0

    def _differences(self, own: np.ndarray, lanes: np.ndarray) -> None:
        """Which joints' bodies differ from the pool model's ``own`` parameters in ``lanes``'."""
        differs = np.flatnonzero((lanes != own).any(axis=(0, 2)))
        if differs.size == 0:
            return
        self.chain = joint_chain(self._model)
        assert self.chain is not None, "batch_key lets no such model differ in its inertias"
        self.joints = tuple(int(j) for j in differs)
        self.loaded = np.asarray((lanes[:, differs] != own[differs]).any(axis=(1, 2)))

    @property
    def delta(self) -> np.ndarray:
        """Per lane its :attr:`joints`' inertias less the pool model's, (lane, joint, 6, 6).

        [kg, kg m, kg m^2] (see the class docstring); made when the NumPy path first needs
        them, for some :attr:`loaded` lane (the compiled kernel reads the lanes'
        :attr:`parameters`).
        """
        if self._delta is None:
            joints, models = self.joints, self._models or ()
            base = np.array([self._model.inertias[j].matrix() for j in joints])
            each: dict[int, np.ndarray] = {}  # by model, as the parameters
            for m in models:
                if id(m) not in each:
                    each[id(m)] = np.array([m.inertias[j].matrix() for j in joints]) - base
            self._delta = np.array([each[id(m)] for m in models])
        return self._delta

    def _call(
        self, algorithm: object, pool: pin.ModelPool, q: np.ndarray, v: np.ndarray, x: np.ndarray
    ) -> np.ndarray:
        """``pin.abaInParallel`` or ``pin.rneaInParallel`` on rows of states."""
        self.calls += 1
        self.states += len(q)
        out = algorithm(self.threads, pool, q.T, v.T, x.T)  # type: ignore[operator]
        return np.asarray(out).reshape(self.n, len(q)).T

    def accelerations(
        self,
        q: np.ndarray,
        v: np.ndarray,
        tau: np.ndarray,
        locked: np.ndarray,
        lanes: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Accelerations [rad/s^2] (0 at locked joints) and holding torques [N m] (0 at free).

        Args:
            q: Configurations, shape (B, n).
            v: Rates, shape (B, n), exactly 0 at locked joints.
            tau: Applied torques, shape (B, n), 0 at locked joints.
            locked: Lock masks, shape (B, n).
            lanes: Each state's lane (for its inertias); None: the pool's model for all.

        With :attr:`compiled`, every state goes to the kernel, with locks or not: one call,
        no split of the states between it and ABA (~2.2 against ~2 us a state, and a
        Pinocchio call, the split's gathers and scatters saved).
        """
        own = lanes is not None and bool(self.joints)  # some lane has its own inertias
        if self.compiled:
            return self._locked(q, v, tau, locked, lanes if own else None)
        a = np.zeros_like(q)
        lam = np.zeros_like(q)
        loaded = self.loaded[lanes] if own else np.zeros(len(q), dtype=bool)
        held = locked.any(axis=1) | loaded
        rows = np.flatnonzero(~held)
        if rows.size:
            a[rows] = self._call(pin.abaInParallel, self.pool, q[rows], v[rows], tau[rows])
        rows = np.flatnonzero(held)
        if rows.size:
            which = lanes[rows] if own else None  # type: ignore[index]
            a[rows], lam[rows] = self._locked(q[rows], v[rows], tau[rows], locked[rows], which)
        return a, lam

    def _locked(
        self,
        q: np.ndarray,
        v: np.ndarray,
        tau: np.ndarray,
        locked: np.ndarray,
        lanes: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`accelerations` of states with locks, from M's free columns and b by RNEA.

        States of lanes with their own inertias (``lanes``) get their terms added to both.
        With :attr:`compiled`, one kernel call instead (for any states, locks or not); should
        Numba fail here, the RNEA columns from then on.
        """
        if self.compiled:
            which = np.zeros(len(q), dtype=np.int64) if lanes is None else lanes + 1
            try:
                out = chain_dynamics.locked_dynamics(
                    self.chain, q, v, tau, locked, self.parameters, which, self.armature,
                    self.gravity,
                )  # fmt: skip
            except body_kernel.failures() as exc:  # Numba cannot run here: NumPy from now on
                body_kernel.fall_back(exc)
                self.compiled = False
            else:
                self.kernel_states += len(q)
                return out
        n = self.n
        free = ~locked
        b = self._call(pin.rneaInParallel, self.pool, q, v, np.zeros_like(q))
        lane, joint = np.nonzero(free)  # one weightless RNEA per (state, free joint), one call
        unit = np.zeros((lane.size, n))
        unit[np.arange(lane.size), joint] = 1.0
        columns = np.zeros((len(q), n, n))  # columns[r, :, j] = M e_j where j is free
        columns[lane, :, joint] = self._call(
            pin.rneaInParallel, self.weightless, q[lane], unit * 0.0, unit
        )
        if lanes is not None:
            rows = np.flatnonzero(self.loaded[lanes])
            if rows.size:  # M's locked columns too: they meet a_L = 0 only
                extra_M, extra_b = self._inertia_terms(q[rows], v[rows], lanes[rows])
                columns[rows] += extra_M
                b[rows] += extra_b
        both = free[:, :, None] & free[:, None, :]
        system = np.where(both, columns, 0.0) + locked[:, :, None] * np.eye(n)
        a = _solve_each(system, np.where(free, tau - b, 0.0))
        a[locked] = 0.0
        lam = np.einsum("rij,rj->ri", columns, a) + b - tau
        lam[free] = 0.0
        return a, lam

    def _inertia_terms(
        self, q: np.ndarray, v: np.ndarray, lanes: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """What the lanes' inertia differences add to M, shape (B, n, n), and b, shape (B, n).

        Per joint j: J^T dI J [kg m^2] and J^T (dI c + v x* dI v) [N m] (the class docstring).
        """
        assert self.chain is not None
        J, V, C = body_motions(self.chain, q, v, self.joints, self.gravity)
        dI = self.delta[lanes]  # (B, D, 6, 6)
        JT = J.swapaxes(-1, -2)
        h = (dI @ V[..., None])[..., 0]  # the bodies' extra momenta
        force = (dI @ C[..., None])[..., 0] + _force_cross(V, h)
        M = (JT @ (dI @ J)).sum(axis=1)
        return M, (JT @ force[..., None])[..., 0].sum(axis=1)


def _force_cross(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Spatial cross products v x* f along the last axis (linear, angular; motion v, force f)."""
    linear = cross(v[..., 3:], f[..., :3])
    angular = cross(v[..., 3:], f[..., 3:]) + cross(v[..., :3], f[..., :3])
    return np.concatenate([linear, angular], axis=-1)


def _solve_each(A: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """The solutions of A[r] x[r] = rhs[r], row by row; NaN where A[r] is singular.

    A singular M_ff then fails that run alone (its derivatives are not finite), as the
    scalar engine's ABA would, instead of the whole batch.
    """
    try:
        return np.linalg.solve(A, rhs[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:
        x = np.full_like(rhs, np.nan)
        for r in range(len(A)):
            try:
                x[r] = np.linalg.solve(A[r], rhs[r])
            except np.linalg.LinAlgError:
                continue
        return x


@dataclass
class _Lanes:
    """The runs' current intervals, one row (lane) per run, in the padded state layout.

    The padded state of a run with n joints is (q, v, W_brake, W_drive, W_short, P_brake),
    3n + 3 values; a locked joint keeps its q and v = 0 with zero rates. Which entries are the
    interval's own (the scalar engine's y) is ``active``; the error norms use those only.
    """

    n: int
    size: int

    def __post_init__(self) -> None:
        n, b, ny = self.n, self.size, 3 * self.n + WORKS
        self.ny = ny
        self.y = np.zeros((b, ny))
        self.fy = np.zeros((b, ny))
        self.lam = np.zeros((b, n))
        self.t = np.zeros(b)
        self.t1 = np.zeros(b)
        self.h = np.zeros(b)
        self.rejected = np.zeros(b, dtype=bool)
        self.locked = np.zeros((b, n), dtype=bool)
        self.sign = np.zeros((b, n))
        self.ratio = np.ones((b, n))
        self.torque = np.zeros((b, n))  # motor side sliding torque [N m]
        self.viscous = np.zeros((b, n))  # 1 / viscous velocity [s/rad], 0: Coulomb
        self.short_torque = np.zeros((b, n))  # short-circuit peak torque where shorted [N m]
        self.short_speed = np.ones((b, n))  # its motor speed [rad/s]
        self.breakaway = np.zeros((b, n))  # motor side static torque [N m]
        self.ramp = np.zeros((b, n))
        self.engaged = np.zeros((b, n))
        self.braked = np.zeros((b, n), dtype=bool)  # engaged brakes
        self.event_kind = np.zeros((b, n), dtype=np.int8)  # 0 none, 1 rest, 2 slip
        self.event_dir = np.zeros((b, n))
        self.event_index = np.zeros((b, n), dtype=int)
        self.g_prev = np.zeros((b, n))
        self.active = np.zeros((b, ny), dtype=bool)
        self.count = np.ones(b)
        self.steps = np.zeros(b, dtype=int)
        self.accepted = np.zeros(b, dtype=int)
        self.evals = np.zeros(b, dtype=int)
        self.running = np.zeros(b, dtype=bool)
        #: Whether the lane holds its run's constants (gear ratios, brake friction): written
        #: at the run's first interval, the same in every phase (a lane is one run's).
        self.constants = np.zeros(b, dtype=bool)
        #: The run's next output time [s] (inf: none) and its grid's last (:class:`_Grid`).
        self.next_out = np.full(b, math.inf)
        self.out_end = np.full(b, -math.inf)


class _Run:
    """One run's hybrid loop and the interval it is waiting for.

    A plain stop's loop (:func:`~vtm_pin.core.simulation.plain_stop`) is left after its first
    interval, when its brakes engage: the engine then decides its life itself, and its
    records are made by :attr:`plain` (see :meth:`BatchEngine._engage`).
    """

    def __init__(
        self,
        index: int,
        problem: Problem,
        integrator: DOP853,
        transition: str,
        holding: bool = True,
    ) -> None:
        self.index = index
        self.problem = problem
        self.integrator = integrator
        self.transition = transition
        self.holding = holding
        #: A plain stop's engagement instant [s] (None: not a plain stop, or no longer).
        self.engage_at = plain_stop(problem, transition, holding)
        #: A plain stop's records once the engine has taken over its life.
        self.plain: PlainStop | None = None
        #: Whether the engine loads its first interval itself (:meth:`BatchEngine._load_plain`):
        #: a plain stop whose motors do not brake by short circuit (that interval is then
        #: passive). Such a run has no loop unless it goes back to it.
        self.direct = self.engage_at is not None and motor_shorts(problem.robot) is None
        self.loop: Generator[SegmentRequest, Reply, SimulationResult] | None = (
            None if self.direct else self._loop()
        )
        self.request: SegmentRequest | None = None
        self.outcome: SimulationResult | VtmError | None = None
        self.grid: _Grid | None = None
        self.ts: list[np.ndarray] = []
        self.ys: list[np.ndarray] = []
        #: Its samples' holding torques, if they are kept (:attr:`BatchEngine.holding`).
        self.holds: list[np.ndarray] | None = [] if holding else None
        self.reduced = np.zeros(0, dtype=int)
        #: The intervals its lane ended at rests it decided itself, not yet handed to the loop.
        self.pieces: list[Rested] = []
        self.output_dt: float | None = None

    def _loop(self) -> Generator[SegmentRequest, Reply, SimulationResult]:
        return hybrid_run(
            self.problem,
            self.integrator,
            transition=self.transition,
            reduced_models=False,
            holding=self.holding,
        )

    @property
    def left(self) -> bool:
        """Whether its loop is not what runs it: a plain stop the engine runs itself."""
        return self.plain is not None or self.loop is None

    def restart(self) -> None:
        """Start its own loop again from t = 0 (a plain stop that is no longer plain)."""
        if self.loop is not None:
            self.loop.close()
        self.loop = self._loop()
        self.engage_at = self.plain = self.request = None
        self.direct = False
        self.pieces = []

    def sample(self, lanes: _Lanes, b: int) -> None:
        """Keep its lane ``b``'s state now as a sample (time, padded state, holding torques)."""
        self.ts.append(lanes.t[b : b + 1].copy())
        self.ys.append(lanes.y[b : b + 1].copy())
        if self.holds is not None:
            self.holds.append(lanes.lam[b : b + 1].copy())

    def advance(self, segment: Reply | None = None, error: VtmError | None = None) -> None:
        """Send the loop its segment(s) (or error); keep its next request or its outcome."""
        try:
            assert self.loop is not None, "a run the engine runs itself has no loop to resume"
            if error is not None:
                self.request = self.loop.throw(error)
            elif segment is None:
                self.request = next(self.loop)
            else:
                self.request = self.loop.send(segment)
        except StopIteration as done:
            self.request, self.outcome = None, done.value
        except VtmError as exc:
            self.request, self.outcome = None, exc
        except Exception as exc:  # a bug: this run fails with it, the others go on
            message = f"internal error ({type(exc).__name__}: {exc})"
            self.request, self.outcome = None, SimulationError(message)


class BatchEngine:
    """Runs of one model (up to its bodies' inertias) stepped together (see the module docstring).

    Args:
        model: The batch's full model (the runs' models equal it up to their bodies' inertias:
            :func:`batch_key`).
        integrator: The dop853 settings every run uses.
        threads: Threads of Pinocchio's parallel algorithms.
        models: Each run's model, in the order of the runs :meth:`run` is given, if they
            differ from ``model`` in their bodies' inertias (:func:`batch_key`).
        holding: False: the output samples get no holding torques (NaN, no right-hand side
            evaluated for them; see :func:`run_many`).
    """

    def __init__(
        self,
        model: pin.Model,
        integrator: DOP853,
        threads: int = 1,
        models: Sequence[pin.Model] | None = None,
        holding: bool = True,
    ) -> None:
        self.dynamics = _Dynamics(model, threads, models)
        self.integrator = integrator
        self.holding = holding
        #: Called with each run as soon as it has its outcome (see :func:`run_many`).
        self.finished: Callable[[_Run], None] | None = None
        self.n = model.nv
        #: Wall time [s] in the dynamics (Pinocchio calls and the solves of locked runs), the runs'
        #: hybrid loops (brake decisions, locks, traces) and event location.
        self.seconds = dict.fromkeys(PARTS[:-1], 0.0)
        #: Work done lane by lane (:data:`LANE_PYTHON`).
        self.lane_python = dict.fromkeys(LANE_PYTHON, 0)
        #: Stage buffers of a step of so many lanes.
        self._work: dict[int, dp.Stages] = {}

    # The right-hand side of every lane in ``rows`` at times t and padded states y.

    def rhs(
        self,
        lanes: _Lanes,
        rows: np.ndarray,
        t: np.ndarray,
        y: np.ndarray,
        drives: _Drives | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """dy/dt (padded) and holding torques [N m] of lanes ``rows`` at (t, y).

        ``drives``: the rows' :class:`_Drives`, when the caller evaluates them more than once
        (a step's stages).
        """
        n = self.n
        start = time.perf_counter()
        d = _drives(lanes, rows) if drives is None else drives
        q, v = y[:, :n], y[:, n : 2 * n]
        ratio, sign, kinetic = d.ratio, d.sign, d.torque
        # Terms no lane has are left out (1 x and x + 0 are exact: the same torques).
        if d.viscous is not None:
            slip = np.maximum(sign * (ratio * v), 0.0)  # [rad/s] motor side, as Viscous.kinetic
            kinetic = kinetic * (1.0 + slip * d.viscous)
        tau = -sign * (ratio * (_ramp(d.ramp, t) * kinetic))
        applied, tau_short = tau, None
        if d.short is not None:
            tau_short = short_circuit_torque(ratio, d.short[0], d.short[1], v)
            applied = tau + tau_short
        a, lam = self.dynamics.accelerations(q, v, applied, d.locked, rows)
        out = np.zeros_like(y)
        out[:, :n] = v
        out[:, n : 2 * n] = a
        out[:, 2 * n] = -np.einsum("bi,bi->b", tau, v)
        if tau_short is not None:
            out[:, 2 * n + 2] = -np.einsum("bi,bi->b", tau_short, v)
        out[:, 2 * n + WORKS :] = tau
        self.seconds["dynamics"] += time.perf_counter() - start
        return out, lam

    def run(self, runs: Sequence[_Run]) -> None:
        """Drive ``runs`` (each already started: waiting with a request) to their outcomes."""
        lanes = _Lanes(self.n, len(runs))
        waiting = list(range(len(runs)))
        while True:
            self._start(lanes, runs, waiting)
            rows = np.flatnonzero(lanes.running)
            if rows.size == 0:
                return
            waiting = self._round(lanes, runs, rows)

    # Starting intervals.

    def _start(self, lanes: _Lanes, runs: Sequence[_Run], waiting: list[int]) -> None:
        """Give every waiting run's request a lane (or answer it at once), then first steps."""
        fresh: list[int] = []
        while waiting:
            again = []
            for b in waiting:
                run = runs[b]
                if run.direct:
                    self._load_plain(lanes, b, run)
                    fresh.append(b)
                    continue
                if run.request is None:
                    continue
                request = run.request
                if request.phase.k == 0 or request.t1 <= request.t0:  # the scalar is instant
                    try:
                        segment = request.integrate()
                    except Exception as exc:
                        self.advance(run, error=_as_vtm_error(exc))
                    else:
                        self.advance(run, segment)
                    again.append(b)
                    continue
                begin = time.perf_counter()
                self._load(lanes, b, run)
                self.seconds["lanes"] += time.perf_counter() - begin
                fresh.append(b)
            waiting = again
        if not fresh:
            return
        rows = np.array(fresh)
        fy, lam = self.rhs(lanes, rows, lanes.t[rows], lanes.y[rows])
        lanes.fy[rows], lanes.lam[rows] = fy, lam
        lanes.h[rows] = self._first_step(lanes, rows)
        lanes.evals[rows] = 2
        lanes.g_prev[rows] = self._g(lanes, rows, lanes.t[rows], lanes.y[rows], lam)
        for b in fresh:  # slip margins as the phase's own events have them (>= 0 after a stick)
            self._own_margins(lanes, runs[b], b, lanes.t[b], lanes.y[b], lanes.g_prev[b], None)
        begin = time.perf_counter()
        for b in fresh:  # the interval's first sample
            runs[b].sample(lanes, b)
        self.seconds["lanes"] += time.perf_counter() - begin

    def _load(self, lanes: _Lanes, b: int, run: _Run) -> None:
        """Write run ``b``'s request into its lane."""
        request = run.request
        assert request is not None
        phase = request.phase
        n, k = self.n, phase.k
        topology = phase.topology
        free = topology.free
        locked = np.array(topology.locked, dtype=int)
        y = np.zeros(3 * n + WORKS)
        y[free] = request.y0[:k]
        y[locked] = topology.q_locked
        y[n + free] = request.y0[k : 2 * k]
        extras = np.arange(2 * n, 3 * n + WORKS)
        reduced = [free, n + free] if phase.passive else [free, n + free, extras]
        if not phase.passive:
            y[extras] = request.y0[2 * k :]
        run.reduced = np.concatenate(reduced)
        lanes.y[b] = y
        lanes.t[b], lanes.t1[b] = request.t0, request.t1
        lanes.rejected[b] = False
        lanes.locked[b] = False
        lanes.locked[b, locked] = True
        lanes.active[b] = False
        lanes.active[b, run.reduced] = True
        lanes.count[b] = run.reduced.size
        lanes.steps[b] = lanes.accepted[b] = 0
        if not lanes.constants[b]:
            machine = phase.machine
            brakes = machine.brakes if machine is not None else {}
            self._load_constants(lanes, b, phase.robot.gear_ratio, brakes)
            lanes.constants[b] = True
        self._load_brakes(lanes, b, phase)
        lanes.running[b] = True
        run.output_dt = request.integrator.output_dt  # type: ignore[attr-defined]
        _start_grid(lanes, b, run, request.t0, request.t1)
        run.ts, run.ys = [], []
        run.holds = [] if self.holding else None

    def _load_plain(self, lanes: _Lanes, b: int, run: _Run) -> None:
        """Write a plain stop's first interval into its lane, as its loop's first request has it.

        The stop is signalled at t = 0: every drive drops out, no brake has engaged, no motor
        brakes (:attr:`_Run.direct`), so the phase to its brakes' engagement is passive: every
        joint free, y = (q0, v0), no accumulator integrated, no state event. The lane is a new
        one (its brake and short-circuit figures at their initial zeros).
        """
        begin = time.perf_counter()
        n, problem = self.n, run.problem
        run.direct = False
        run.reduced = np.arange(2 * n)
        lanes.y[b, :n], lanes.y[b, n : 2 * n] = problem.q0, problem.v0
        lanes.t[b], lanes.t1[b] = 0.0, run.engage_at
        lanes.active[b, : 2 * n] = True
        lanes.count[b] = 2 * n
        robot = problem.robot
        brakes = {robot.joint_index(brake.joint): brake for brake in problem.brakes}
        self._load_constants(lanes, b, robot.gear_ratio, brakes)
        lanes.constants[b] = lanes.running[b] = True
        run.output_dt = run.integrator.output_dt
        _start_grid(lanes, b, run, 0.0, lanes.t1[b])
        self.seconds["lanes"] += time.perf_counter() - begin

    @staticmethod
    def _load_constants(
        lanes: _Lanes, b: int, ratio: np.ndarray, brakes: Mapping[int, Brake]
    ) -> None:
        """Gear ratios and brake friction constants (``brakes`` by joint) of run ``b``.

        Its lane is its own: they are the same in every phase.
        """
        lanes.ratio[b] = ratio
        for j, brake in brakes.items():
            friction = brake.friction
            if isinstance(friction, Coulomb):  # the engine's laws (fallback_reason), not ideal
                lanes.torque[b, j] = friction.sliding_torque
                lanes.breakaway[b, j] = friction.breakaway_torque
                lanes.ramp[b, j] = friction.ramp
                lanes.viscous[b, j] = 1.0 / getattr(friction, "viscous_velocity", math.inf)

    def _load_brakes(self, lanes: _Lanes, b: int, phase: object) -> None:
        """Sliding signs, engagement times and the state events of run ``b``'s phase."""
        lanes.sign[b] = 0.0
        lanes.event_kind[b] = 0
        lanes.short_torque[b], lanes.short_speed[b] = phase.shorted()  # type: ignore[attr-defined]
        machine = phase.machine  # type: ignore[attr-defined]
        if machine is None:
            return
        engaged = phase.engaged  # type: ignore[attr-defined]
        lanes.engaged[b, list(machine.brakes)] = 0.0
        lanes.braked[b] = False
        if engaged:
            lanes.engaged[b, list(engaged)] = list(engaged.values())
            lanes.braked[b, list(engaged)] = True
        signs = phase.sliding_signs  # type: ignore[attr-defined]
        if signs:  # the free joints sliding
            lanes.sign[b, list(signs)] = list(signs.values())
        specs = phase.event_specs  # type: ignore[attr-defined]
        if specs:  # each joint's event: its index, crossing, 1 at rest or 2 slipping
            kinds, joints, directions = zip(*specs, strict=True)
            lanes.event_index[b, joints] = range(len(joints))
            lanes.event_dir[b, joints] = directions
            lanes.event_kind[b, joints] = [
                1 if kind is StateEventKind.ZERO_VELOCITY else 2 for kind in kinds
            ]

    def _first_step(self, lanes: _Lanes, rows: np.ndarray) -> np.ndarray:
        """Hairer's initial step guess per lane, as DOP853's (one more evaluation)."""
        it = self.integrator
        t, y = lanes.t[rows], lanes.y[rows]

        def f(t: np.ndarray, y: np.ndarray) -> np.ndarray:
            return self.rhs(lanes, rows, t, y)[0]

        return dp.first_step(
            f,
            t,
            y,
            lanes.fy[rows],
            lanes.t1[rows] - t,
            (it.rtol, it.atol, it.max_step),
            _LANES,
            lanes.count[rows],
            lanes.active[rows],
        )

    def _g(
        self, lanes: _Lanes, rows: np.ndarray, t: np.ndarray, y: np.ndarray, lam: np.ndarray
    ) -> np.ndarray:
        """The state-event functions of lanes ``rows`` (NaN where a joint has none)."""
        n = self.n
        kind = lanes.event_kind[rows]
        static = lanes.ratio[rows] * (_ramp(_ramps(lanes, rows), t) * lanes.breakaway[rows])
        scale = np.maximum(1.0, np.max(np.abs(lam), axis=1))
        margin = static + ROUNDOFF * scale[:, None] - np.abs(lam)
        g = np.where(kind == 1, y[:, n : 2 * n], margin)
        return np.where(kind == 0, np.nan, g)

    # One step attempt of every running lane.

    def _stages(
        self, lanes: _Lanes, rows: np.ndarray, h: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One step of lanes ``rows``: stages K (per lane), y_new, holding torques at y_new."""
        work = self._work.get(rows.size)
        if work is None:
            work = self._work[rows.size] = dp.Stages(lanes.ny, rows.size)
        held: list[np.ndarray] = []
        drives = _drives(lanes, rows)

        def into(t: np.ndarray, y: np.ndarray, out: np.ndarray) -> None:
            out[...], lam = self.rhs(lanes, rows, t, y, drives)
            held[:] = [lam]

        work.K[:, 0] = lanes.fy[rows]
        y_new = dp.step(into, lanes.t[rows], lanes.y[rows], h, work)
        return work.K, y_new, held[0]

    def _error(
        self, lanes: _Lanes, rows: np.ndarray, K: np.ndarray, y_new: np.ndarray, h: np.ndarray
    ) -> np.ndarray:
        """DOP853's scaled error norm per lane, over the interval's own entries."""
        it = self.integrator
        y, active, count = lanes.y[rows], lanes.active[rows], lanes.count[rows]
        return dp.error_norm(y, y_new, h, K, it.rtol, it.atol, _LANES, count, active)

    def _round(self, lanes: _Lanes, runs: Sequence[_Run], rows: np.ndarray) -> list[int]:
        """One step attempt of every running lane; returns the runs whose interval ended."""
        it = self.integrator
        lanes.steps[rows] += 1
        finished: list[int] = []
        over = rows[lanes.steps[rows] > it.max_steps]
        for b in over:
            self._fail(lanes, runs, b, self._step_limit(lanes, runs[b], b), finished)
        rows = rows[lanes.steps[rows] <= it.max_steps]
        h, last = dp.clamp(lanes.t[rows], lanes.t1[rows], lanes.h[rows], it.max_step, _LANES)
        K, y_new, lam_new = self._stages(lanes, rows, h)
        lanes.evals[rows] += dp.S
        err = self._error(lanes, rows, K, y_new, h)
        bad = ~(err <= 1.0)
        if bad.any():
            self._reject(lanes, runs, rows[bad], h[bad], err[bad], finished)
        good = ~bad
        if good.any():
            step = _Step(h, last, err, K, y_new).select(good)
            self._accept(lanes, runs, rows[good], step, lam_new[good], finished)
        return finished

    def _reject(
        self,
        lanes: _Lanes,
        runs: Sequence[_Run],
        rows: np.ndarray,
        h: np.ndarray,
        err: np.ndarray,
        finished: list[int],
    ) -> None:
        """Shrink rejected lanes' steps; a step below the round-off of t fails the run."""
        with np.errstate(divide="ignore", invalid="ignore"):
            h = h * dp.shrink(err, _LANES)
        lanes.h[rows] = h
        lanes.rejected[rows] = True
        tiny = dp.too_small(lanes.t[rows], h)
        for b, hb in zip(rows[tiny], h[tiny], strict=True):
            it = self.integrator
            finite_f = bool(np.isfinite(lanes.fy[b]).all())
            reason = (
                "the derivatives are not finite there"
                if not finite_f
                else f"rtol = {it.rtol:g}, atol = {it.atol:g} cannot be met there"
            )
            error = SimulationError(
                f"dop853: the step fell to {hb:.3g} s at t = {lanes.t[b]:.6g} s, below the "
                f"round-off of t; {reason} (a singular or extremely stiff motion)"
            )
            self._fail(lanes, runs, int(b), error, finished)

    def _accept(
        self,
        lanes: _Lanes,
        runs: Sequence[_Run],
        rows: np.ndarray,
        step: _Step,
        lam_new: np.ndarray,
        finished: list[int],
    ) -> None:
        """Accepted steps: events, dense output, the next step size, ended intervals."""
        lanes.accepted[rows] += 1
        t = lanes.t[rows]
        t_new = np.where(step.last, lanes.t1[rows], t + step.h)
        g_new = self._g(lanes, rows, t_new, step.y_new, lam_new)
        fired = _crossed(lanes.g_prev[rows], g_new, lanes.event_dir[rows])
        fired &= lanes.event_kind[rows] != 0
        slips = fired & (lanes.event_kind[rows] == 2)
        for i in np.flatnonzero(slips.any(axis=1)):  # confirmed by the phase's own events
            b = int(rows[i])
            self._own_margins(lanes, runs[b], b, t_new[i], step.y_new[i], g_new[i], fired[i])
        events: np.ndarray = np.asarray(fired.any(axis=1))
        # An output time falls in the step (as _Grid.due, across the lanes).
        due = ~events & (lanes.next_out[rows] <= np.minimum(t_new, lanes.out_end[rows]))
        going: set[int] = set()  # lanes that settled their rest and go on
        if events.any() or due.any():
            going = self._dense_samples(lanes, runs, rows, step, t_new, fired, events | due)
        for b in rows[events]:
            if int(b) not in going:
                lanes.running[b] = False
                finished.append(int(b))
        go = ~events  # the stages are not copied: f at the step's end only
        rows, t_new, last = rows[go], t_new[go], step.last[go]
        lanes.g_prev[rows] = g_new[go]
        factor = dp.grow(step.err[go], lanes.rejected[rows], _LANES)
        lanes.rejected[rows] = False
        lanes.t[rows], lanes.y[rows], lanes.fy[rows] = t_new, step.y_new[go], step.K[go, dp.S]
        lanes.lam[rows] = lam_new[go]
        lanes.h[rows] = step.h[go] * factor
        gridless = lanes.out_end[rows] == -math.inf
        engaging: list[int] = []  # plain stops at their brakes' engagement
        for i in np.flatnonzero(last | gridless):
            b = int(rows[i])
            run = runs[b]
            run.sample(lanes, b)
            if last[i] and run.plain is None and run.engage_at == lanes.t[b]:
                engaging.append(b)
            elif last[i]:
                lanes.running[b] = False
                self._finish(lanes, run, b, None)
                finished.append(b)
        if engaging:
            self._engage(lanes, runs, np.array(engaging), finished)

    def _engage(
        self, lanes: _Lanes, runs: Sequence[_Run], rows: np.ndarray, finished: list[int]
    ) -> None:
        """Plain stops' brakes engaging at the end of their first interval, across the lanes.

        The brake state machine's decision (:meth:`~vtm_pin.physics.brakes.BrakeMachine.engage`
        for every joint, then :meth:`~vtm_pin.physics.brakes.BrakeMachine.settle`) when every
        joint moves faster than ``REST_RATE``: each brake slides against its joint's motion,
        and nothing else changes. The engine takes it itself. The run's loop is left: its
        records go to a :class:`~vtm_pin.core.simulation.PlainStop`, and its lane goes on at
        once with the next interval as the loop's next phase has it (every joint sliding and
        watched for its rest, the accumulators integrated, to the run's end). Its rests then
        stick across the lanes (:meth:`_settle_rests`) until none slides (:meth:`_conclude`);
        anything else hands it back to its own loop (:meth:`_return`). A lane with a joint at
        rest now, or a state not finite, hands its run the interval, whose loop decides.
        """
        n = self.n
        y = lanes.y[rows]
        v = y[:, n : 2 * n]
        common = (np.abs(v) > REST_RATE).all(axis=1) & np.isfinite(y).all(axis=1)
        for b in rows[~common]:
            lanes.running[b] = False
            self._finish(lanes, runs[b], int(b), None)
            finished.append(int(b))
        rows, v = rows[common], v[common]
        if rows.size == 0:
            return
        begin = time.perf_counter()
        for b in rows:
            run = runs[b]
            t, y_b, _ = self._samples(lanes, run, b)
            if not lanes.active[b, 2 * n]:  # a passive interval's accumulators are 0 (as the
                y_b[:, 2 * n :] = lanes.y[b, 2 * n :] = 0.0  # loop has them); now integrated
            counts = (int(lanes.evals[b]), int(lanes.accepted[b]))
            run.plain = PlainStop(run.problem, self.integrator.name, (t, y_b), counts)
            if run.loop is not None:
                run.loop.close()
            run.request = None
            lanes.t1[b] = run.problem.duration
        self.lane_python["plain_stops"] += rows.size
        self.seconds["hybrid"] += time.perf_counter() - begin
        sign = np.where(v > 0.0, 1.0, -1.0)
        lanes.sign[rows], lanes.event_dir[rows] = sign, -sign
        lanes.event_kind[rows], lanes.event_index[rows] = 1, np.arange(n)
        lanes.braked[rows], lanes.engaged[rows] = True, lanes.t[rows, None]
        lanes.active[rows], lanes.count[rows] = True, lanes.ny
        t, y = lanes.t[rows], lanes.y[rows]
        lanes.fy[rows], lanes.lam[rows] = self.rhs(lanes, rows, t, y)
        lanes.g_prev[rows] = self._g(lanes, rows, t, y, lanes.lam[rows])
        self._restart(lanes, runs, rows)

    def _dense_samples(
        self,
        lanes: _Lanes,
        runs: Sequence[_Run],
        rows: np.ndarray,
        step: _Step,
        t_new: np.ndarray,
        fired: np.ndarray,
        dense: np.ndarray,
    ) -> set[int]:
        """Dense output of the ``dense`` lanes: event location, output times (batched).

        A lane whose step fired a state event gets its earliest event located on the
        step's continuous extension (as :class:`DOP853` does, with the phase's own event
        functions), its output times up to it, and the event state; its interval ends.
        Rests located across the lanes are settled there where the lanes can
        (:meth:`_settle_rests`).

        Returns:
            The lanes that settled their rest and go on with their next interval.
        """
        sub, fired, t_new = rows[dense], fired[dense], t_new[dense]
        lanes.evals[sub] += dp.N_EXTRA
        part = step.select(dense)
        F = self._dense_coefficients(lanes, sub, part)
        owners: list[int] = []
        times: list[float] = []
        ends: dict[int, int] = {}
        rested: dict[int, int] = {}  # the ends located across the lanes
        rests = self._locate_rests(lanes, sub, fired, F, part.h) if fired.any() else {}
        self.lane_python["batched_locations"] += len(rests)
        starts, ends_at = lanes.t[sub].tolist(), t_new.tolist()
        any_fired: list[bool] = np.asarray(fired.any(axis=1)).tolist()
        for i, (b, t, some) in enumerate(zip(sub.tolist(), starts, any_fired, strict=True)):
            run = runs[b]
            if some and not lanes.running[b]:  # handed back to its own loop (a plain stop)
                continue
            if some:
                try:
                    found = rests.get(i)
                    if found is None and not self._sync(lanes, run, b):
                        continue
                    tau, index = found or self._locate(
                        lanes, run, b, F[i], float(part.h[i]), fired[i]
                    )
                except Exception as exc:
                    self.advance(run, error=_as_vtm_error(exc))
                    continue
                until = t + tau - (run.grid.slack if run.grid is not None else 0.0)
                count = _grid_times(lanes, b, run.grid, until, times)
                times.append(t + tau)
                owners.extend([i] * (count + 1))
                ends[b] = index
                if i in rests:
                    rested[b] = index
            else:
                owners.extend([i] * _grid_times(lanes, b, run.grid, ends_at[i], times))
        if owners:
            self._store_samples(lanes, runs, sub, part, F, np.array(owners, dtype=int), times)
        for b, event in ends.items():
            if b not in rested:
                self._finish(lanes, runs[b], b, event)
        return self._settle_rests(lanes, runs, rested) if rested else set()

    def _settle_rests(
        self, lanes: _Lanes, runs: Sequence[_Run], rested: dict[int, int]
    ) -> set[int]:
        """Rests located across the lanes, settled there when the joint only sticks.

        This is the brake state machine's common decision
        (:meth:`~vtm_pin.physics.brakes.BrakeMachine.settle`) as array operations. Lane b's
        event is sliding joint j reaching rest (``rested``: lane -> event index). If every
        other braked free joint slides on the way its mode says (faster than ``REST_RATE``:
        none reverses, none is at rest) and the rest falls before the interval's end, the
        lane locks j (v_j = 0: the momentum-consistent jump is the identity) and evaluates
        its right-hand side there. If every stuck joint's slip margin, j's included, is then
        >= 0 (:meth:`_g`: the stick decision's own test), every brake at rest holds: j
        sticks, and the interval is kept for the run as
        :class:`~vtm_pin.core.simulation.Rested` (its loop records the stick when it is next
        handed anything). A lane with a joint still sliding goes on with its next interval at
        once; one without hands its run the rests now. Any other lane hands its run the
        interval, whose loop settles it.

        Returns:
            The lanes that go on.
        """
        begin, dynamics = time.perf_counter(), self.seconds["dynamics"]
        n = self.n
        rows = np.array(sorted(rested), dtype=int)
        t = np.array([runs[b].ts[-1][-1] for b in rows])
        y = np.stack([runs[b].ys[-1][-1] for b in rows])
        kind, index = lanes.event_kind[rows], lanes.event_index[rows]
        joint = np.argmax((kind == 1) & (index == np.array([rested[b] for b in rows])[:, None]), 1)
        samples = {int(b): self._samples(lanes, runs[b], b) for b in rows}
        others = lanes.braked[rows] & ~lanes.locked[rows]
        others[np.arange(rows.size), joint] = False
        on = lanes.sign[rows] * y[:, n : 2 * n] > REST_RATE  # sliding on as its mode says
        ok = ~(others & ~on).any(axis=1) & (t < lanes.t1[rows])
        held = np.zeros(0, dtype=bool)
        if ok.any():
            held = self._lock_rests(lanes, rows[ok], joint[ok], t[ok], y[ok])
        settled = rows[ok][held]
        going = settled[(lanes.sign[settled] != 0.0).any(axis=1)]
        for b, j in zip(settled, joint[ok][held], strict=True):
            t_b, y_b, hold = samples[int(b)]
            steps = int(lanes.accepted[b])  # the ended interval's (reset by the restart)
            evals = int(lanes.evals[b])
            runs[b].pieces.append(Rested(t_b, y_b, hold, evals, steps, int(j), lanes.lam[b].copy()))
            if not runs[b].left:  # its layout for the segments handed to its loop
                runs[b].reduced = np.flatnonzero(lanes.active[b])
        self.lane_python["settled_rests"] += settled.size
        inner = self.seconds["dynamics"] - dynamics
        self.seconds["lanes"] += time.perf_counter() - begin - inner
        self._restart(lanes, runs, going)
        for b in np.setdiff1d(settled, going):  # nothing slides on: its run decides what follows
            self._conclude(lanes, runs[b], int(b))
        for b in np.setdiff1d(rows, settled):  # its loop settles it
            self._hand(lanes, runs[b], int(b), samples[int(b)], rested[int(b)])
        return {int(b) for b in going}

    def _lock_rests(
        self, lanes: _Lanes, rows: np.ndarray, joint: np.ndarray, t: np.ndarray, y: np.ndarray
    ) -> np.ndarray:
        """Lock each lane's arrived joint at (t, y) and test the stuck joints' margins there.

        The lanes ``rows`` are left in their next phase (f, holding torques and event
        functions at its start included); whether each holds. A lane that does not is
        loaded afresh with its run's next request.
        """
        n = self.n
        y = y.copy()
        y[np.arange(rows.size), n + joint] = 0.0
        lanes.locked[rows, joint] = True
        lanes.sign[rows, joint] = lanes.short_torque[rows, joint] = 0.0
        lanes.short_speed[rows, joint] = 1.0
        lanes.event_kind[rows, joint], lanes.event_dir[rows, joint] = 2, -1.0
        lanes.active[rows, joint] = lanes.active[rows, n + joint] = False
        lanes.count[rows] -= 2
        lanes.t[rows], lanes.y[rows] = t, y
        lanes.fy[rows], lanes.lam[rows] = self.rhs(lanes, rows, t, y)
        g = lanes.g_prev[rows] = self._g(lanes, rows, t, y, lanes.lam[rows])
        held: np.ndarray = ~((lanes.event_kind[rows] == 2) & ~(g >= 0.0)).any(axis=1)
        _order_events(lanes, rows[held])
        return held

    def _restart(self, lanes: _Lanes, runs: Sequence[_Run], rows: np.ndarray) -> None:
        """Start the next interval of lanes ``rows`` where they stand (f and margins known)."""
        if rows.size == 0:
            return
        lanes.h[rows] = self._first_step(lanes, rows)
        lanes.evals[rows] = 2
        lanes.steps[rows] = lanes.accepted[rows] = 0
        lanes.rejected[rows] = False
        begin = time.perf_counter()
        for b in rows:
            run = runs[b]
            _start_grid(lanes, b, run, float(lanes.t[b]), float(lanes.t1[b]))
            run.sample(lanes, b)
        self.seconds["lanes"] += time.perf_counter() - begin

    def _store_samples(
        self,
        lanes: _Lanes,
        runs: Sequence[_Run],
        sub: np.ndarray,
        part: _Step,
        F: np.ndarray,
        owner: np.ndarray,
        times: list[float],
    ) -> None:
        """The dense output at ``times`` [s] (of lanes ``sub[owner]``), with holding torques."""
        when = np.array(times)
        x = (when - lanes.t[sub][owner]) / part.h[owner]
        y = dp.dense_value(F[owner], x, lanes.y[sub][owner], _LANES)
        # No right-hand side for the samples without holding torques: nobody reads them.
        lam = self.rhs(lanes, sub[owner], when, y)[1] if self.holding else None
        # Each lane's samples are consecutive: one slice (a view) of each per lane.
        bounds = (np.flatnonzero(np.diff(owner)) + 1).tolist()
        starts, ends = [0, *bounds], [*bounds, len(when)]
        for b, first, end in zip(sub[owner[starts]].tolist(), starts, ends, strict=True):
            run = runs[b]
            run.ts.append(when[first:end])
            run.ys.append(y[first:end])
            if lam is not None:
                run.holds.append(lam[first:end])

    def _own_margins(
        self,
        lanes: _Lanes,
        run: _Run,
        b: int,
        t: float,
        y: np.ndarray,
        g: np.ndarray,
        fired: np.ndarray | None,
    ) -> None:
        """Run ``b``'s slip margins at (t, y) from its phase's own event functions.

        They replace the batched values in ``g``; with ``fired``, a slip counts as fired only
        if the phase's own margin crossed too (the two agree to round-off, and the phase's
        events are what the event location uses).
        """
        joints = np.flatnonzero(lanes.event_kind[b] == 2)
        if fired is not None:
            joints = joints[fired[joints]]
        if joints.size == 0 or not self._sync(lanes, run, b):
            return
        request = run.request
        assert request is not None
        begin = time.perf_counter()
        phase = request.phase
        hold = phase.holding_torque(float(t), y[run.reduced])  # what its slip events ask for
        for j in joints:
            g[j] = phase.machine.slip_margin(float(t), int(j), hold)  # type: ignore[union-attr]
            if fired is not None:
                fired[j] = _crossed(lanes.g_prev[b, j], g[j], lanes.event_dir[b, j])
        self.seconds["lanes"] += time.perf_counter() - begin

    def _locate(
        self, lanes: _Lanes, run: _Run, b: int, F: np.ndarray, h: float, fired: np.ndarray
    ) -> tuple[float, int]:
        """The earliest state event in run ``b``'s step: (offset [s], event index)."""
        request = run.request
        assert request is not None
        reduced = run.reduced
        y, Fr = lanes.y[b, reduced], np.ascontiguousarray(F[:, reduced])

        def dense(tau: float) -> np.ndarray:  # DOP853's continuous extension, as it has it
            return dp.dense_value(Fr, tau / h, y, dp.ONE_LANE)

        events = [e.event for e in request.phase.events]
        self.lane_python["own_locations"] += 1
        indices = sorted(int(lanes.event_index[b, j]) for j in np.flatnonzero(fired))
        begin = time.perf_counter()
        found = locate(events, indices, float(lanes.t[b]), y, dense, h, self.integrator.event_tol)
        self.seconds["location"] += time.perf_counter() - begin
        return found

    def _locate_rests(
        self, lanes: _Lanes, sub: np.ndarray, fired: np.ndarray, F: np.ndarray, h: np.ndarray
    ) -> dict[int, tuple[float, int]]:
        """The earliest event of the lanes whose step only fired joints coming to rest (batched).

        A sliding joint's zero-velocity event is its rate, one entry of the step's continuous
        extension: bisection on it, all lanes at once, to :attr:`DOP853.event_tol`, ends on
        the side after the crossing, as :func:`~vtm_pin.numerics.integrators.fixed_step.locate`
        does with Brent's method (the two agree to the tolerance, 1e-14 s by default). The
        earliest root is kept only if no other event of the lane has crossed by then: another
        rate, or a stuck joint's slip margin within :data:`_MARGIN_GUARD` of zero. Lanes with
        anything else (a slip fired, a rate starting at exactly 0, a step whose end is not
        past zero, an earlier crossing) are left to the phase's own events: ``{}`` for them.

        Returns:
            Per index into ``sub``: (offset [s] from the step's start, event index).
        """
        begin, dynamics = time.perf_counter(), self.seconds["dynamics"]
        n, tol = self.n, self.integrator.event_tol
        kind = lanes.event_kind[sub]
        g0 = lanes.y[sub, n : 2 * n]
        simple = fired.any(axis=1) & ~(fired & (kind != 1)).any(axis=1)
        simple &= ~(fired & (g0 == 0.0)).any(axis=1)
        lane, joint = np.nonzero(fired & simple[:, None])
        if lane.size == 0:
            return {}
        direction = lanes.event_dir[sub][lane, joint]
        start = g0[lane, joint]
        coef = F[lane, :, n + joint]  # (pairs, 7): the rates' continuous extensions

        def rate(tau: np.ndarray, some: slice | np.ndarray = slice(None)) -> np.ndarray:
            x = tau / h[lane][some]
            return start[some] + np.einsum("pj,pj->p", dp.dense_weights(x), coef[some])

        hi, ok = _roots(rate, start, h[lane], direction, tol)
        found: dict[int, tuple[float, int]] = {}
        for p in np.flatnonzero(ok):
            i = int(lane[p])
            candidate = (float(hi[p]), int(lanes.event_index[sub[i], joint[p]]))
            found[i] = min(found.get(i, candidate), candidate)
        rooted = np.zeros_like(fired)
        rooted[lane[ok], joint[ok]] = True
        for k in np.flatnonzero((fired & ~rooted).any(axis=1) & simple):  # a rate without root
            found.pop(int(k), None)
        self._drop_earlier(lanes, sub, F, h, found)
        inner = self.seconds["dynamics"] - dynamics  # the slip margins' right-hand sides
        self.seconds["location"] += time.perf_counter() - begin - inner
        return found

    def _drop_earlier(
        self,
        lanes: _Lanes,
        sub: np.ndarray,
        F: np.ndarray,
        h: np.ndarray,
        found: dict[int, tuple[float, int]],
    ) -> None:
        """Drop from ``found`` the lanes where another event crossed by the root found."""
        if not found:
            return
        n = self.n
        index = np.array(list(found), dtype=int)
        rows = sub[index]
        tau = np.array([found[int(i)][0] for i in index])
        x = tau / h[index]
        y = dp.dense_value(F[index], x, lanes.y[rows], _LANES)
        kind = lanes.event_kind[rows]
        first = np.array([found[int(i)][1] for i in index])
        own = lanes.event_index[rows] == first[:, None]
        rates = _crossed(lanes.y[rows, n : 2 * n], y[:, n : 2 * n], lanes.event_dir[rows])
        bad = (rates & (kind == 1) & ~own).any(axis=1)
        slips = (kind == 2).any(axis=1)
        if slips.any():
            _, lam = self.rhs(lanes, rows[slips], lanes.t[rows[slips]] + tau[slips], y[slips])
            g = self._g(lanes, rows[slips], lanes.t[rows[slips]] + tau[slips], y[slips], lam)
            scale = np.maximum(1.0, np.max(np.abs(lam), axis=1))
            near = (kind[slips] == 2) & ~(g > _MARGIN_GUARD * scale[:, None])
            bad[slips] |= near.any(axis=1)
        for i in index[bad]:
            del found[int(i)]

    def _dense_coefficients(self, lanes: _Lanes, rows: np.ndarray, step: _Step) -> np.ndarray:
        """The 7th-order continuous extensions' coefficients F, shape (B, 7, ny)."""
        drives = _drives(lanes, rows)

        def into(t: np.ndarray, y: np.ndarray, out: np.ndarray) -> None:
            out[...], _ = self.rhs(lanes, rows, t, y, drives)

        t, y = lanes.t[rows], lanes.y[rows]
        return dp.dense_coefficients(into, t, y, step.y_new, step.h, step.K, _LANES)

    def _finish(self, lanes: _Lanes, run: _Run, b: int, event: int | None) -> None:
        """Hand run ``b`` its segment (after the rests it settled) and take its next request."""
        self._hand(lanes, run, b, self._samples(lanes, run, b), event)

    def _hand(
        self,
        lanes: _Lanes,
        run: _Run,
        b: int,
        samples: tuple[np.ndarray, np.ndarray, np.ndarray | None],
        event: int | None,
    ) -> None:
        """Hand run ``b`` its interval's samples as its segment (reduced layout).

        A plain stop's interval that did not end as a plain stop's do (:meth:`_engage`) is not
        handed: the run goes back to its own loop (:meth:`_return`).
        """
        if run.left:
            self._return(lanes, run, b)
            return
        t, y, hold = samples
        steps = int(lanes.accepted[b])
        segment = Segment(t, y[:, run.reduced], int(lanes.evals[b]), event, steps, hold)
        reply: Reply = (*run.pieces, segment) if run.pieces else segment
        run.pieces = []
        self.advance(run, reply)

    def _sync(self, lanes: _Lanes, run: _Run, b: int) -> bool:
        """Hand run ``b`` the rests its lane settled, if any: its request is the lane's again.

        The run's phase (its own event functions) is then the one its lane integrates.
        Returns whether the run goes on (its loop may fail on them: the lane stops). A plain
        stop has no loop to hand them or phase to ask: it goes back to its own loop
        (:meth:`_return`), and does not go on.
        """
        if run.left:
            self._return(lanes, run, b)
            return False
        if run.pieces:
            pieces, run.pieces = tuple(run.pieces), []
            self.advance(run, pieces)
            if run.request is None:
                lanes.running[b] = False
        return run.request is not None

    def _conclude(self, lanes: _Lanes, run: _Run, b: int) -> None:
        """Run ``b``'s lane settled its rests and nothing slides on: hand them to its loop.

        A plain stop's joints are then all stuck: its records end it
        (:meth:`~vtm_pin.core.simulation.PlainStop.result`), or, if a lock was not at rest,
        it goes back to its own loop (:meth:`_return`).
        """
        plain = run.plain
        if plain is None:
            self._sync(lanes, run, b)
            return
        begin = time.perf_counter()
        pieces, run.pieces = tuple(run.pieces), []
        try:
            outcome: SimulationResult | VtmError | None = plain.result(pieces, run.problem.duration)
        except VtmError as exc:
            outcome = exc
        self.seconds["hybrid"] += time.perf_counter() - begin
        if outcome is None:
            self._return(lanes, run, b)
            return
        lanes.running[b] = False
        run.plain, run.outcome = None, outcome
        self._ended(run)

    def _return(self, lanes: _Lanes, run: _Run, b: int) -> None:
        """Hand a plain stop whose life is not plain after all back to its own loop.

        The loop starts again from t = 0 and its lane waits for the loop's first request, as
        a lane whose interval ended (the caller's lanes that ended are loaded next): such a
        run costs its first interval and what the engine ran of it twice.
        """
        run.restart()
        lanes.running[b] = False
        self.lane_python["plain_returned"] += 1
        self.advance(run)

    def _samples(
        self, lanes: _Lanes, run: _Run, b: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Run ``b``'s samples since its interval began, taken from it.

        Returns:
            Times [s], padded states and holding torques [N m] (NaN at free joints; None
            without :attr:`holding`).
        """
        begin = time.perf_counter()
        t, y, hold = np.concatenate(run.ts), np.concatenate(run.ys), None
        run.ts, run.ys = [], []
        if run.holds is not None:
            hold = np.concatenate(run.holds)
            hold[:, ~lanes.locked[b]] = np.nan
            run.holds = []
        self.seconds["lanes"] += time.perf_counter() - begin
        return t, y, hold

    def advance(
        self, run: _Run, segment: Reply | None = None, error: VtmError | None = None
    ) -> None:
        """Hand a run its segment(s) (or error), timing its hybrid loop; not once it has ended."""
        if run.outcome is not None:
            return
        begin = time.perf_counter()
        run.advance(segment, error)
        self.seconds["hybrid"] += time.perf_counter() - begin
        if segment is not None or error is not None:
            self.lane_python["resumptions"] += 1
            self.lane_python["intervals"] += (
                len(segment) if isinstance(segment, tuple) else int(segment is not None)
            )
        self._ended(run)

    def _ended(self, run: _Run) -> None:
        """Tell :attr:`finished` of a run that has its outcome (none yet: nothing)."""
        if run.outcome is not None and self.finished is not None:
            try:
                self.finished(run)
            except Exception as exc:  # not the engine's failure: it must not fall back
                raise _Finished(exc) from exc

    def _fail(
        self, lanes: _Lanes, runs: Sequence[_Run], b: int, error: VtmError, finished: list[int]
    ) -> None:
        """Run ``b`` fails in its lane's interval (after the rests it settled, as the scalar's).

        A plain stop goes back to its own loop instead (:meth:`_return`), which meets the
        failure itself.
        """
        finished.append(int(b))
        if runs[b].left:
            self._return(lanes, runs[b], b)
            return
        self._sync(lanes, runs[b], b)
        lanes.running[b] = False
        self.advance(runs[b], error=error)

    def _step_limit(self, lanes: _Lanes, run: _Run, b: int) -> StepLimitError:
        """The scalar dop853's error for run ``b``'s interval (its first sample is its start)."""
        it = self.integrator
        t0 = float(run.ts[0][0]) if run.ts else float(lanes.t[b])
        return StepLimitError(
            f"dop853 took {it.max_steps} steps from t = {t0:g} s and reached only "
            f"t = {lanes.t[b]:.6g} s of {lanes.t1[b]:g} s; the limit is {it.max_steps}: set "
            "integrator.max_steps, or loosen rtol / atol",
            it.max_steps + 1,
            it.max_steps,
        )


@dataclass
class _Step:
    """The accepted step of some lanes: sizes, whether last, errors, stages, new states.

    K: per lane the stages (f at the step's end in K[:, 12]), shape (B, 16, ny); it may be
    the engine's buffer of the round's stages (:meth:`select` of every lane copies nothing:
    3.4 MB a round of 1,250 UR10 lanes), valid until the next round's.
    """

    h: np.ndarray
    last: np.ndarray
    err: np.ndarray
    K: np.ndarray
    y_new: np.ndarray

    def select(self, mask: np.ndarray) -> _Step:
        """The lanes of ``mask``; this step itself if it holds every lane."""
        if mask.all():
            return self
        return _Step(self.h[mask], self.last[mask], self.err[mask], self.K[mask], self.y_new[mask])


#: Secant steps of the batched location of rests before its check (then bisection where needed).
_SECANT_STEPS = 6
#: A stuck joint's slip margin counts as clear of zero at a located rest, for the batched
#: location, above this fraction of the largest holding torque (at least 1 N m): the phase's own
#: margin, which the scalar location uses, differs from the batched one by round-off only.
_MARGIN_GUARD = 1e-6


def _roots(
    g: Callable[..., np.ndarray],
    g0: np.ndarray,
    h: np.ndarray,
    direction: np.ndarray,
    tol: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Where each of many functions g, at g0 at 0, crosses zero in (0, h] (to ``tol``).

    ``g(tau)`` evaluates all of them, ``g(tau, some)`` those indexed by ``some``.

    Secant steps from the ends (the rates are nearly linear over a step), then a check that
    the crossing lies between tau - tol / 2 and tau + tol / 2; where it does not, bisection.
    Either way the root returned is on the side after the crossing, less than ``tol`` past it.

    Returns:
        The roots [s], and whether each function has crossed by h at all (no root if not).
    """
    end = g(h)
    ok = _crossed(g0, end, direction)
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b, ga, gb = np.zeros_like(h), h.copy(), g0, end
        for _ in range(_SECANT_STEPS):
            c = b - gb * (b - a) / (gb - ga)
            c = np.clip(np.where(np.isfinite(c), c, b), 0.0, h)  # converged: 0 / 0
            a, ga, b, gb = b, gb, c, g(c)
    lo, hi = np.clip(b - 0.5 * tol, 0.0, h), np.clip(b + 0.5 * tol, 0.0, h)
    good = _crossed(g0, g(hi), direction) & ~_crossed(g0, g(lo), direction)
    left = np.flatnonzero(ok & ~good)
    if left.size:
        lo[left], hi[left] = 0.0, h[left]
        while np.any(hi[left] - lo[left] > tol):
            mid = 0.5 * (lo[left] + hi[left])
            past = _crossed(g0[left], g(mid, left), direction[left])
            hi[left], lo[left] = np.where(past, mid, hi[left]), np.where(past, lo[left], mid)
    return hi, ok


def _order_events(lanes: _Lanes, rows: np.ndarray) -> None:
    """Number the state events of lanes ``rows`` as their phases do.

    :meth:`~vtm_pin.physics.brakes.BrakeMachine.event_specs`: the sliding joints' rests in
    joint order, then the stuck joints' slips in joint order.
    """
    if rows.size == 0:
        return
    n = lanes.n
    kind = lanes.event_kind[rows]
    key = np.where(kind == 1, 0, np.where(kind == 2, n, 2 * n)) + np.arange(n)
    lanes.event_index[rows] = np.argsort(np.argsort(key, axis=1), axis=1)


@dataclass(frozen=True)
class _Drives:
    """What the right-hand side reads of some lanes, gathered once for a step's stages.

    Each lane's brakes and drives (gear ratios, modes' signs, sliding torques [N m], locks)
    do not change within a step. A term no lane of the batch has is None: viscous factors,
    the normal-force ramps (engagement times [s], ramp times [s]) and the short-circuit
    peaks (torque [N m], speed [rad/s]).
    """

    ratio: np.ndarray
    sign: np.ndarray
    torque: np.ndarray
    locked: np.ndarray
    viscous: np.ndarray | None
    ramp: tuple[np.ndarray, np.ndarray] | None
    short: tuple[np.ndarray, np.ndarray] | None


def _drives(lanes: _Lanes, rows: np.ndarray) -> _Drives:
    """The :class:`_Drives` of lanes ``rows``."""
    return _Drives(
        lanes.ratio[rows],
        lanes.sign[rows],
        lanes.torque[rows],
        lanes.locked[rows],
        lanes.viscous[rows] if lanes.viscous.any() else None,
        _ramps(lanes, rows),
        (lanes.short_torque[rows], lanes.short_speed[rows]) if lanes.short_torque.any() else None,
    )


def _ramps(lanes: _Lanes, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The rows' brakes' engagement and ramp times [s]; None where no lane's brake ramps."""
    return (lanes.engaged[rows], lanes.ramp[rows]) if lanes.ramp.any() else None


def _ramp(ramps: tuple[np.ndarray, np.ndarray] | None, t: np.ndarray) -> np.ndarray | float:
    """The brakes' normal-force ramp at times t [s]: 0 to 1 over ``ramp`` after engaging.

    1.0 where no lane's brake ramps (the factor is then 1 everywhere: the products are exact).
    """
    if ramps is None:
        return 1.0
    engaged, ramp = ramps
    elapsed = t[:, None] - engaged
    return np.where(ramp == 0.0, 1.0, np.clip(elapsed / np.where(ramp == 0.0, 1.0, ramp), 0.0, 1.0))


def _crossed(g0: np.ndarray, g1: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """:meth:`StateEvent.crossed`, elementwise (NaN never crosses)."""
    with np.errstate(invalid="ignore"):
        up = (direction >= 0) & (g0 < 0.0) & (0.0 <= g1)
        down = (direction <= 0) & (g0 > 0.0) & (0.0 >= g1)
        back = (g0 == 0.0) & (direction * g1 > 0.0)
    return up | down | back


@dataclass(frozen=True)
class BatchOutcome:
    """The outcome of many runs.

    Attributes:
        results: Per run, its result, or the error that ended it.
        engines: Per run, ``batched`` or ``scalar``.
        fallbacks: Per run, why it went to the scalar engine (None if batched).
        seconds: Wall time [s]: ``total``, and the batched engine's split (:data:`PARTS`).
        shares: Per batched run, its share of its batch's split [s]; None if scalar.
        calls: Batched Pinocchio calls (ABA, RNEA) made.
        states: States they evaluated.
        kernel_states: States with locks (or their own inertias) that the compiled kernel
            evaluated instead (:func:`~vtm_pin.physics.chain_dynamics.locked_dynamics`).
        lane_python: What the batches did lane by lane, counted (:data:`LANE_PYTHON`).
    """

    results: tuple[SimulationResult | VtmError, ...]
    engines: tuple[str, ...]
    fallbacks: tuple[str | None, ...]
    seconds: dict[str, float]
    shares: tuple[dict[str, float] | None, ...]
    calls: int
    states: int
    kernel_states: int = 0
    lane_python: dict[str, int] = dataclasses.field(default_factory=dict)


class _Finished(BaseException):
    """An error of a run's ``on_done`` call, carried through the engine's own handlers."""

    def __init__(self, error: Exception) -> None:
        super().__init__(error)
        self.error = error


#: Called with (run index, its result or error, why it went to the scalar engine or None, its
#: share of its batch's split so far [s] or None) as soon as a run of :func:`run_many` ends.
OnDone = Callable[
    [int, "SimulationResult | VtmError", "str | None", "dict[str, float] | None"], None
]


def run_many(
    problems: Sequence[Problem],
    integrators: Sequence[object],
    *,
    transition: str = "kkt",
    engine: str = "batched",
    threads: int = 1,
    on_done: OnDone | None = None,
    min_lanes: int = 1,
    holding: bool = True,
) -> BatchOutcome:
    """Run many problems; the batched engine takes those it can (see :func:`fallback_reason`).

    Runs whose models differ at most in their bodies' inertias (:func:`batch_key`) and that
    have the same integrator settings advance together (without the compiled kernel, a model
    with at least :data:`MIN_LANES` runs in a batch of its own: :func:`_groups`). A run's
    ``wall_time`` is
    its share of its batch's time. Groups of fewer than ``min_lanes`` runs go to the scalar
    engine (reason :data:`FEW_LANES`): a batch of a few lanes is slower than the scalar engine.

    Args:
        problems: The runs.
        integrators: Each run's integrator.
        transition: Transition rule of every run.
        engine: ``batched``, or ``scalar`` for one :func:`~vtm_pin.core.simulation.simulate` per
            run.
        threads: Threads of Pinocchio's parallel algorithms.
        on_done: Called as soon as each run ends (in the order they end), so that a caller
            can keep its finished runs if it is interrupted. A batched run's result then has
            as its ``wall_time`` the batch's time since the batch's previous run ended (these
            add up to the batch's time); the outcome returned at the end has equal shares of
            it. The time spent in ``on_done`` itself is not the batch's. An error it raises
            ends the call.
        min_lanes: Fewest runs a batch is given (a study's runner uses :data:`MIN_LANES`).
        holding: False: the results' holding torques are not computed (NaN at every sample)
            for a caller that reads none (a study's records: ~70 of a UR10 case's ~290
            right-hand sides are its output samples'); the runs' motions, brake decisions
            and events do not change.

    Raises:
        SimulationError: An unknown engine.
    """
    if engine not in ENGINES:
        raise SimulationError(f"Unknown engine '{engine}'; allowed: {', '.join(ENGINES)}")
    begin = time.perf_counter()
    results: list[SimulationResult | VtmError | None] = [None] * len(problems)
    reasons = [
        "engine scalar chosen" if engine == "scalar" else fallback_reason(p, i)
        for p, i in zip(problems, integrators, strict=True)
    ]
    keys = _model_keys(problems, reasons)
    groups = _groups(problems, integrators, reasons, min_lanes, keys)
    for index, (problem, reason) in enumerate(zip(problems, reasons, strict=True)):
        if reason is None:
            continue
        results[index] = _simulate_one(problem, integrators[index], transition, holding)
        if on_done is not None:
            on_done(index, results[index], reason, None)  # type: ignore[arg-type]
    seconds = dict.fromkeys(PARTS, 0.0)
    shares: list[dict[str, float] | None] = [None] * len(problems)
    calls = states = kernel_states = 0
    lane_python = dict.fromkeys(LANE_PYTHON, 0)
    for (_, integrator), indices in groups.items():
        started = time.perf_counter()
        runs = [
            _Run(i, problems[i], integrator, transition, holding)  # type: ignore[arg-type]
            for i in indices
        ]
        robots = [problems[i].robot for i in indices]
        models = [robot.model for robot in robots]
        base = _base_model(robots, [keys[i] for i in indices])
        batch = BatchEngine(base, integrator, threads, models, holding)  # type: ignore[arg-type]
        clock = _Clock(batch, started)
        _run_batch(batch, runs, problems, reasons, on_done, clock)
        parts = clock.parts_now()
        elapsed = sum(parts.values())
        share = {name: value / len(runs) for name, value in parts.items()}
        for run in runs:
            outcome = run.outcome
            if isinstance(outcome, SimulationResult):
                outcome = dataclasses.replace(outcome, wall_time=elapsed / len(runs))
            results[run.index] = outcome
            shares[run.index] = share
        for name, value in parts.items():
            seconds[name] += value
        calls += batch.dynamics.calls
        states += batch.dynamics.states
        kernel_states += batch.dynamics.kernel_states
        for name, count in batch.lane_python.items():
            lane_python[name] += count
    seconds["total"] = time.perf_counter() - begin
    assert all(r is not None for r in results)
    return BatchOutcome(
        results=tuple(results),  # type: ignore[arg-type]
        engines=tuple("scalar" if r is not None else "batched" for r in reasons),
        fallbacks=tuple(reasons),
        seconds=seconds,
        shares=tuple(shares),
        calls=calls,
        states=states,
        kernel_states=kernel_states,
        lane_python=lane_python,
    )


def _model_keys(problems: Sequence[Problem], reasons: Sequence[str | None]) -> list[bytes]:
    """:func:`robot_model_key` of each run's robot, once per robot object.

    A study's cases share one robot per payload. b"" for the runs that go to the scalar
    engine (those with a ``reason``).
    """
    known: dict[int, bytes] = {}
    out = []
    for problem, reason in zip(problems, reasons, strict=True):
        key = b"" if reason is not None else known.get(id(problem.robot))
        if key is None:
            key = known[id(problem.robot)] = robot_model_key(problem.robot)
        out.append(key)
    return out


def _groups(
    problems: Sequence[Problem],
    integrators: Sequence[object],
    reasons: list[str | None],
    min_lanes: int,
    keys: Sequence[bytes],
) -> dict[tuple[bytes, object], list[int]]:
    """The batches: indices of runs of one integrator, at least ``min_lanes``.

    Without the compiled kernel, a model with at least :data:`MIN_LANES` runs gets a batch of
    its own (:func:`model_key`: its lanes cost least, ABA where nothing is locked); the runs of
    the other models are pooled by :func:`batch_key` (their lanes carry their own inertias,
    which costs more per lane than a batch of their own model but less than the scalar
    engine). With it (:func:`~vtm_pin.physics.chain_dynamics.runs`), every state goes through
    the kernel with its lane's own bodies' parameters, whatever its batch: a lane costs the
    same pooled, its motion is the same to the bit, and a batch's steps cost less per lane
    the more lanes share them, so every run is pooled (measured, issue 27: the UR10 envelope
    study's six payload classes in one batch, ~8 % less time a case than in six). The runs
    of smaller groups are given the reason :data:`FEW_LANES` (in ``reasons``). ``keys``: the
    problems' robots' :func:`robot_model_key`.
    """
    own = not chain_dynamics.runs()  # a batch of its own for a model with enough runs
    exact: dict[tuple[bytes, object], list[int]] = {}
    for index, reason in enumerate(reasons):
        if reason is None:
            exact.setdefault((keys[index], integrators[index]), []).append(index)
    groups: dict[tuple[bytes, object], list[int]] = {}
    for (model, integrator), indices in exact.items():
        if own and len(indices) >= MIN_LANES:
            groups[b"model " + model, integrator] = indices
        else:
            pool = (robot_batch_key(problems[indices[0]].robot), integrator)
            groups.setdefault(pool, []).extend(indices)
    for key, indices in list(groups.items()):
        indices.sort()
        if len(indices) < min_lanes:
            del groups[key]
            for index in indices:
                reasons[index] = FEW_LANES.format(min_lanes=min_lanes)
    return groups


def _base_model(robots: Sequence[Robot], keys: Sequence[bytes]) -> pin.Model:
    """The batch's model: the one most of its runs' robots have (they cost nothing more).

    In a tie, the first of those models in the order of the runs. ``keys``: the robots'
    :func:`robot_model_key`.
    """
    counts = collections.Counter(keys)
    return robots[keys.index(max(counts, key=counts.__getitem__))].model


def _run_batch(
    batch: BatchEngine,
    runs: Sequence[_Run],
    problems: Sequence[Problem],
    reasons: list[str | None],
    on_done: OnDone | None,
    clock: _Clock,
) -> None:
    """Drive ``runs`` on ``batch``; if the engine fails, the runs left go to the scalar one."""
    if on_done is not None:
        batch.finished = functools.partial(_report, on_done, clock)
    try:
        for run in runs:
            if not run.direct:  # a plain stop the engine starts itself has no loop
                batch.advance(run)
        batch.run(runs)
    except _Finished as stop:
        raise stop.error from None
    except Exception as exc:
        for run in runs:
            if run.outcome is None:
                transition = run.transition
                run.outcome = _simulate_one(
                    problems[run.index], batch.integrator, transition, batch.holding
                )
                reasons[run.index] = f"the batched engine failed ({type(exc).__name__})"
                if on_done is not None:
                    on_done(run.index, run.outcome, reasons[run.index], None)
    finally:
        # The engine and its clock refer to each other: left so, the batch, its runs and
        # whatever ``on_done`` holds (a study's scenarios and results) would wait for the
        # collector's oldest generation, which a study worker's thresholds make rare.
        batch.finished = None


class _Clock:
    """A batch's time, handed out to its runs as they end: each gets the time since the last.

    The shares add up to the batch's time (its mean is the batch's time over its runs, as
    the outcome's equal shares), and each is known when its run ends. The time spent in the
    caller's ``on_done`` (a study's report of the case) is not the batch's: it is left out.
    """

    def __init__(self, batch: BatchEngine, started: float) -> None:
        self.batch = batch
        self.started = started
        self.outside = 0.0  # [s] in on_done
        self.parts = dict.fromkeys(PARTS, 0.0)

    def parts_now(self) -> dict[str, float]:
        """The batch's split [s] since it started, the callbacks' time left out."""
        elapsed = time.perf_counter() - self.started - self.outside
        return {**self.batch.seconds, "stepping": elapsed - sum(self.batch.seconds.values())}

    def share(self) -> dict[str, float]:
        """The batch's split [s] since the last call."""
        parts = self.parts_now()
        share = {name: parts[name] - self.parts[name] for name in PARTS}
        self.parts = parts
        return share


def _report(on_done: OnDone, clock: _Clock, run: _Run) -> None:
    """Hand a finished batched run to ``on_done``, with its share of the batch's time."""
    outcome = run.outcome
    assert outcome is not None
    share = clock.share()
    if isinstance(outcome, SimulationResult):
        outcome = dataclasses.replace(outcome, wall_time=sum(share.values()))
    begin = time.perf_counter()
    try:
        on_done(run.index, outcome, None, share)
    finally:
        clock.outside += time.perf_counter() - begin


def _simulate_one(
    problem: Problem, integrator: object, transition: str, holding: bool = True
) -> SimulationResult | VtmError:
    """One run on the scalar engine; its result or the error that ended it."""
    from .simulation import simulate

    try:
        return simulate(problem, integrator, transition=transition, holding=holding)  # type: ignore[arg-type]
    except Exception as exc:
        return _as_vtm_error(exc)


def simulate_many(
    problems: Sequence[Problem],
    integrator: object,
    *,
    transition: str = "kkt",
    engine: str = "batched",
    threads: int = 1,
) -> list[SimulationResult]:
    """Simulate many problems with one integrator; the first failure is raised.

    Args:
        problems: The runs.
        integrator: The integrator of every run.
        transition: Transition rule of every run.
        engine: ``batched`` (runs it cannot take go to the scalar engine) or ``scalar``.
        threads: Threads of Pinocchio's parallel algorithms.

    Raises:
        VtmError: The first run that failed.
    """
    outcome = run_many(
        problems,
        [integrator] * len(problems),
        transition=transition,
        engine=engine,
        threads=threads,
    )
    for result in outcome.results:
        if isinstance(result, VtmError):
            raise result
    return list(outcome.results)  # type: ignore[arg-type]


def _as_vtm_error(exc: Exception) -> VtmError:
    """``exc`` as the error a run ends with (a bug says so in one line)."""
    if isinstance(exc, VtmError):
        return exc
    return SimulationError(f"internal error ({type(exc).__name__}: {exc})")


def _start_grid(lanes: _Lanes, b: int, run: _Run, t0: float, t1: float) -> None:
    """Run ``b``'s output times in its interval [t0, t1] [s], noted in its lane."""
    grid = run.grid = None if run.output_dt is None else _Grid(run.output_dt, t0, t1)
    lanes.next_out[b] = math.inf if grid is None else grid.k * grid.dt
    lanes.out_end[b] = -math.inf if grid is None else grid.end


def _grid_times(lanes: _Lanes, b: int, grid: _Grid | None, until: float, times: list[float]) -> int:
    """Append lane ``b``'s output times up to ``until`` [s] (and its end); how many."""
    if grid is None:
        return 0
    limit = min(until, grid.end)
    count = 0
    while (when := grid.k * grid.dt) <= limit:
        times.append(when)
        grid.k += 1
        count += 1
    lanes.next_out[b] = when
    return count
