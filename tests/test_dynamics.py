import numpy as np
import planar_reference as ref
import pytest
from conftest import robot
from hypothesis import given, settings
from hypothesis import strategies as st

from vtm_pin import Topology, compute_bias, compute_energy, compute_forward_dynamics, compute_M
from vtm_pin.numerics.dynamics import solve_small

# Two Pinocchio algorithms (ABA on a reduced model vs CRBA + RNEA + Cholesky) agree to
# round-off amplified by cond(M) <= ~1e4 for these arms.
ALGORITHM_RTOL = 1e-9


@pytest.mark.parametrize("name", ["planar_3r", "ur5", "panda"])
def test_locked_forward_dynamics_solves_reduced_equations(name):
    r = robot(name)
    data = r.model.createData()
    rng = np.random.default_rng(2)
    for _ in range(5):
        q = rng.uniform(-1.5, 1.5, r.nv)
        locked = sorted(rng.choice(r.nv, size=rng.integers(1, r.nv), replace=False).tolist())
        free = np.setdiff1d(np.arange(r.nv), locked)
        v = rng.uniform(-2, 2, r.nv)
        v[locked] = 0.0
        tau = rng.uniform(-10, 10, r.nv)
        a = compute_forward_dynamics(r.model, data, q, v, tau, locked)
        assert np.all(a[locked] == 0.0)
        M = compute_M(r.model, data, q)
        b = compute_bias(r.model, data, q, v)
        residual = M[np.ix_(free, free)] @ a[free] + b[free] - tau[free]
        assert np.max(np.abs(residual)) <= ALGORITHM_RTOL * np.max(np.abs(tau[free] - b[free]))


@pytest.mark.parametrize("name", ["planar_3r", "ur5", "panda"])
def test_reduced_model_matches_full_model_with_locks(name):
    r = robot(name)
    data = r.model.createData()
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.uniform(-1.5, 1.5, r.nv)
        v = rng.uniform(-2, 2, r.nv)
        locked = sorted(rng.choice(r.nv, size=rng.integers(0, r.nv), replace=False).tolist())
        v[locked] = 0.0
        topology = Topology(r, locked, q)
        ydot = topology.rhs(0.0, topology.split(q, v))
        a = compute_forward_dynamics(r.model, data, q, v, np.zeros(r.nv), locked)
        k = topology.n_free
        np.testing.assert_array_equal(ydot[:k], v[topology.free])
        np.testing.assert_allclose(ydot[k:], a[topology.free], rtol=ALGORITHM_RTOL, atol=1e-9)


def test_unlocked_forward_dynamics_matches_closed_form():
    r = robot("planar_3r")
    data = r.model.createData()
    q, v = np.array([0.4, -1.0, 2.0]), np.array([1.0, -0.5, 2.0])
    a = compute_forward_dynamics(r.model, data, q, v, np.zeros(3))
    np.testing.assert_allclose(a, np.linalg.solve(ref.mass_matrix(q), -ref.bias(q, v)), rtol=1e-10)


def test_energy_matches_closed_form():
    r = robot("planar_3r")
    q, v = np.array([0.4, -1.0, 2.0]), np.array([1.0, -0.5, 2.0])
    T, V = compute_energy(r.model, r.model.createData(), q, v)
    assert T == pytest.approx(0.5 * v @ ref.mass_matrix(q) @ v, rel=1e-12)
    assert V == pytest.approx(ref.potential_energy(q), rel=1e-12)


def test_all_locked_topology_is_frozen():
    r = robot("planar_3r")
    q = np.array([0.1, 0.2, 0.3])
    topology = Topology(r, [0, 1, 2], q)
    assert topology.n_free == 0
    assert topology.rhs(0.0, topology.split(q, np.zeros(3))).size == 0
    q_back, v_back = topology.merge(np.zeros(0))
    np.testing.assert_array_equal(q_back, q)
    np.testing.assert_array_equal(v_back, 0.0)


def test_energy_momentum_equals_the_mass_matrix_product():
    """p = M(q) v from RNEA (no gravity, zero velocity, a = v) equals CRBA's M times v."""
    from vtm_pin import compute_energy_momentum, load_scenario, run_scenario

    scenario = load_scenario("scenarios/rx160l_estop_cat0.yaml")
    result = run_scenario(scenario)
    energy = compute_energy_momentum(scenario.robot, result)
    model, data = scenario.robot.model, scenario.robot.model.createData()
    for i in range(0, result.t.size, max(1, result.t.size // 20)):
        M = compute_M(model, data, result.q[i])
        p = M @ result.v[i]
        # 1e-12 relative: the same sums in another order, round-off only
        assert np.allclose(energy.p[i], p, rtol=1e-12, atol=1e-12 * np.abs(p).max())
        assert energy.kinetic[i] == pytest.approx(0.5 * result.v[i] @ p, rel=1e-12, abs=1e-12)


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 8), seed=st.integers(0, 2**31 - 1))
def test_solve_small_solves_as_numpy_does(n, seed):
    """LAPACK's gesv called directly: NumPy's solve (the same LU) to round-off."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n)) + n * np.eye(n)
    b = rng.normal(size=n)
    x = solve_small(A, b)
    # Tolerance: two LU solves of a well-conditioned (diagonally loaded) matrix agree to a
    # few ulps of the solution.
    np.testing.assert_allclose(
        x, np.linalg.solve(A, b), rtol=0, atol=1e-12 * max(1.0, np.abs(x).max())
    )
    np.testing.assert_allclose(A @ x, b, rtol=0, atol=1e-10)


def test_solve_small_refuses_a_singular_matrix_as_numpy_does():
    with pytest.raises(np.linalg.LinAlgError):
        solve_small(np.array([[1.0, 2.0], [2.0, 4.0]]), np.ones(2))
