"""MuJoCo's batched rollout against vtm_pin's many-case engine: same cases, same accuracy.

Issue 14, "a peer for studies". Each of the paper's examples (``pendulum3r``: 3R, locks at
0.8 and 1.3 s; ``rx160l_paper_locks``: 6R, locks at 0, 0.05, 0.1, 0.15 s) becomes ``--cases``
cases that differ only in the initial velocity: v0 times a factor drawn uniformly in
[0.5, 1.5] (fixed seed). The 3R example starts at rest, so there v0 = (factor - 1) x 1 rad/s
on every joint (a spread of -0.5..0.5 rad/s centred on the paper's case). Lock times are
unchanged, so every case has the same topology sequence and lock times on every RK4 grid used.

MuJoCo side (exact locks, as :func:`mujoco_reference.run_exact`): per topology phase one
``mujoco.rollout`` call over all cases (a list of models, one per case, since the lock angles
differ per case), then the momentum-consistent (``kkt``) jump of every case with MuJoCo's own
mass matrix, solved as one batched KKT system. The topology models are compiled before the
run and not timed (as in ``run_exact``): the bodies of joints that lock during the run are kept
out of MuJoCo's static-body fusion so that writing each case's lock angle into its model's
``body_quat`` (timed, with the rollouts, the mass matrices and the jumps) replaces compiling;
the wrist locks of the 6R example at t = 0 are the same in every case and are compiled in.
Rollouts run on persistent ``mujoco.rollout.Rollout`` objects: ``nthread=0`` (in the calling
thread, "1 thread") and ``nthread=2``.

vtm_pin side: ``vtm_pin.core.batch.simulate_many`` (engine "batched" and "scalar") with DOP853 at
rtol 1e-3..1e-12 (atol = rtol / 100); a stand-in looping ``vtm_pin.core.simulation.simulate`` if
that module is missing.

Error: max over cases of max |q(T) - q_ref(T)| [rad], q_ref from DOP853 at rtol 1e-13. For
each target the cheapest setting (largest dt or rtol, no interpolation) with error <= target
is chosen per side. Each ladder runs coarse to fine and stops once every target is met.
Every setting is run once (warm-up, error), then all are timed round robin ``--repeats``
times (so a drifting machine load hits every side alike) and the median is kept; run it
with ``OMP_NUM_THREADS=1``.

    python benchmarks/mujoco_rollout.py [--cases 256] [--repeats 3] [--out benchmarks/out]
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import functools
import json
import os
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import mujoco
import mujoco.rollout
import mujoco_reference as mr
import numpy as np
from benchlib import REFERENCE_RTOL, make_integrator
from matplotlib.figure import Figure

import vtm_pin as vp
from vtm_pin.core.problem import Problem
from vtm_pin.core.results import SimulationResult
from vtm_pin.core.simulation import simulate
from vtm_pin.numerics.constraints import lock_jacobian
from vtm_pin.numerics.integrators import Integrator
from vtm_pin.numerics.transitions import kkt

try:
    from vtm_pin.core.batch import simulate_many

    BATCH_ENGINE = "vtm_pin.core.batch.simulate_many"
except ImportError:
    BATCH_ENGINE = "stand-in: loop of vtm_pin.core.simulation.simulate (vtm_pin.core.batch missing)"

    def simulate_many(
        problems: Sequence[Problem],
        integrator: Integrator,
        *,
        transition: str = "kkt",
        engine: str = "batched",
    ) -> list[SimulationResult]:
        """Stand-in for ``vtm_pin.core.batch.simulate_many``: one scalar simulation per problem."""
        del engine  # both engines are the scalar loop here
        return [simulate(p, integrator, transition=transition) for p in problems]


ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ("pendulum3r", "rx160l_paper_locks")
#: Target errors [rad].
TARGETS = (1e-4, 1e-5, 1e-6, 1e-7, 1e-8)
#: RK4 steps [s] of MuJoCo, as work_precision.MUJOCO_DT; those off a scenario's lock grid are
#: skipped.
MUJOCO_DT = (5e-2, 2.5e-2, 1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4)
#: DOP853 relative tolerances [-] of vtm_pin (atol = rtol / 100).
RTOLS = tuple(10.0**-k for k in range(3, 13))
#: Initial velocity [rad/s] per unit (factor - 1) for a scenario that starts at rest.
ZERO_V0_SCALE = 1.0
#: Most RK4 steps per rollout call (bounds the state output buffer, N x CHUNK x nstate).
CHUNK = 1000
SEED = 0


@dataclass
class Point:
    """One setting of one side: accuracy and median wall time.

    Attributes:
        side: ``mujoco-1thread``, ``mujoco-2threads``, ``vtm_pin-batched`` or
            ``vtm_pin-scalar``.
        setting: RK4 step dt [s] (MuJoCo) or DOP853 rtol [-] (vtm_pin).
        error: Max over cases of max |q(T) - q_ref(T)| [rad].
        wall: Median wall time of the whole batch [s].
        rollout: Median time inside ``mujoco.rollout`` [s] (MuJoCo only, else NaN).
        times: Every repeat's wall time [s].
    """

    side: str
    setting: float
    error: float
    wall: float
    rollout: float = float("nan")
    times: list[float] = field(default_factory=list)


def make_cases(problem: Problem, n: int, seed: int = SEED) -> list[Problem]:
    """``n`` variants of ``problem`` whose v0 [rad/s] is scaled by factors in [0.5, 1.5]."""
    factors = np.random.default_rng(seed).uniform(0.5, 1.5, n)
    v0 = np.asarray(problem.v0, dtype=float)
    if np.any(v0):
        velocities = factors[:, None] * v0
    else:  # at rest: spread around it instead of scaling zero
        velocities = (factors[:, None] - 1.0) * ZERO_V0_SCALE * np.ones_like(v0)
    return [dataclasses.replace(problem, v0=v) for v in velocities]


def reference(problems: Sequence[Problem]) -> np.ndarray:
    """Final positions q(T) [rad] of every case by DOP853 at rtol 1e-13, shape (N, n)."""
    integrator = make_integrator("dop853", REFERENCE_RTOL)
    return np.array([simulate(p, integrator, transition="kkt").q[-1] for p in problems])


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (w, x, y, z) quaternions, broadcast over leading axes."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


@dataclass
class _Phase:
    """One topology phase of the replay: its models and what locks at its end."""

    steps: int
    lock: list[int]  # joints (indices) locking at the end of the phase
    locked: list[int]  # joints locked during the phase
    varying: list[int]  # those whose lock angle differs per case, in body_ids order
    free: list[int]
    models: list[mujoco.MjModel]  # one per case (the same one while nothing is locked)
    body_ids: list[int]  # body of each locked joint, in the phase's models
    base_quat: np.ndarray  # their body_quat at lock angle 0, shape (k, 4)
    axes: np.ndarray  # their joint axes (unit, body frame), shape (k, 3)
    template: np.ndarray  # a full-physics state of the phase's models, shape (nstate,)
    data: list[mujoco.MjData]  # one per thread


def _phase_models(
    scenario: vp.Scenario, dt: float, locked: list[str], fixed: dict[str, float], n_cases: int
) -> tuple[list[mujoco.MjModel], list[int], np.ndarray, np.ndarray]:
    """Models of one topology, one per case; lock angles are set per run in ``body_quat``.

    As :func:`mujoco_reference._locked_model` (locked joints deleted, jointless bodies fused
    into their parents). Joints in ``fixed`` lock at an angle [rad] known before the run (at
    t = 0, the same for every case): it is compiled in. Each other locked joint's body is kept
    out of the fusion (an excluded contact pair with the world; contacts are off) so that each
    case's lock angle can be written into its own model without compiling.

    Returns:
        The models, the kept bodies' ids, their ``body_quat`` at lock angle 0 (k, 4) and their
        joint axes (k, 3, unit, body frame), in the order of the non-fixed ``locked``.
    """
    spec = mr._spec(scenario, dt)
    bodies, axes = {}, {}
    for joint in list(spec.joints):
        if joint.name not in locked:
            continue
        body = joint.parent
        axis = np.asarray(joint.axis, dtype=float) / np.linalg.norm(joint.axis)
        if joint.name in fixed:
            turn = np.zeros(4)
            mujoco.mju_axisAngle2Quat(turn, axis, fixed[joint.name])
            body.quat = _quat_mul(np.asarray(body.quat, dtype=float), turn)
        else:
            bodies[joint.name], axes[joint.name] = body.name, axis
            spec.add_exclude(bodyname1=body.name, bodyname2=spec.worldbody.name)
        spec.delete(joint)
    model = spec.compile()
    varying = [j for j in locked if j not in fixed]
    ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, bodies[j]) for j in varying]
    base = model.body_quat[ids].copy()
    models = [copy.copy(model) for _ in range(n_cases)] if varying else [model] * n_cases
    return models, ids, base, np.array([axes[j] for j in varying]).reshape(-1, 3)


class MujocoBatch:
    """Exact-lock replay of N cases of one scenario with ``mujoco.rollout``, RK4 step dt [s].

    Raises:
        ValueError: A lock time is not on the dt grid, or the scenario has brakes or a stop.
    """

    def __init__(self, scenario: vp.Scenario, dt: float, q0: np.ndarray) -> None:
        """Compile every topology's models (not timed) for the cases starting at q0 [rad] (N, n).

        Locks at t = 0 whose angle is the same in every case are compiled in.
        """
        mr._check(scenario)
        self.joints = list(scenario.robot.joints)
        n_cases = len(q0)
        plan = mr._schedule(scenario, dt)
        fixed = {
            joint: float(q0[0, i])
            for e in scenario.events
            if e.t == 0.0
            for joint in e.lock
            if np.all(q0[:, (i := self.joints.index(joint))] == q0[0, i])
        }
        self.full = mr._spec(scenario, dt).compile()
        self.full_data = mujoco.MjData(self.full)
        self.phases: list[_Phase] = []
        locked: list[str] = []
        size = 0
        for steps, lock in plan:
            free = [i for i, j in enumerate(self.joints) if j not in locked]
            models: list[mujoco.MjModel] = []
            ids: list[int] = []
            base = axes = template = np.zeros((0, 4))
            data: list[mujoco.MjData] = []
            if steps and free:
                models, ids, base, axes = _phase_models(scenario, dt, locked, fixed, n_cases)
                data = [mujoco.MjData(models[0]) for _ in range(2)]
                nstate = mujoco.mj_stateSize(models[0], mujoco.mjtState.mjSTATE_FULLPHYSICS)
                if models[0].nq != len(free) or nstate < 1 + 2 * len(free):
                    raise RuntimeError("unexpected MuJoCo state layout")
                template = np.empty(nstate)
                mujoco.mj_getState(
                    models[0], data[0], template, mujoco.mjtState.mjSTATE_FULLPHYSICS
                )
                size = max(size, n_cases * min(steps, CHUNK) * nstate)
            self.phases.append(
                _Phase(
                    steps,
                    [self.joints.index(j) for j in lock],
                    [self.joints.index(j) for j in locked],
                    [self.joints.index(j) for j in locked if j not in fixed],
                    free,
                    models,
                    ids,
                    base,
                    axes,
                    template,
                    data,
                )
            )
            locked = [*locked, *lock]
        self.buffer = np.empty(size)  # state output of the rollouts, reused

    def _set_lock_angles(self, phase: _Phase, q: np.ndarray) -> None:
        """Write each case's lock angles [rad] into its model's ``body_quat``."""
        if not phase.varying:
            return
        half = 0.5 * q[:, phase.varying]  # (N, k)
        turn = np.concatenate(
            [np.cos(half)[..., None], np.sin(half)[..., None] * phase.axes], axis=-1
        )
        quats = _quat_mul(phase.base_quat, turn)  # (N, k, 4)
        for model, quat in zip(phase.models, quats, strict=True):
            model.body_quat[phase.body_ids] = quat

    def _roll(self, phase: _Phase, state: np.ndarray, pool: mujoco.rollout.Rollout) -> np.ndarray:
        """All cases through the phase's steps, CHUNK steps per call; the final states.

        Shapes and types are right by construction, so ``rollout``'s checks are skipped.
        """
        remaining, n = phase.steps, state.shape
        while remaining:
            k = min(CHUNK, remaining)
            out = self.buffer[: n[0] * k * n[1]].reshape(n[0], k, n[1])
            data = phase.data[: max(1, pool.nthread)]
            pool.rollout(phase.models, data, state, nstep=k, state=out, skip_checks=True)
            state = np.ascontiguousarray(out[:, -1])
            remaining -= k
        return state

    def _jump(self, q: np.ndarray, v: np.ndarray, phase: _Phase) -> np.ndarray:
        """Momentum-consistent velocities [rad/s] after the phase's locks, every case at once.

        The KKT system of :mod:`vtm_pin.numerics.transitions.kkt` with MuJoCo's mass matrix,
        batched.
        """
        n, N = len(self.joints), len(q)
        rows = [*phase.locked, *phase.lock]
        J = lock_jacobian(n, rows)
        m = J.shape[0]
        M = np.empty((N, n, n))
        for i in range(N):
            self.full_data.qpos[:] = q[i]
            mujoco.mj_kinematics(self.full, self.full_data)
            mujoco.mj_comPos(self.full, self.full_data)
            mujoco.mj_makeM(self.full, self.full_data)
            mujoco.mj_fullM(self.full, self.full_data, M[i])
        K = np.zeros((N, n + m, n + m))
        K[:, :n, :n] = M
        K[:, :n, n:] = J.T
        K[:, n:, :n] = J
        rhs = np.zeros((N, n + m, 1))
        rhs[:, n:, 0] = -v @ J.T
        return v + np.linalg.solve(K, rhs)[:, :n, 0]

    def run(
        self,
        q0: np.ndarray,
        v0: np.ndarray,
        pool: mujoco.rollout.Rollout,
        check: bool = False,
    ) -> tuple[np.ndarray, float, float]:
        """Final positions [rad] (N, n), wall time [s] and time inside ``rollout`` [s].

        Args:
            q0: Initial positions [rad], shape (N, n).
            v0: Initial velocities [rad/s], shape (N, n).
            pool: A ``Rollout`` (``nthread=0``: in the calling thread; else its thread pool).
            check: Compare the first case's jumps with ``kkt.compute_transition`` (slow).
        """
        q, v = q0.copy(), v0.copy()
        t, rolling = 0.0, 0.0
        start = time.perf_counter()
        for phase in self.phases:
            if phase.models:
                self._set_lock_angles(phase, q)
                nq = len(phase.free)
                state = np.tile(phase.template, (len(q), 1))
                state[:, 0] = t
                state[:, 1 : 1 + nq] = q[:, phase.free]
                state[:, 1 + nq : 1 + 2 * nq] = v[:, phase.free]
                started = time.perf_counter()
                state = self._roll(phase, state, pool)
                rolling += time.perf_counter() - started
                q[:, phase.free] = state[:, 1 : 1 + nq]
                v[:, phase.free] = state[:, 1 + nq : 1 + 2 * nq]
            t += phase.steps * self.full.opt.timestep
            if phase.lock:
                v_minus = v
                v = self._jump(q, v, phase)
                if check:
                    self._check_jump(q[0], v_minus[0], v[0], phase)
        return q, time.perf_counter() - start, rolling

    def _check_jump(self, q: np.ndarray, v_minus: np.ndarray, v: np.ndarray, ph: _Phase) -> None:
        """The batched jump of one case against vtm_pin's ``kkt`` rule (as run_exact)."""
        n = len(self.joints)
        self.full_data.qpos[:] = q
        mujoco.mj_forward(self.full, self.full_data)
        M = np.zeros((n, n))
        mujoco.mj_fullM(self.full, self.full_data, M)
        expected = kkt.compute_transition(
            M, lock_jacobian(n, ph.locked), lock_jacobian(n, ph.lock), v_minus
        ).v_plus
        if not np.allclose(v, expected, rtol=1e-10, atol=1e-12):
            raise RuntimeError(f"batched jump differs from kkt: {v} vs {expected}")


