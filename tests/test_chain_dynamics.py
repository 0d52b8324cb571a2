"""The compiled forward dynamics with locks (vtm_pin.physics.chain_dynamics) against Pinocchio.

The batched engine evaluates every state with locks, or with a lane's own payload, through this
one kernel when Numba is installed (the ``fast`` extra, which the ``test`` extra installs). Its
accelerations and holding torques must be those of Pinocchio's CRBA and RNEA (with the model's
armature) on each state's own model: M_ff a_f = tau_f - b_f, lambda_L = M_Lf a_f + b_L - tau_L.

Tolerance DYNAMICS_TOLERANCE relative to 1 + the largest value compared: both sides are exact
up to round-off (measured ~1e-13 on these models, whose M_ff have condition numbers up to ~1e4
with armature); 1e-10 leaves room for that condition.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from test_kinematics import every_joint_type

import vtm_pin as vp
from vtm_pin.numerics.dynamics import compute_M
from vtm_pin.physics import chain_dynamics
from vtm_pin.physics.kinematics import joint_chain
from vtm_pin.physics.payload import Payload, attach_payload

pytestmark = pytest.mark.skipif(not chain_dynamics.AVAILABLE, reason="Numba is not installed")

DYNAMICS_TOLERANCE = 1e-10


def _models(name: str, rng: np.random.Generator) -> list[pin.Model]:
    """The model and variants that differ in their bodies' inertias only."""
    if name == "tree":
        model = every_joint_type()[0]
        model.armature = rng.uniform(0.0, 0.5, model.nv)
        others = []
        for _ in range(3):
            other = pin.Model(model)
            j = int(rng.integers(1, model.njoints))
            other.inertias[j] = other.inertias[j] + pin.Inertia.Random()
            others.append(other)
        return [model, *others]
    robot = vp.load_robot(name)
    payloads = [Payload(float(m), tuple(rng.uniform(-0.1, 0.1, 3))) for m in (0.5, 4.0, 10.0)]
    return [robot.model, *(attach_payload(robot, p).model for p in payloads)]


def _reference(
    model: pin.Model, q: np.ndarray, v: np.ndarray, tau: np.ndarray, locked: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    data = model.createData()
    M = compute_M(model, data, q)
    b = pin.nonLinearEffects(model, data, q, v)
    free = np.flatnonzero(~locked)
    a = np.zeros(model.nv)
    a[free] = np.linalg.solve(M[np.ix_(free, free)], tau[free] - b[free])
    return a, np.where(locked, M @ a + b - tau, 0.0)


@pytest.mark.parametrize("name", ["ur10", "rx160l", "panda", "tree"])
def test_the_kernel_is_pinocchios_dynamics_with_locks_on_each_states_own_model(name: str) -> None:
    """Random states of each model (the tree has every joint type, two branches and armature),
    each with the bodies of one of its variants (payloads, a random inertia on a body), with
    no lock, every joint locked, one joint free and random locks."""
    rng = np.random.default_rng(36)
    models = _models(name, rng)
    model = models[0]
    n, B = model.nv, 40
    parameters = np.array([[i.toDynamicParameters() for i in m.inertias] for m in models])
    q = np.array([pin.randomConfiguration(model, -np.ones(n), np.ones(n)) for _ in range(B)])
    v = rng.uniform(-2.0, 2.0, (B, n))
    tau = rng.uniform(-30.0, 30.0, (B, n))
    locked = rng.random((B, n)) < 0.5
    locked[0], locked[1], locked[2] = False, True, True
    locked[2, n // 2] = False
    v[locked] = 0.0  # the locked joints' torques stay: lambda_L has - tau_L
    which = rng.integers(0, len(models), B)
    chain = joint_chain(model)
    a, lam = chain_dynamics.locked_dynamics(
        chain, q, v, tau, locked, parameters, which, model.armature, model.gravity.vector
    )
    for s in range(B):
        a_ref, lam_ref = _reference(models[which[s]], q[s], v[s], tau[s], locked[s])
        assert np.abs(a[s] - a_ref).max() <= DYNAMICS_TOLERANCE * (1.0 + np.abs(a_ref).max())
        assert np.abs(lam[s] - lam_ref).max() <= DYNAMICS_TOLERANCE * (1.0 + np.abs(lam_ref).max())
        assert np.all(a[s][locked[s]] == 0.0) and np.all(lam[s][~locked[s]] == 0.0)


def test_a_singular_free_block_fails_its_state_alone() -> None:
    """A free joint that carries no inertia (a massless last body, no armature) has M_ff = 0:
    that state's free acceleration and its holding torques are NaN, as a singular solve
    gives (its run fails alone); the other state is exact."""
    robot = vp.load_robot("ur10")
    model = pin.Model(robot.model)
    model.armature = np.zeros(model.nv)
    model.inertias[model.njoints - 1] = pin.Inertia.Zero()
    n = model.nv
    rng = np.random.default_rng(2)
    q, v = rng.uniform(-2.0, 2.0, (2, n)), np.zeros((2, n))
    tau = np.zeros((2, n))
    locked = np.ones((2, n), dtype=bool)
    locked[0, n - 1] = False  # only the massless joint free: singular
    locked[1, 0] = False
    parameters = np.array([[i.toDynamicParameters() for i in model.inertias]])
    a, lam = chain_dynamics.locked_dynamics(
        joint_chain(model), q, v, tau, locked, parameters, np.zeros(2, dtype=int),
        model.armature, model.gravity.vector,
    )  # fmt: skip
    assert np.isnan(a[0, n - 1]) and np.all(a[0, :-1] == 0.0)
    assert np.all(np.isnan(lam[0, :-1])) and lam[0, n - 1] == 0.0
    a_ref, _ = _reference(model, q[1], v[1], tau[1], locked[1])
    tolerance = DYNAMICS_TOLERANCE * (1.0 + np.abs(a_ref).max())
    np.testing.assert_allclose(a[1], a_ref, rtol=0, atol=tolerance)
