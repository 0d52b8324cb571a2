import numpy as np
import pinocchio as pin
import pytest
from conftest import SCENARIOS, robot

from vtm_pin import (
    TRANSITIONS,
    ConstraintError,
    LockEvent,
    Problem,
    compute_M,
    load_scenario,
    run_scenario,
    simulate,
)
from vtm_pin.core.holonomic import (
    FrameConstraint,
    compute_kinematics,
    project_initial_state,
    stack,
)
from vtm_pin.core.phase import Phase
from vtm_pin.core.topology import Topology
from vtm_pin.numerics.constraints import check_independent, lock_jacobian
from vtm_pin.numerics.integrators import DOP853
from vtm_pin.numerics.transitions.projected import compute_null_space_projector

LOOP = FrameConstraint("loop", "tip_l", "tip_r", "point", ("x", "z"))
Q_FIVEBAR = np.array([-0.4, 0.57978007700581935, 0.2, 0.16334925102132061])  # [rad], closed
RULES = ("kkt", "projected", "minimal")


def consistent_state(r, constraints, q, v):
    """(q, v) moved onto the constraints (the projection warns: expected here)."""
    with pytest.warns(UserWarning, match="moved onto the constraints"):
        return project_initial_state(r, q, v, constraints)


def fivebar_states(seed, count=5):
    r = robot("planar_fivebar")
    rng = np.random.default_rng(seed)
    for _ in range(count):
        q = Q_FIVEBAR + rng.uniform(-0.2, 0.2, 4)
        v = rng.uniform(-2, 2, 4)
        yield r, *consistent_state(r, [LOOP], q, v)


def rigid_contact(model, constraint, kind):
    fa = model.frames[model.getFrameId(constraint.frame_a)]
    if constraint.frame_b is None:
        return pin.RigidConstraintModel(
            kind, model, fa.parentJoint, fa.placement, 0, constraint.target, pin.LOCAL_WORLD_ALIGNED
        )
    fb = model.frames[model.getFrameId(constraint.frame_b)]
    return pin.RigidConstraintModel(
        kind,
        model,
        fa.parentJoint,
        fa.placement,
        fb.parentJoint,
        fb.placement,
        pin.LOCAL_WORLD_ALIGNED,
    )


def pinocchio_acceleration(model, q, v, contact):
    data = model.createData()
    models = pin.StdVec_RigidConstraintModel()
    models.append(contact)
    datas = pin.StdVec_RigidConstraintData()
    datas.append(contact.createData())
    pin.initConstraintDynamics(model, data, models, datas)
    prox = pin.ProximalSettings(1e-14, 1e-12, 100)
    return pin.constraintDynamics(model, data, q, v, np.zeros(model.nv), models, datas, prox)


def our_acceleration(r, constraints, q, v):
    topology = Topology(r, [], q)
    phase = Phase(r, topology, constraints=tuple(constraints))
    return phase.constrained_acceleration(topology.split(q, v), np.zeros(r.nv))[0]


@pytest.mark.parametrize("seed", range(3))
def test_fivebar_dynamics_match_pinocchio_constraint_dynamics(seed):
    """Index-1 equations vs pin.constraintDynamics (its 3D contact; the y row is redundant)."""
    for r, q, v in fivebar_states(seed):
        ours = our_acceleration(r, [LOOP], q, v)
        theirs = pinocchio_acceleration(
            r.model, q, v, rigid_contact(r.model, LOOP, pin.ContactType.CONTACT_3D)
        )
        # Both are exact solves of the same system; 1e-9 of |a| ~ 10-100 rad/s^2 is round-off.
        np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-9 * max(1.0, np.max(np.abs(ours))))


@pytest.mark.parametrize(
    "mode, kind", [("point", pin.ContactType.CONTACT_3D), ("pose", pin.ContactType.CONTACT_6D)]
)
def test_docked_arm_dynamics_match_pinocchio(mode, kind):
    r = robot("rx160l")
    rng = np.random.default_rng(7)
    for _ in range(3):
        q = rng.uniform(-1, 1, 6)
        dock = FrameConstraint("dock", "tool0", None, mode).latch(r.model, r.model.createData(), q)
        v = rng.uniform(-1, 1, 6)
        v = _project(r, dock, q, v)
        ours = our_acceleration(r, [dock], q, v)
        theirs = pinocchio_acceleration(r.model, q, v, rigid_contact(r.model, dock, kind))
        np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-8 * max(1.0, np.max(np.abs(ours))))