@dataclass
class _Job:
    """One side at one setting: what to time, and the error of its warm-up run [rad]."""

    side: str
    setting: float
    error: float
    run: Callable[[], tuple[float, float]]  # -> (wall [s], rollout [s] or NaN)
    samples: list[tuple[float, float]] = field(default_factory=list)


def _mujoco_times(
    batch: MujocoBatch, q0: np.ndarray, v0: np.ndarray, pool: mujoco.rollout.Rollout
) -> tuple[float, float]:
    """Wall time [s] and time inside ``rollout`` [s] of one batch run."""
    return batch.run(q0, v0, pool)[1:]


def _vtm_pin_times(
    problems: Sequence[Problem], integrator: Integrator, engine: str
) -> tuple[float, float]:
    """Wall time [s] of one ``simulate_many`` call over every case (and NaN)."""
    start = time.perf_counter()
    simulate_many(problems, integrator, transition="kkt", engine=engine)
    return time.perf_counter() - start, float("nan")


def mujoco_jobs(
    scenario: vp.Scenario,
    problems: Sequence[Problem],
    q_ref: np.ndarray,
    pools: tuple[mujoco.rollout.Rollout, mujoco.rollout.Rollout],
) -> list[_Job]:
    """MuJoCo at every dt of :data:`MUJOCO_DT` on the lock grid, coarse to fine, 1 and 2 threads.

    Each dt is run once per thread count (warm-up, error; the jumps checked against ``kkt``
    and the first case against ``run_exact``); the ladder stops after the first dt whose error
    is below every target.
    """
    q0 = np.array([p.q0 for p in problems])
    v0 = np.array([p.v0 for p in problems])
    jobs = []
    for dt in MUJOCO_DT:
        try:
            batch = MujocoBatch(scenario, dt, q0)
        except ValueError:  # a lock time off this grid
            continue
        q = batch.run(q0, v0, pools[0], check=True)[0]
        exact = mr.run_exact(dataclasses.replace(scenario, problem=problems[0]), dt).q
        if not np.allclose(q[0], exact, rtol=0.0, atol=1e-9):
            raise RuntimeError(f"case 0 differs from run_exact: {q[0]} vs {exact}")
        if not np.array_equal(batch.run(q0, v0, pools[1])[0], q):
            raise RuntimeError("2 rollout threads give other results than 1")
        error = float(np.max(np.abs(q - q_ref)))
        for side, pool in zip(("mujoco-1thread", "mujoco-2threads"), pools, strict=True):
            once = functools.partial(_mujoco_times, batch, q0, v0, pool)
            jobs.append(_Job(side, dt, error, once))
        print(f"  mujoco dt {dt:.2g} s: error {error:.2e} rad", file=sys.stderr)
        if error <= min(TARGETS):
            break
    return jobs


