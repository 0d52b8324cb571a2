"""The robot's cache of reduced models and Data, and the O(n) joint-lock path of the loop."""

from __future__ import annotations

import copy
import dataclasses
import pickle

import numpy as np
import pinocchio as pin
import pytest
from conftest import SCENARIOS

from vtm_pin import load_robot, load_scenario
from vtm_pin.core.topology import Topology, reduced_model, weightless_model
from vtm_pin.files.model_cache import ModelCache
from vtm_pin.numerics.constraints import lock_jacobian
from vtm_pin.numerics.dynamics import compute_M
from vtm_pin.numerics.integrators import DOP853, RK4
from vtm_pin.numerics.transitions import TRANSITIONS
from vtm_pin.physics.arm_points import sample_arm_points
from vtm_pin.physics.kinematics import kinematics_key, pinocchio_data
from vtm_pin.physics.payload import Payload, attach_payload
from vtm_pin.scene import annex_b
from vtm_pin.scene.scenario import run_scenario

#: Two exact methods compared; round-off grows with cond(M) (see test_recursive_transition).
RTOL = 1e-12


def same_model(a: pin.Model, b: pin.Model, rng: np.random.Generator) -> None:
    """Bit-for-bit the same dynamics and kinematics at random states."""
    assert a.nq == b.nq and a.nv == b.nv and a.njoints == b.njoints
    assert list(a.names) == list(b.names)
    np.testing.assert_array_equal(a.armature, b.armature)
    np.testing.assert_array_equal(a.gravity.vector, b.gravity.vector)
    for i in range(a.njoints):
        np.testing.assert_array_equal(
            a.inertias[i].toDynamicParameters(), b.inertias[i].toDynamicParameters()
        )
        np.testing.assert_array_equal(
            a.jointPlacements[i].homogeneous, b.jointPlacements[i].homogeneous
        )
    da, db = a.createData(), b.createData()
    for _ in range(3):
        q, v, tau = rng.uniform(-1.0, 1.0, (3, a.nv))
        np.testing.assert_array_equal(pin.aba(a, da, q, v, tau), pin.aba(b, db, q, v, tau))
        np.testing.assert_array_equal(pin.rnea(a, da, q, v, tau), pin.rnea(b, db, q, v, tau))


@pytest.mark.parametrize("name", ["planar_3r", "rx160l", "ur10"])
def test_cached_reduced_model_equals_a_fresh_one(name: str) -> None:
    robot = load_robot(name)
    rng = np.random.default_rng(3)
    n = robot.nv
    for locked in [(0,), (1, 2), tuple(range(1, n))]:
        q = rng.uniform(-1.0, 1.0, n)
        topology = Topology(robot, locked, q)
        ids = [robot.model.getJointId(robot.joints[i]) for i in locked]
        fresh = pin.buildReducedModel(robot.model, ids, q)
        same_model(topology.model, fresh, rng)
        # The free joints' angles do not enter: another q with the same locked angles hits.
        other = rng.uniform(-1.0, 1.0, n)
        other[list(locked)] = q[list(locked)]
        assert Topology(robot, locked, other).model is topology.model
        # The locked angles do: they are part of the key.
        moved = q.copy()
        moved[locked[0]] += 1e-15 * max(1.0, abs(q[locked[0]])) + 1e-300
        assert Topology(robot, locked, moved).model is not topology.model


def test_weightless_models_have_no_gravity_and_the_same_inertias() -> None:
    robot = load_robot("rx160l")
    rng = np.random.default_rng(4)
    q = rng.uniform(-1.0, 1.0, robot.nv)
    model, _ = weightless_model(robot)
    assert np.all(model.gravity.vector == 0.0)
    assert model is not robot.model and np.any(robot.model.gravity.vector != 0.0)
    free, _ = reduced_model(robot, (1, 3), q[[1, 3]], weightless=True)
    heavy, _ = reduced_model(robot, (1, 3), q[[1, 3]])
    assert np.all(free.gravity.vector == 0.0) and np.any(heavy.gravity.vector != 0.0)
    qf = q[[0, 2, 4, 5]]
    np.testing.assert_array_equal(
        pin.crba(free, free.createData(), qf), pin.crba(heavy, heavy.createData(), qf)
    )


def test_cache_is_bounded_least_recently_used() -> None:
    cache = ModelCache(size=2)
    built = []

    def build(key: str):
        return lambda: built.append(key) or key

    assert cache.get("a", build("a")) == "a"
    assert cache.get("b", build("b")) == "b"
    assert cache.get("a", build("a")) == "a"  # a hit; "b" is now the least recently used
    assert cache.get("c", build("c")) == "c"
    assert len(cache) == 2 and built == ["a", "b", "c"]
    assert cache.get("a", build("a")) == "a" and built == ["a", "b", "c"]
    assert cache.get("b", build("b")) == "b" and built == ["a", "b", "c", "b"]
    assert (cache.hits, cache.misses) == (2, 4)