def _project(r, constraint, q, v):
    """The velocity v moved M-orthogonally onto J v = 0."""
    data = r.model.createData()
    compute_kinematics(r.model, data, q, v)
    _, J, _ = stack((constraint,), r.model, data)
    return compute_null_space_projector(compute_M(r.model, data, q), J) @ v


def transition_cases():
    """(M, J1, J2, v) with non-trivial J1 on the five-bar and on the docked arm."""
    for r, q, v in fivebar_states(11):
        data = r.model.createData()
        compute_kinematics(r.model, data, q, v)
        _, J_loop, _ = stack((LOOP,), r.model, data)
        yield "fivebar", compute_M(r.model, data, q), J_loop, lock_jacobian(4, [2]), v
    arm = robot("rx160l")
    rng = np.random.default_rng(3)
    for mode, locks in [("point", [1]), ("point", [0, 4])]:
        q = rng.uniform(-1, 1, 6)
        dock = FrameConstraint("dock", "tool0", None, mode).latch(
            arm.model, arm.model.createData(), q
        )
        v = rng.uniform(-1, 1, 6)
        v = _project(arm, dock, q, v)
        data = arm.model.createData()
        compute_kinematics(arm.model, data, q, v)
        _, J_dock, _ = stack((dock,), arm.model, data)
        yield "rx160l", compute_M(arm.model, data, q), J_dock, lock_jacobian(6, locks), v
        # and the other way round: locks persistent, docking activated
        v2 = rng.uniform(-1, 1, 6)
        v2[locks] = 0.0
        yield "rx160l-dock", compute_M(arm.model, data, q), lock_jacobian(6, locks), J_dock, v2


@pytest.mark.parametrize("case", list(transition_cases()), ids=lambda c: c[0])
def test_formulations_agree_with_nontrivial_J1(case):
    _, M, J1, J2, v = case
    results = [TRANSITIONS[rule](M, J1, J2, v) for rule in RULES]
    scale = np.max(np.abs(v))
    for res in results[1:]:
        assert np.max(np.abs(res.v_plus - results[0].v_plus)) <= 1e-9 * scale
        np.testing.assert_allclose(
            res.Lambda, results[0].Lambda, rtol=1e-9, atol=1e-9 * np.max(np.abs(results[0].Lambda))
        )
    J = np.vstack([J1, J2])
    for res in results:
        dv = res.v_plus - v
        # Momentum is conserved in the directions the constraints still allow (F^T M v).
        np.testing.assert_allclose(
            res.p_free_plus, res.p_free_minus, rtol=0, atol=1e-10 * np.max(np.abs(M @ v))
        )
        assert res.energy_loss == pytest.approx(0.5 * dv @ M @ dv, rel=1e-10, abs=1e-14)
        assert np.max(np.abs(J @ res.v_plus)) <= 1e-12 * scale


@pytest.mark.parametrize("name", ["fivebar_lock", "rx160l_dock_point", "rx160l_dock_pose"])
def test_every_activation_conserves_allowed_momentum(name):
    scenario = load_scenario(SCENARIOS / f"{name}.yaml")
    for rule in RULES:
        result = run_scenario(scenario, rule)
        for event in result.events:
            tr = event.transition
            M = compute_M(scenario.robot.model, scenario.robot.model.createData(), event.q)
            dv = tr.v_plus - event.v_minus
            np.testing.assert_allclose(tr.p_free_plus, tr.p_free_minus, rtol=0, atol=1e-9)
            assert tr.energy_loss == pytest.approx(0.5 * dv @ M @ dv, rel=1e-10, abs=1e-12)


def test_three_formulations_give_the_same_closed_loop_run():
    scenario = load_scenario(SCENARIOS / "fivebar_lock.yaml")
    runs = [run_scenario(scenario, rule) for rule in RULES]
    for other in runs[1:]:
        np.testing.assert_allclose(other.q[-1], runs[0].q[-1], rtol=0, atol=1e-9)


