"""The O(n) joint-lock transition agrees with the kkt rule (issue 14, item 2)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vtm_pin.numerics.constraints import lock_jacobian
from vtm_pin.numerics.dynamics import compute_M
from vtm_pin.numerics.transitions import TRANSITIONS
from vtm_pin.numerics.transitions.recursive import (
    at_rest,
    compute_joint_lock_transition,
    compute_joint_lock_transition_dense,
    joint_lock_at_rest,
    weightless,
)
from vtm_pin.physics.chain import build_chain
from vtm_pin.physics.robot import load_robot

#: Two exact methods compared; their round-off grows with cond(M) (up to ~1e4 on these arms
#: with armature), so 1e-12 relative to the largest value compared, times that condition.
RTOL = 1e-12


def compare(robot_model, q, v, locked_before, joints):
    n = robot_model.nv
    M = compute_M(robot_model, robot_model.createData(), q)
    J1, J2 = lock_jacobian(n, locked_before), lock_jacobian(n, joints)
    v = v.copy()
    v[list(locked_before)] = 0.0
    reference = TRANSITIONS["kkt"](M, J1, J2, v)
    fast = compute_joint_lock_transition(weightless(robot_model), q, v, locked_before, joints)
    tol = RTOL * np.linalg.cond(M)
    scale = max(1.0, float(np.max(np.abs(reference.Lambda), initial=1.0)))
    np.testing.assert_allclose(fast.v_plus, reference.v_plus, rtol=0, atol=tol * np.abs(v).max())
    np.testing.assert_allclose(fast.Lambda, reference.Lambda, rtol=0, atol=tol * scale)
    np.testing.assert_allclose(fast.p_free_plus, reference.p_free_plus, rtol=0, atol=tol * scale)
    np.testing.assert_allclose(fast.p_free_plus, fast.p_free_minus, rtol=0, atol=tol * scale)
    assert fast.energy_loss == pytest.approx(reference.energy_loss, rel=tol, abs=tol * scale)
    assert fast.energy_loss >= -tol * scale
    assert fast.m1 == reference.m1


@pytest.mark.parametrize("name", ["ur10", "rx160l", "panda"])
def test_recursive_lock_equals_kkt_on_arms(name: str) -> None:
    robot = load_robot(name)
    rng = np.random.default_rng(7)
    n = robot.nv
    for _ in range(5):
        q = rng.uniform(-1.0, 1.0, n)
        q = np.clip(q, robot.model.lowerPositionLimit, robot.model.upperPositionLimit)
        v = rng.uniform(-2.0, 2.0, n)
        order = rng.permutation(n)
        k = int(rng.integers(0, n - 1))
        compare(robot.model, q, v, sorted(order[:k].tolist()), [int(order[k])])


def _drawn_lock(
    n: int, seed: int, data: st.DataObject, spatial: bool = True, at_rest: bool = False
) -> tuple:
    """An n-link chain, a state, and joints locked before and now (at rest if ``at_rest``)."""
    robot = build_chain(n, spatial=spatial)
    rng = np.random.default_rng(seed)
    q = rng.uniform(-1.5, 1.5, n)
    v = rng.uniform(-2.0, 2.0, n)
    joints = data.draw(st.lists(st.integers(0, n - 1), min_size=1, max_size=n, unique=True))
    split = data.draw(st.integers(0, len(joints) - 1))
    if at_rest:
        v[joints] = 0.0
    return robot, q, v, joints[:split], joints[split:]


@settings(max_examples=40, deadline=None, derandomize=True)
@given(
    n=st.integers(2, 30),
    spatial=st.booleans(),
    seed=st.integers(0, 2**31 - 1),
    data=st.data(),
)
def test_recursive_lock_equals_kkt_on_chains(n, spatial, seed, data) -> None:
    """Any lock set on any chain: the same jump, impulses and energy loss as kkt."""
    robot, q, v, before, now = _drawn_lock(n, seed, data, spatial)
    compare(robot.model, q, v, before, now)


@pytest.mark.parametrize("name", ["rx160l", "panda"])
def test_locking_joints_at_rest_changes_nothing_exactly(name: str) -> None:
    """No jump, no impulse, to the last bit (the brake state machine reads exact zeros)."""
    robot = load_robot(name)
    rng = np.random.default_rng(11)
    n = robot.nv
    q = rng.uniform(-1.0, 1.0, n)
    v = rng.uniform(-2.0, 2.0, n)
    v[[1, 3]] = 0.0
    fast = compute_joint_lock_transition(weightless(robot.model), q, v, [3], [1])
    np.testing.assert_array_equal(fast.v_plus, v)
    np.testing.assert_array_equal(fast.Lambda, 0.0)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(n=st.integers(2, 12), seed=st.integers(0, 2**31 - 1), data=st.data())
def test_the_dense_lock_at_rest_is_the_general_one(n, seed, data) -> None:
    """Locking joints whose rates are exactly 0 (a brake sticking at rest) takes a short path:
    v+ = v- and no impulse to the bit, no energy lost, the free momentum (M v)_f kept, as the
    general steps give them (M times a zero dv) and as kkt does to round-off; with a locking
    rate not 0 it is not taken."""
    robot, q, v, before, now = _drawn_lock(n, seed, data, at_rest=True)
    joints = [*before, *now]
    M = compute_M(robot.model, robot.model.createData(), q)
    fast = compute_joint_lock_transition_dense(M, v, before, now)
    free = [i for i in range(n) if i not in joints]
    np.testing.assert_array_equal(fast.v_plus, v)
    np.testing.assert_array_equal(fast.Lambda, np.zeros(len(joints)))
    np.testing.assert_array_equal(fast.p_free_minus, (M @ v)[free])
    np.testing.assert_array_equal(fast.p_free_plus, fast.p_free_minus)
    assert (fast.energy_loss, fast.m1, fast.residual) == (0.0, len(before), 0.0)
    reference = TRANSITIONS["kkt"](M, lock_jacobian(n, before), lock_jacobian(n, now), v)
    np.testing.assert_allclose(fast.v_plus, reference.v_plus, rtol=0, atol=1e-12)
    v[now[0]] = 1e-3  # one locking joint moves: a jump
    moving = compute_joint_lock_transition_dense(M, v, before, now)
    assert moving.energy_loss > 0.0 and np.any(moving.Lambda != 0.0)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(n=st.integers(2, 12), seed=st.integers(0, 2**31 - 1), data=st.data())
def test_the_lock_at_rest_from_the_momentum_is_the_recursive_one_to_the_bit(n, seed, data) -> None:
    """A lock at rest in the scalar engine's loop takes M v- from one RNEA pass on the
    weightless model and builds no reduced model: every field equals the recursive rule's, to
    the bit (with zero locked rates its solve and products give exact zeros). (The batched
    engine's loop takes M v- another way: tests/test_simulation.py.)"""
    robot, q, v, before, now = _drawn_lock(n, seed, data, at_rest=True)
    model = weightless(robot.model)
    assert at_rest(v, before, now)
    p = pin.rnea(model, model.createData(), q, np.zeros(n), v)
    short = joint_lock_at_rest(p, v, before, now)
    general = compute_joint_lock_transition(model, q, v, before, now)
    for field in ("v_plus", "Lambda", "p_free_minus", "p_free_plus"):
        np.testing.assert_array_equal(getattr(short, field), getattr(general, field))
    assert (short.energy_loss, short.m1, short.residual) == (
        general.energy_loss,
        general.m1,
        general.residual,
    )
    v[now[0]] = 1e-3
    assert not at_rest(v, before, now)