def test_a_copied_or_pickled_robot_starts_with_an_empty_cache() -> None:
    robot = load_robot("planar_3r")
    Topology(robot, (1,), np.array([0.1, 0.2, 0.3])).rhs(0.0, np.zeros(4))
    assert len(robot.cache) > 0
    assert len(pickle.loads(pickle.dumps(robot)).cache) == 0
    assert len(copy.deepcopy(robot).cache) == 0
    changed = dataclasses.replace(robot, model=pin.Model(robot.model))
    assert changed.cache is not robot.cache and len(changed.cache) == 0
    assert changed == robot  # the cache does not take part in comparisons


def test_a_payload_copy_shares_the_kinematic_entries_only() -> None:
    """A robot with a payload differs in one body's inertia: it shares its robot's kinematic
    entries (the kinematics key, the chain, the arm's points, the Annex-B chain), both ways,
    and builds its own dynamic ones (Data, reduced models)."""
    robot = load_robot("ur10")
    loaded = attach_payload(robot, Payload(mass=5.0, com=(0.0, 0.0, 0.1)))
    assert loaded.cache is not robot.cache
    key = kinematics_key(robot)
    assert kinematics_key(loaded) is key  # computed once, found by the copy
    points = sample_arm_points(loaded)
    assert sample_arm_points(robot) is points  # the other way round
    frame = robot.tool_frame
    reach = annex_b.horizontal_reach(loaded, frame, np.zeros(6))
    assert reach == annex_b.horizontal_reach(robot, frame, np.zeros(6))
    assert loaded.cache.hits > 0 and ("annex_b_chain", frame) in robot.cache._kinematic
    assert pinocchio_data(loaded) is not pinocchio_data(robot)
    a, b = weightless_model(loaded)[0], weightless_model(robot)[0]
    assert a.inertias[6] != b.inertias[6]  # its own dynamic entries: the payload's body
    loaded.cache.clear()  # forgets for the copy alone
    assert kinematics_key(robot) is key and kinematics_key(loaded) is not key


@pytest.mark.parametrize("name", ["pendulum3r", "rx160l_paper_locks", "panda_estop_cat0"])
def test_results_are_the_same_with_a_cold_and_a_warm_cache(name: str) -> None:
    scenario = load_scenario(SCENARIOS / f"{name}.yaml")
    scenario = dataclasses.replace(scenario, integrator=DOP853(1e-8, 1e-10))
    scenario.robot.cache.clear()
    cold = run_scenario(scenario, "kkt")
    assert scenario.robot.cache.misses > 0
    hits = scenario.robot.cache.hits
    warm = run_scenario(scenario, "kkt")
    assert scenario.robot.cache.hits > hits
    for field in ("t", "q", "v", "holding", "brake_work"):
        np.testing.assert_array_equal(getattr(cold, field), getattr(warm, field), field)
    for a, b in zip(cold.events, warm.events, strict=True):
        np.testing.assert_array_equal(a.transition.v_plus, b.transition.v_plus)
        np.testing.assert_array_equal(a.transition.Lambda, b.transition.Lambda)


@pytest.mark.parametrize(
    "name", ["pendulum3r", "rx160l_paper_locks", "panda_estop_cat0", "rx160l_estop_cat0"]
)
def test_loop_joint_locks_agree_with_the_dense_kkt_rule(name: str) -> None:
    """The kkt rule's O(n) path for pure joint locks: every field of every event record."""
    scenario = load_scenario(SCENARIOS / f"{name}.yaml")
    result = run_scenario(dataclasses.replace(scenario, integrator=RK4(1e-3)), "kkt")
    robot = scenario.robot
    assert result.events
    for event in result.events:
        n = robot.nv
        before = robot.joint_indices(event.locked_before)
        J1, J2 = lock_jacobian(n, before), lock_jacobian(n, robot.joint_indices(event.lock))
        M = compute_M(robot.model, robot.model.createData(), event.q)
        dense = TRANSITIONS["kkt"](M, J1, J2, event.v_minus)
        fast = event.transition
        tol = RTOL * np.linalg.cond(M)
        scale = max(1.0, float(np.max(np.abs(dense.Lambda), initial=1.0)))
        v_scale = max(1.0, float(np.max(np.abs(event.v_minus))))
        np.testing.assert_allclose(fast.v_plus, dense.v_plus, rtol=0, atol=tol * v_scale)
        np.testing.assert_array_equal(fast.v_plus[np.any(np.vstack([J1, J2]) != 0, axis=0)], 0.0)
        np.testing.assert_allclose(fast.Lambda, dense.Lambda, rtol=0, atol=tol * scale)
        np.testing.assert_allclose(fast.p_free_minus, dense.p_free_minus, rtol=0, atol=tol * scale)
        np.testing.assert_allclose(fast.p_free_plus, dense.p_free_plus, rtol=0, atol=tol * scale)
        assert fast.energy_loss == pytest.approx(dense.energy_loss, rel=tol, abs=tol * scale)
        assert fast.m1 == dense.m1 and fast.residual <= dense.residual