def vtm_pin_jobs(problems: Sequence[Problem], q_ref: np.ndarray) -> list[_Job]:
    """vtm_pin's batched and scalar engines at every rtol of :data:`RTOLS`, loose to tight.

    Each is run once (warm-up, error); the ladder stops after the first rtol whose error is
    below every target with both engines.
    """
    jobs = []
    for rtol in RTOLS:
        integrator = make_integrator("dop853", rtol)
        errors = []
        for engine in ("batched", "scalar"):
            results = simulate_many(problems, integrator, transition="kkt", engine=engine)
            error = float(np.max(np.abs(np.array([r.q[-1] for r in results]) - q_ref)))
            once = functools.partial(_vtm_pin_times, problems, integrator, engine)
            jobs.append(_Job(f"vtm_pin-{engine}", rtol, error, once))
            errors.append(error)
        print(
            f"  vtm_pin rtol {rtol:.0e}: errors {errors[0]:.2e}, {errors[1]:.2e} rad",
            file=sys.stderr,
        )
        if max(errors) <= min(TARGETS):
            break
    return jobs


def time_jobs(jobs: Sequence[_Job], repeats: int) -> list[Point]:
    """Time every job ``repeats`` times, round robin (machine load drifts alike for all)."""
    for _ in range(repeats):
        for job in jobs:
            job.samples.append(job.run())
    return [
        Point(
            job.side,
            job.setting,
            job.error,
            statistics.median(w for w, _ in job.samples),
            statistics.median(r for _, r in job.samples),
            [w for w, _ in job.samples],
        )
        for job in jobs
    ]


