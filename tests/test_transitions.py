import numpy as np
import pinocchio as pin
import pytest
from conftest import robot

from vtm_pin import TRANSITIONS, TransitionError, compute_M
from vtm_pin.numerics.constraints import lock_jacobian, orthogonal_complement
from vtm_pin.numerics.transitions import kkt, solve_saddle_point
from vtm_pin.numerics.transitions.projected import compute_null_space_projector

CONSISTENT = ["kkt", "projected", "minimal"]
ROBOTS = ["planar_3r", "ur5", "panda"]

# The three formulations solve differently sized systems of condition <= ~1e6 here; they
# must agree to 1e-10 relative (the bound), which leaves ~1e5 x machine epsilon.
AGREEMENT_RTOL = 1e-10
# Momentum and energy identities hold exactly in exact arithmetic; 1e-10 relative allows the
# round-off of one dense solve.
INVARIANT_RTOL = 1e-10


def random_case(r, rng):
    """A random state with random persistent (J1) and new (J2) lock sets, J1 v = 0."""
    n = r.nv
    q = rng.uniform(-2.0, 2.0, n)
    order = rng.permutation(n)
    m1 = int(rng.integers(0, n - 1))
    m2 = int(rng.integers(1, n - m1 + 1))
    old, new = sorted(order[:m1].tolist()), sorted(order[m1 : m1 + m2].tolist())
    v = rng.uniform(-3.0, 3.0, n)
    v[old] = 0.0
    data = r.model.createData()
    return q, v, lock_jacobian(n, old), lock_jacobian(n, new), compute_M(r.model, data, q)


def cases():
    return [(name, seed) for name in ROBOTS for seed in range(8)]


@pytest.mark.parametrize("name, seed", cases())
def test_consistent_formulations_agree(name, seed):
    r = robot(name)
    _, v, J1, J2, M = random_case(r, np.random.default_rng(seed))
    results = {rule: TRANSITIONS[rule](M, J1, J2, v) for rule in CONSISTENT}
    ref = results["kkt"]
    scale_v = np.max(np.abs(ref.v_plus)) + np.max(np.abs(v))
    scale_L = np.max(np.abs(ref.Lambda))
    for rule in ("projected", "minimal"):
        res = results[rule]
        assert np.max(np.abs(res.v_plus - ref.v_plus)) <= AGREEMENT_RTOL * scale_v, rule
        assert np.max(np.abs(res.Lambda - ref.Lambda)) <= AGREEMENT_RTOL * scale_L, rule
        assert res.energy_loss == pytest.approx(ref.energy_loss, rel=AGREEMENT_RTOL, abs=1e-12)


@pytest.mark.parametrize("name, seed", cases())
def test_kkt_matches_pinocchio_impulse_dynamics(name, seed):
    r = robot(name)
    q, v, J1, J2, M = random_case(r, np.random.default_rng(seed))
    J = np.vstack([J1, J2])
    data = r.model.createData()
    v_pin = pin.impulseDynamics(r.model, data, q, v, J, 0.0, 0.0)
    res = kkt.compute_transition(M, J1, J2, v)
    scale = np.max(np.abs(v))
    assert np.max(np.abs(res.v_plus - v_pin)) <= AGREEMENT_RTOL * scale
    # Pinocchio's impulse_c is the impulse acting on the system: M dv = J^T impulse_c, the
    # opposite sign of the paper's Lambda (M dv + J^T Lambda = 0).
    np.testing.assert_allclose(
        data.impulse_c, -res.Lambda, rtol=1e-8, atol=AGREEMENT_RTOL * np.max(np.abs(res.Lambda))
    )


@pytest.mark.parametrize("rule", CONSISTENT)
@pytest.mark.parametrize("name, seed", cases())
def test_consistent_jump_invariants(rule, name, seed):
    r = robot(name)
    _, v, J1, J2, M = random_case(r, np.random.default_rng(seed))
    res = TRANSITIONS[rule](M, J1, J2, v)
    J = np.vstack([J1, J2])
    # Constraints: the solver's residual is round-off, and the locked rates are exactly zero.
    assert res.residual <= 1e-12 * np.max(np.abs(v))
    assert np.all(J @ res.v_plus == 0.0)
    # Momentum of the joints that stay free is conserved.
    p_scale = np.max(np.abs(M @ v))
    dp = np.max(np.abs(res.p_free_plus - res.p_free_minus), initial=0.0)
    assert dp <= INVARIANT_RTOL * p_scale
    # Energy lost = 1/2 dv^T M dv (the jump is an M-orthogonal projection).
    dv = res.v_plus - v
    assert res.energy_loss == pytest.approx(0.5 * dv @ M @ dv, rel=INVARIANT_RTOL, abs=1e-12)
    assert res.energy_loss >= 0.0
    # Momentum balance with the impulses: M dv + J^T Lambda = 0.
    assert np.max(np.abs(M @ dv + J.T @ res.Lambda)) <= INVARIANT_RTOL * p_scale


