import numpy as np
import pytest

from vtm_pin import TRANSITIONS, Problem, RobotLoadError, compute_M, simulate
from vtm_pin.numerics.constraints import lock_jacobian
from vtm_pin.numerics.integrators import DOP853
from vtm_pin.physics.chain import LINK_LENGTH, build_chain


@pytest.mark.parametrize("spatial", [False, True])
def test_chain_has_n_links_and_a_tip(spatial):
    robot = build_chain(7, spatial=spatial)
    assert robot.nv == 7 and robot.joints[-1] == "joint7"
    assert robot.model.existFrame("tip")
    M = compute_M(robot.model, robot.model.createData(), np.zeros(7))
    assert np.all(np.linalg.eigvalsh(M) > 0)


def test_hanging_chain_is_at_rest_and_tip_length():
    import pinocchio as pin

    robot = build_chain(5)
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, np.zeros(5))
    tip = data.oMf[robot.model.getFrameId("tip")].translation
    np.testing.assert_allclose(tip, [0.0, 0.0, -5 * LINK_LENGTH], atol=1e-15)
    result = simulate(Problem(robot, np.zeros(5), np.zeros(5), 0.5), DOP853(1e-10, 1e-12))
    assert np.max(np.abs(result.q[-1])) == 0.0  # hanging straight down is an equilibrium


@pytest.mark.parametrize("n", [50, 200])
def test_formulations_agree_on_long_chains(n):
    robot = build_chain(n, spatial=True)
    rng = np.random.default_rng(n)
    q = rng.uniform(-0.5, 0.5, n)
    old = list(range(0, n - 1, 2))
    v = rng.uniform(-1, 1, n)
    v[old] = 0.0
    M = compute_M(robot.model, robot.model.createData(), q)
    J1, J2 = lock_jacobian(n, old), lock_jacobian(n, [n - 1])
    results = [TRANSITIONS[k](M, J1, J2, v) for k in ("kkt", "projected", "minimal")]
    for res in results[1:]:
        # cond(M) grows with n (~1e7 at n = 200): agreement to 1e-8 of |v| is round-off.
        np.testing.assert_allclose(res.v_plus, results[0].v_plus, rtol=0, atol=1e-8)


def test_chain_needs_a_link():
    with pytest.raises(RobotLoadError, match="a chain needs at least one link"):
        build_chain(0)