def cheapest(points: Sequence[Point], side: str, target: float) -> Point | None:
    """The cheapest point of ``side`` with error <= ``target`` [rad], if any.

    Cheapest in work: the largest dt or rtol (fewer steps), not the smallest wall time, so
    that noise in the timings of a loaded machine cannot pick a finer setting.
    """
    ok = [p for p in points if p.side == side and p.error <= target]
    return max(ok, key=lambda p: p.setting) if ok else None


def table(points: Sequence[Point]) -> list[dict[str, float]]:
    """Per target: each side's cheapest setting, its time [s], and the ratios."""
    nan = float("nan")
    rows = []
    for target in TARGETS:
        m1 = cheapest(points, "mujoco-1thread", target)
        m2 = cheapest(points, "mujoco-2threads", target)
        ours = cheapest(points, "vtm_pin-batched", target)
        scalar = cheapest(points, "vtm_pin-scalar", target)
        ours_wall = ours.wall if ours else nan
        rows.append(
            {
                "target": target,
                "mujoco_dt": m1.setting if m1 else nan,
                "mujoco_1thread": m1.wall if m1 else nan,
                "mujoco_1thread_rollout": m1.rollout if m1 else nan,
                "mujoco_2threads": m2.wall if m2 else nan,
                "mujoco_2threads_rollout": m2.rollout if m2 else nan,
                "vtm_pin_rtol": ours.setting if ours else nan,
                "vtm_pin_batched": ours_wall,
                "vtm_pin_scalar_rtol": scalar.setting if scalar else nan,
                "vtm_pin_scalar": scalar.wall if scalar else nan,
                "ratio_mujoco1_over_vtm_pin": (m1.wall if m1 else nan) / ours_wall,
                "ratio_mujoco2_over_vtm_pin": (m2.wall if m2 else nan) / ours_wall,
            }
        )
    return rows