def test_naive_breaks_momentum_on_paper_event():
    """At the paper's first lock (t = 0.8 s, joint 2) the naive rule changes p1 and p3."""
    r = robot("planar_3r")
    # State just before t = 0.8 s from the paper run (RK4 dt = 1e-4), to 1e-10 rad, rad/s.
    q = np.array([-0.3297463574, 0.2224520163, 0.6432226839])
    v = np.array([-1.9122426919, -0.3080797949, 1.6337513514])
    M = compute_M(r.model, r.model.createData(), q)
    J1, J2 = lock_jacobian(3, []), lock_jacobian(3, [1])
    naive = TRANSITIONS["naive"](M, J1, J2, v)
    consistent = TRANSITIONS["kkt"](M, J1, J2, v)
    jump = naive.p_free_plus - naive.p_free_minus
    assert np.all(np.abs(jump) > 10.0)  # [N m s]: tens of N m s on the free joints
    np.testing.assert_allclose(consistent.p_free_plus, consistent.p_free_minus, rtol=1e-12)
    assert naive.energy_loss > 10 * consistent.energy_loss


def test_all_joints_locked_freezes_velocity():
    r = robot("ur5")
    q, v = np.zeros(6), np.linspace(-1, 1, 6)
    M = compute_M(r.model, r.model.createData(), q)
    for rule in CONSISTENT:
        res = TRANSITIONS[rule](M, np.zeros((0, 6)), np.eye(6), v)
        np.testing.assert_array_equal(res.v_plus, 0.0)
        assert res.energy_loss == pytest.approx(0.5 * v @ M @ v, rel=1e-12)


def test_lock_of_joint_at_rest_changes_nothing():
    """J2 v- = 0 gives a zero right-hand side: no jump and no energy change."""
    r = robot("planar_3r")
    q, v = np.array([0.3, 0.2, 0.1]), np.array([1.0, 0.0, -1.0])
    M = compute_M(r.model, r.model.createData(), q)
    for rule in [*CONSISTENT, "naive"]:
        res = TRANSITIONS[rule](M, np.zeros((0, 3)), lock_jacobian(3, [1]), v)
        np.testing.assert_allclose(res.v_plus, v, rtol=0, atol=1e-15)
        assert abs(res.energy_loss) <= 1e-12


def test_redundant_locks_raise_named_error():
    M = np.eye(3)
    J1 = lock_jacobian(3, [1])
    message = "KKT transition: singular system, the constraints are redundant"
    with pytest.raises(TransitionError, match=message):
        kkt.compute_transition(M, J1, lock_jacobian(3, [1]), np.array([1.0, 0.0, 1.0]))
    with pytest.raises(TransitionError, match="redundant"):
        orthogonal_complement(np.vstack([J1, J1]))


def test_saddle_point_solve_meets_both_block_rows():
    """[M G^T; G 0] [x; Lambda] = [f; c] at a robot's mass matrix, with and without f."""
    rng = np.random.default_rng(5)
    r = robot("ur5")
    M = compute_M(r.model, r.model.createData(), rng.uniform(-2.0, 2.0, r.nv))
    G, c, f = rng.normal(size=(2, r.nv)), rng.normal(size=2), rng.normal(size=r.nv)
    for top in (f, None):
        x, Lambda = solve_saddle_point(M, G, c, "test", f=top)
        expected = np.zeros(r.nv) if top is None else top
        # one dense solve of a system of condition ~1e4: round-off well below 1e-10
        np.testing.assert_allclose(M @ x + G.T @ Lambda, expected, rtol=0, atol=1e-10)
        np.testing.assert_allclose(G @ x, c, rtol=0, atol=1e-10)


def test_null_space_projector_is_the_m_orthogonal_projection_onto_ker_j():
    """N^2 = N, J N = 0, and M N is symmetric (the projection is M-orthogonal)."""
    rng = np.random.default_rng(6)
    r = robot("panda")
    M = compute_M(r.model, r.model.createData(), rng.uniform(-1.0, 1.0, r.nv))
    J = rng.normal(size=(3, r.nv))
    N = compute_null_space_projector(M, J)
    # products of a few well-conditioned solves: round-off ~1e-13
    np.testing.assert_allclose(N @ N, N, rtol=0, atol=1e-10)
    np.testing.assert_allclose(J @ N, 0.0, rtol=0, atol=1e-10)
    np.testing.assert_allclose(M @ N, (M @ N).T, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(
        compute_null_space_projector(M, np.zeros((0, r.nv))), np.eye(r.nv)
    )
