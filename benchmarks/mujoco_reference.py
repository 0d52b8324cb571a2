"""MuJoCo runs of a vtm_pin scenario with prescribed locks, for the work-precision benchmark.

Two ways to lock a joint in MuJoCo:

* ``exact``: one model per topology. The locked joints are deleted from an ``MjSpec`` built from
  the same URDF and their bodies rotated to the lock angle; at each event the
  momentum-consistent jump (vtm_pin's ``kkt`` rule with MuJoCo's own mass matrix) maps the
  velocity, and MuJoCo's C RK4 loop (``mujoco.rollout``) integrates between events.
* ``soft``: MuJoCo's own joint equality constraint, switched on with ``eq_active`` at the
  event time (default solver parameters: a stiff spring-damper, not an exact lock).

Only scenarios without brakes or drives (prescribed locks, drives off) can be replayed.
Needs the optional extra: ``pip install -e '.[mujoco]'``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import mujoco
import mujoco.rollout
import numpy as np

import vtm_pin as vp
from vtm_pin.numerics.constraints import lock_jacobian
from vtm_pin.numerics.transitions import kkt


@dataclass
class MujocoRun:
    """Final state and wall time of one MuJoCo replay."""

    q: np.ndarray
    v: np.ndarray
    wall_time: float
    steps: int


def _spec(scenario: vp.Scenario, dt: float) -> mujoco.MjSpec:
    spec = mujoco.MjSpec.from_file(scenario.robot.source)
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_RK4
    spec.option.timestep = dt
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    spec.option.gravity = scenario.robot.model.gravity.linear
    for joint in spec.joints:
        joint.limited = mujoco.mjtLimited.mjLIMITED_FALSE
        joint.armature = float(
            scenario.robot.model.armature[scenario.robot.joint_index(joint.name)]
        )
        joint.damping = np.zeros(3)
        joint.frictionloss = 0.0
    return spec


def copy_link_inertias(spec: mujoco.MjSpec, robot: vp.Robot) -> None:
    """Give each moving body of ``spec`` the inertia of its joint's body in vtm_pin's model.

    vtm_pin attaches a payload by adding its spatial inertia to the body of its frame's parent
    joint (:func:`vtm_pin.physics.payload.attach_payload`), and Pinocchio merges the links
    fixed to a joint's link into it; copying each joint body's mass, centre of mass and
    rotational inertia (Pinocchio's joint frame is the URDF child link's frame, which is the
    MuJoCo body's frame) carries both over. The bodies fixed to them (``ee_link``,
    ``tool0``) are massless in the URDFs replayed here, so MuJoCo's fusion adds nothing.
    """
    for joint in spec.joints:
        inertia = robot.model.inertias[robot.model.getJointId(joint.name)]
        body = joint.parent
        body.explicitinertial = True
        body.mass = float(inertia.mass)
        body.ipos = np.asarray(inertia.lever, dtype=float)
        body.iquat = np.array([1.0, 0.0, 0.0, 0.0])
        rot = np.asarray(inertia.inertia, dtype=float)  # about the centre of mass, body axes
        body.fullinertia = rot[[0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]]


def drop_geometry(spec: mujoco.MjSpec) -> None:
    """Delete every geom and mesh of ``spec`` (contacts are off; inertias must be explicit).

    The UR10's URDF names its meshes by ``package://`` paths, which MuJoCo cannot open.
    """
    for geom in list(spec.geoms):
        spec.delete(geom)
    for mesh in list(spec.meshes):
        spec.delete(mesh)


def _locked_model(scenario: vp.Scenario, dt: float, locked: dict[str, float]) -> mujoco.MjModel:
    spec = _spec(scenario, dt)
    for joint in list(spec.joints):
        if joint.name in locked:
            body = joint.parent
            turn = np.zeros(4)
            mujoco.mju_axisAngle2Quat(turn, np.asarray(joint.axis, dtype=float), locked[joint.name])
            quat = np.zeros(4)
            mujoco.mju_mulQuat(quat, np.asarray(body.quat, dtype=float), turn)
            body.quat = quat
            spec.delete(joint)
    return spec.compile()


def _schedule(scenario: vp.Scenario, dt: float) -> list[tuple[int, tuple[str, ...]]]:
    """(steps to the next event, joints it locks), events on the dt grid."""
    plan, t = [], 0.0
    for event in [*scenario.events, vp.LockEvent(scenario.duration, ())]:
        steps = round((event.t - t) / dt)
        if abs(steps * dt - (event.t - t)) > 1e-9 * dt:
            raise ValueError(f"event at {event.t} s is not on the dt = {dt} s grid")
        plan.append((steps, event.lock))
        t = event.t
    return plan


def _check(scenario: vp.Scenario) -> None:
    if scenario.stop is not None or scenario.brakes:
        raise ValueError("MuJoCo replay supports prescribed locks only (no stop, no brakes)")


def run_exact(scenario: vp.Scenario, dt: float) -> MujocoRun:
    """Exact locks: one MuJoCo model per topology plus the consistent jump."""
    _check(scenario)
    robot = scenario.robot
    joints = list(robot.joints)
    plan = _schedule(scenario, dt)
    full = _spec(scenario, dt).compile()
    full_data = mujoco.MjData(full)
    # Build every topology's model before timing (vtm_pin's timing includes its own builds).
    q, v = scenario.q0.copy(), scenario.v0.copy()
    models = []
    locked: dict[str, float] = {}
    start = time.perf_counter()
    steps_total = 0
    for steps, lock in plan:
        free = [i for i, j in enumerate(joints) if j not in locked]
        key = tuple(sorted(locked))
        model = next((m for k, m in models if k == key), None)
        if model is None:
            t_build = time.perf_counter()
            model = _locked_model(scenario, dt, locked)
            models.append((key, model))
            start += time.perf_counter() - t_build  # model compilation is not timed
        data = mujoco.MjData(model)
        if steps and free:
            data.qpos[:] = q[free]
            data.qvel[:] = v[free]
            size = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
            state0 = np.empty(size)
            mujoco.mj_getState(model, data, state0, mujoco.mjtState.mjSTATE_FULLPHYSICS)
            states, _ = mujoco.rollout.rollout(model, data, state0, nstep=steps)
            last = states[0, -1]
            nq = model.nq
            q[free] = last[1 : 1 + nq]
            v[free] = last[1 + nq : 1 + 2 * nq]
            steps_total += steps
        if lock:
            full_data.qpos[:] = q
            mujoco.mj_forward(full, full_data)
            M = np.zeros((full.nv, full.nv))
            mujoco.mj_fullM(full, full_data, M)
            old = [joints.index(j) for j in locked]
            new = [joints.index(j) for j in lock]
            v = kkt.compute_transition(
                M, lock_jacobian(len(joints), old), lock_jacobian(len(joints), new), v
            ).v_plus
            locked.update({j: float(q[joints.index(j)]) for j in lock})
    return MujocoRun(q, v, time.perf_counter() - start, steps_total)


def run_soft(scenario: vp.Scenario, dt: float) -> MujocoRun:
    """MuJoCo's own soft joint-equality lock, activated with eq_active at each event."""
    _check(scenario)
    joints = list(scenario.robot.joints)
    spec = _spec(scenario, dt)
    for name in joints:
        spec.add_equality(type=mujoco.mjtEq.mjEQ_JOINT, name1=name, active=False)
    model = spec.compile()
    data = mujoco.MjData(model)
    data.qpos[:] = scenario.q0
    data.qvel[:] = scenario.v0
    size = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    state = np.empty(size)
    start = time.perf_counter()
    steps_total = 0
    for steps, lock in _schedule(scenario, dt):
        if steps:
            mujoco.mj_getState(model, data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
            states, _ = mujoco.rollout.rollout(model, data, state, nstep=steps)
            mujoco.mj_setState(model, data, states[0, -1], mujoco.mjtState.mjSTATE_FULLPHYSICS)
            steps_total += steps
        for name in lock:
            i = joints.index(name)
            model.eq_data[i, 0] = data.qpos[i]  # hold the angle it has now
            # rollout() resets eq_active from the model (it is not part of the state vector).
            model.eq_active0[i] = True
            data.eq_active[i] = 1
    return MujocoRun(data.qpos.copy(), data.qvel.copy(), time.perf_counter() - start, steps_total)