def format_table(rows: Sequence[dict[str, float]]) -> str:
    """The table of :func:`table` as text; MuJoCo cells are total (rollout only) [s]."""
    head = (
        f"{'target':>7} | {'dt [s]':>7} {'MuJoCo 1 thr [s]':>18} {'MuJoCo 2 thr [s]':>18} | "
        f"{'rtol':>6} {'vtm batched':>11} {'rtol':>6} {'vtm scalar':>10} | "
        f"{'MJ1/vtm':>7} {'MJ2/vtm':>7}"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        mj1 = f"{r['mujoco_1thread']:.3f} ({r['mujoco_1thread_rollout']:.3f})"
        mj2 = f"{r['mujoco_2threads']:.3f} ({r['mujoco_2threads_rollout']:.3f})"
        lines.append(
            f"{r['target']:>7.0e} | {r['mujoco_dt']:>7.2g} {mj1:>18} {mj2:>18} | "
            f"{r['vtm_pin_rtol']:>6.0e} {r['vtm_pin_batched']:>11.3f} "
            f"{r['vtm_pin_scalar_rtol']:>6.0e} {r['vtm_pin_scalar']:>10.3f}"
            f" | {r['ratio_mujoco1_over_vtm_pin']:>7.2f} {r['ratio_mujoco2_over_vtm_pin']:>7.2f}"
        )
    return "\n".join(lines)


def format_points(points: Sequence[Point]) -> str:
    """Every measured setting: side, dt or rtol, error [rad], wall and rollout time [s]."""
    lines = [f"{'side':<16} {'dt/rtol':>8} {'error [rad]':>12} {'wall [s]':>9} {'rollout':>9}"]
    for p in points:
        lines.append(
            f"{p.side:<16} {p.setting:>8.2g} {p.error:>12.2e} {p.wall:>9.3f} {p.rollout:>9.3f}"
        )
    return "\n".join(lines)


def plot(results: dict[str, list[Point]], n_cases: int) -> Figure:
    """Wall time [s] against error [rad], one line per side, one panel per scenario."""
    fig = Figure(figsize=(6 * len(results), 5), layout="constrained")
    styles = {
        "mujoco-1thread": "o-",
        "mujoco-2threads": "s-",
        "vtm_pin-batched": "^-",
        "vtm_pin-scalar": "v:",
    }
    for k, (name, points) in enumerate(results.items()):
        ax = fig.add_subplot(1, len(results), k + 1)
        for side, style in styles.items():
            pts = sorted((max(p.error, 1e-16), p.wall) for p in points if p.side == side)
            if pts:
                ax.loglog(*zip(*pts, strict=True), style, label=side)
        pts = sorted((max(p.error, 1e-16), p.rollout) for p in points if p.side == "mujoco-1thread")
        if pts:
            ax.loglog(
                *zip(*pts, strict=True), "o--", alpha=0.5, label="mujoco-1thread rollout only"
            )
        for target in TARGETS:
            ax.axvline(target, color="0.85", lw=0.8, zorder=0)
        ax.set_xlabel("max over cases of max |q(T) - q_ref(T)| [rad]")
        ax.set_ylabel(f"wall time for {n_cases} cases [s] (median)")
        ax.set_title(name)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize="small")
    return fig