def test_drift_with_and_without_stabilisation():
    """10 s closed-loop run of the five-bar: Baumgarte keeps |h| at the integrator's level."""
    r = robot("planar_fivebar")
    drift = {}
    for gains in [(0.0, 0.0), (10.0, 10.0)]:
        problem = Problem(r, Q_FIVEBAR, np.zeros(4), 10.0, constraints=(LOOP,), baumgarte=gains)
        result = simulate(problem, DOP853(1e-8, 1e-10))
        drift[gains] = np.nanmax(result.drift, axis=0)
    # Measured (DOP853 rtol 1e-8): no stabilisation max |h| 5.4e-9 m, growing to the end;
    # Baumgarte (10, 10) 1.7e-10 m, 3e-13 m at the end.
    assert drift[(10.0, 10.0)][0] < drift[(0.0, 0.0)][0] / 10
    assert drift[(10.0, 10.0)][0] < 1e-8


def test_redundant_loop_rows_are_named():
    r = robot("planar_fivebar")
    full = FrameConstraint("loop", "tip_l", "tip_r", "point")  # x, y, z: y is identically 0
    with pytest.raises(
        ConstraintError, match=r"'loop.y' depends on the others \(rank 2 of 3 rows\)"
    ):
        simulate(Problem(r, Q_FIVEBAR, np.zeros(4), 1.0, (LockEvent(0.5, (), (full,)),)), DOP853())
    with pytest.raises(ConstraintError, match=r"'lock joint2' depends on the others"):
        check_independent(
            np.vstack([lock_jacobian(3, [1]), lock_jacobian(3, [1])]),
            ["lock joint2", "lock joint2"],
        )


def test_initial_state_is_projected_with_a_warning():
    r = robot("planar_fivebar")
    q = Q_FIVEBAR + np.array([0.0, 0.01, 0.0, 0.0])
    with pytest.warns(UserWarning, match=r"Initial state moved onto the constraints by up to"):
        qp, vp_ = project_initial_state(r, q, np.array([1.0, 0.0, 0.0, 0.0]), [LOOP])
    data = r.model.createData()
    compute_kinematics(r.model, data, qp, vp_)
    h, J, _ = stack((LOOP,), r.model, data)
    assert np.max(np.abs(h)) < 1e-13 and np.max(np.abs(J @ vp_)) < 1e-12


def penalty_run(stiffness):
    """The five-bar lock of joint_r1 replaced by a stiff critically damped spring [N m/rad]."""
    r = robot("planar_fivebar")
    q, v = Q_FIVEBAR.copy(), np.zeros(4)
    before = simulate(Problem(r, q, v, 0.6, constraints=(LOOP,)), DOP853(1e-12, 1e-14))
    q, v = before.q[-1], before.v[-1]
    topology = Topology(r, [], q)
    phase = Phase(r, topology, constraints=(LOOP,), baumgarte=(10.0, 10.0))
    q_lock = q[2]
    damping = 2.0 * np.sqrt(stiffness * 1.0)  # critical for ~1 kg m^2 of effective inertia

    def rhs(t, y):
        tau = np.zeros(4)
        tau[2] = -stiffness * (y[2] - q_lock) - damping * y[6]
        a = phase.constrained_acceleration(y, tau)[0]
        return np.concatenate([y[4:], a])

    from scipy.integrate import solve_ivp

    sol = solve_ivp(rhs, (0.6, 0.7), np.concatenate([q, v]), "DOP853", rtol=1e-10, atol=1e-12)
    return sol.y[:, -1]


def test_stiff_penalty_model_converges_to_the_consistent_jump():
    """The lock as a stiff spring-damper: the free rates 0.1 s later approach the exact run."""
    r = robot("planar_fivebar")
    events = (LockEvent(0.6, ("joint_r1",)),)
    exact = simulate(
        Problem(r, Q_FIVEBAR, np.zeros(4), 0.7, events, constraints=(LOOP,)), DOP853(1e-12, 1e-14)
    )
    errors = []
    for k in (1e4, 1e6, 1e8):
        state = penalty_run(k)
        errors.append(np.max(np.abs(state[[4, 5, 7]] - exact.v[-1][[0, 1, 3]])))
    # Measured: 2.6e-2, 3.1e-3, 3.4e-5, 1.3e-6 rad/s for k = 1e2, 1e4, 1e6, 1e8 N m/rad.
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 1e-2