def main(argv: list[str] | None = None) -> None:
    """Run both sides on both examples, print and save the tables and the plot."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "out")
    parser.add_argument("--scenarios", nargs="*", default=list(SCENARIOS))
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    meta = {
        "mujoco": mujoco.__version__,
        "vtm_pin_batch_engine": BATCH_ENGINE,
        "mujoco_rollout_threads": [1, 2],
        "cases": args.cases,
        "repeats": args.repeats,
        "seed": SEED,
        "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS"),
        "cpus": os.cpu_count(),
    }
    print(
        f"MuJoCo {mujoco.__version__}; vtm_pin engine: {BATCH_ENGINE}; {args.cases} cases, "
        f"median of {args.repeats}; OMP_NUM_THREADS={meta['OMP_NUM_THREADS']}"
    )
    report: dict[str, object] = {"meta": meta}
    results: dict[str, list[Point]] = {}
    serial = mujoco.rollout.Rollout(nthread=0)  # rolls out in the calling thread
    with mujoco.rollout.Rollout(nthread=2) as pool:
        for name in args.scenarios:
            scenario = vp.load_scenario(ROOT / "scenarios" / f"{name}.yaml")
            problems = make_cases(scenario.problem, args.cases)
            print(f"{name}: reference ...", file=sys.stderr)
            q_ref = reference(problems)
            jobs = mujoco_jobs(scenario, problems, q_ref, (serial, pool))
            jobs += vtm_pin_jobs(problems, q_ref)
            print(f"{name}: timing {len(jobs)} jobs x {args.repeats} ...", file=sys.stderr)
            points = time_jobs(jobs, args.repeats)
            rows = table(points)
            results[name] = points
            print(
                f"\n{name}: {args.cases} cases, T = {scenario.duration} s, locks at "
                f"{[e.t for e in scenario.events]} s; time [s] for all cases at the cheapest "
                "setting reaching each target; MuJoCo: total (rollout only)"
            )
            print(format_table(rows))
            print("\nevery setting measured:")
            print(format_points(points))
            report[name] = {"points": [asdict(p) for p in points], "table": rows}
    elapsed = time.perf_counter() - started
    meta["runtime_s"] = elapsed
    (args.out / "mujoco_rollout.json").write_text(json.dumps(report, indent=2))
    plot(results, args.cases).savefig(args.out / "mujoco_rollout.png", dpi=120)
    print(f"\nwrote {args.out}/mujoco_rollout.json and mujoco_rollout.png ({elapsed:.0f} s)")


if __name__ == "__main__":
    main()
