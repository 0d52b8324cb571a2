"""The batched dynamics of lanes whose bodies' inertias differ from the batch's model (issue 27).

A payload drawn per case gives every case its own model; such runs share a batch
(:func:`vtm_pin.core.batch.batch_key`) whose lanes carry their inertias' differences dI from
the batch's model, added as J^T dI J to M and J^T (dI c + v x* dI v) to the bias forces.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin
import pytest
import yaml
from conftest import KERNEL_PATHS

import vtm_pin as vp
from vtm_pin.core import batch as batch_module
from vtm_pin.core.batch import (
    FEW_LANES,
    MIN_LANES,
    _base_model,
    _Dynamics,
    _groups,
    _model_keys,
    batch_key,
    model_key,
    robot_batch_key,
    robot_model_key,
    run_many,
)
from vtm_pin.exceptions import VtmWarning
from vtm_pin.numerics.dynamics import compute_M
from vtm_pin.physics import body_kernel, chain_dynamics, kinematics
from vtm_pin.physics.payload import Payload, attach_payload
from vtm_pin.scene.scenario import SCENARIOS_DIR

#: Relative agreement with Pinocchio on each lane's own model [-]: both are exact up to
#: round-off (ABA against the free columns of M by RNEA plus the payload's J^T dI J, solved
#: by LU), measured ~3e-15 on the UR10; 1e-10 leaves room for the condition of M_ff.
DYNAMICS_TOLERANCE = 1e-10


def _payload(rng: np.random.Generator) -> Payload:
    """A payload of 0-10 kg, its centre within 0.1 m of the flange, a box's inertia turned."""
    mass = rng.uniform(0.0, 10.0)
    x, y, z = rng.uniform(0.02, 0.2, 3) ** 2
    turn, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    inertia = turn @ np.diag([y + z, x + z, x + y]) @ turn.T * mass / 12.0
    return Payload(mass, tuple(rng.uniform(-0.1, 0.1, 3)), inertia)


def _path(monkeypatch: pytest.MonkeyPatch, compiled: bool) -> None:
    monkeypatch.setattr(body_kernel, "AVAILABLE", compiled)
    monkeypatch.setattr(chain_dynamics, "AVAILABLE", compiled)


@KERNEL_PATHS
def test_lanes_with_their_own_inertias_have_their_own_models_dynamics(
    compiled: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """a and the holding torques of random lanes, each with its own payload (or the batch's
    model, or a random inertia on another joint's body), are Pinocchio's ABA / RNEA on that
    lane's own model: lanes with no lock, every joint locked, one free joint, random locks.
    The payload bodies' motions by NumPy and the RNEA columns, and by the compiled kernels
    (the ``fast`` extra: :mod:`vtm_pin.physics.chain_dynamics` for every state with locks or
    its own inertias)."""
    _path(monkeypatch, compiled)
    robot = vp.load_robot("ur10")
    base, n = robot.model, robot.nv
    rng = np.random.default_rng(27)
    B = 48
    models = []
    for r in range(B):
        if r % 6 == 0:
            models.append(
                base
            )  # the batch's own model: no extra cost (ABA when unlocked, NumPy path)
        elif r % 6 == 5:
            model = pin.Model(base)
            j = int(rng.integers(1, base.njoints))
            model.inertias[j] = model.inertias[j] + pin.Inertia.Random()
            models.append(model)
        else:
            models.append(attach_payload(robot, _payload(rng)).model)
    dynamics = _Dynamics(base, threads=1, models=models)
    assert dynamics.compiled is compiled
    assert dynamics.loaded.tolist() == [r % 6 != 0 for r in range(B)]
    q = rng.uniform(-3.0, 3.0, (B, n))
    v = rng.uniform(-2.0, 2.0, (B, n))
    tau = rng.uniform(-50.0, 50.0, (B, n))
    locked = rng.random((B, n)) < 0.5
    locked[:12] = False
    locked[12], locked[13], locked[14] = True, True, True
    locked[14, 2] = False
    v[locked] = tau[locked] = 0.0
    lanes = rng.permutation(B)  # states in any order: each takes its lane's inertias
    a, lam = dynamics.accelerations(q, v, tau, locked, lanes)
    plain = _Dynamics(base, threads=1)  # no lane models: every lane is the pool's
    a_plain, lam_plain = plain.accelerations(q, v, tau, locked, lanes)
    own = np.array([not dynamics.loaded[r] for r in lanes])
    np.testing.assert_array_equal(a_plain[own], a[own])  # the same calls, the same bits
    np.testing.assert_array_equal(lam_plain[own], lam[own])
    shifted = _Dynamics(base, threads=1, models=models[1:] + models[:1])  # lane 0 loaded
    a_none, lam_none = shifted.accelerations(q, v, tau, locked)  # no lanes: the pool's model
    np.testing.assert_array_equal(a_none, a_plain)
    np.testing.assert_array_equal(lam_none, lam_plain)
    for i, r in enumerate(lanes):
        model = models[r]
        data = model.createData()
        free = np.flatnonzero(~locked[i])
        M = compute_M(model, data, q[i])
        b = pin.nonLinearEffects(model, data, q[i], v[i])
        a_ref = np.zeros(n)
        a_ref[free] = np.linalg.solve(M[np.ix_(free, free)], tau[i, free] - b[free])
        if free.size == n:
            a_ref = pin.aba(model, data, q[i], v[i], tau[i])
        lam_ref = np.where(locked[i], pin.rnea(model, data, q[i], v[i], a_ref) - tau[i], 0.0)
        assert np.abs(a[i] - a_ref).max() <= DYNAMICS_TOLERANCE * (1.0 + np.abs(a_ref).max())
        assert np.abs(lam[i] - lam_ref).max() <= DYNAMICS_TOLERANCE * (1.0 + np.abs(lam_ref).max())


def test_models_differing_in_inertias_only_share_a_batch_key() -> None:
    """A payload leaves the batch key as it is (the model key changes); other dynamics do not."""
    robot = vp.load_robot("ur10")
    loaded = attach_payload(robot, Payload(3.0, (0.0, 0.01, 0.05))).model
    assert model_key(loaded) != model_key(robot.model)
    assert batch_key(loaded) == batch_key(robot.model)
    heavier = pin.Model(robot.model)
    heavier.armature = heavier.armature * 2.0
    assert batch_key(heavier) != batch_key(robot.model)
    moved = pin.Model(robot.model)
    moved.jointPlacements[2] = pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.1]))
    assert batch_key(moved) != batch_key(robot.model)


@KERNEL_PATHS
def test_runs_with_drawn_payloads_are_batched_and_agree_with_the_scalar_engine(
    compiled: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """16 UR10 stops, each with its own payload, go through run_many as one batch and end
    as the scalar engine's: brake events within 1e-10 s and final states within 1e-8 (the
    issue's tolerance; record figures are checked in tests/test_batch_agreement.py), on
    either path of the batched engine."""
    _path(monkeypatch, compiled)
    raw = yaml.safe_load((SCENARIOS_DIR / "ur10_annex_b.yaml").read_text())
    raw["duration"] = 0.6  # [s] the stops are over by then
    scenario = vp.build_scenario(raw, source="test", base_dir=SCENARIOS_DIR, name="payloads")
    rng = np.random.default_rng(14)
    problems = []
    for _ in range(16):
        robot = attach_payload(scenario.robot, _payload(rng))
        problems.append(dataclasses.replace(scenario.problem, robot=robot))
    integrators = [scenario.integrator] * len(problems)
    batched = run_many(problems, integrators, min_lanes=16)
    scalar = run_many(problems, integrators, engine="scalar")
    assert batched.engines == ("batched",) * 16
    assert (batched.kernel_states > 0) is compiled
    for one, other in zip(scalar.results, batched.results, strict=True):
        assert isinstance(one, vp.SimulationResult) and isinstance(other, vp.SimulationResult)
        assert [(e.joint, e.kind) for e in one.brake_events] == [
            (e.joint, e.kind) for e in other.brake_events
        ]
        times = np.subtract([e.t for e in one.brake_events], [e.t for e in other.brake_events])
        assert np.abs(times).max() <= 1e-10
        np.testing.assert_allclose(other.q[-1], one.q[-1], rtol=0, atol=1e-8)
        np.testing.assert_allclose(other.v[-1], one.v[-1], rtol=0, atol=1e-8)


def test_a_batchs_model_is_the_one_most_of_its_runs_have() -> None:
    """Runs of the most common model cost nothing more: it is the batch's (the first in a tie)."""
    robot = vp.load_robot("ur10")
    light = attach_payload(robot, Payload(1.0, (0.0, 0.0, 0.05)))
    heavy = [attach_payload(robot, Payload(8.0, (0.0, 0.0, 0.05))) for _ in range(2)]
    robots = [light, *heavy]
    keys = [robot_model_key(robot) for robot in robots]
    assert _base_model(robots, keys) is heavy[0].model
    assert _base_model(robots[:2], keys[:2]) is light.model


def test_a_robots_cached_model_key_is_its_models() -> None:
    """The key kept in part in a robot's cache (shared with its payload copies) is
    :func:`model_key` of its model, before and after a copy has filled the shared part."""
    robot = vp.load_robot("ur10")
    loaded = attach_payload(robot, Payload(3.0, (0.0, 0.01, 0.05)))
    assert robot_model_key(loaded) == model_key(loaded.model)
    assert robot_model_key(robot) == model_key(robot.model)
    assert robot_model_key(loaded) != robot_model_key(robot)


def test_a_robots_batch_key_from_its_cache_is_its_models(monkeypatch: pytest.MonkeyPatch) -> None:
    """:func:`robot_batch_key` (the chain and the key's fixed part from the robot's cache,
    shared with its payload copies) is :func:`batch_key` of its model: for the base robot,
    for payload copies made before and after the shared part is filled, and for a model whose
    joints the NumPy chain does not take (its key is then the whole model's)."""
    robot = vp.load_robot("ur10")
    first = attach_payload(robot, Payload(3.0, (0.0, 0.01, 0.05)))
    assert robot_batch_key(first) == batch_key(first.model)
    later = attach_payload(robot, Payload(7.0, (0.02, 0.0, 0.05)))
    assert robot_batch_key(later) == batch_key(later.model) == batch_key(robot.model)
    assert robot_batch_key(robot) == batch_key(robot.model)
    assert robot_model_key(later) != robot_model_key(first)
    monkeypatch.setattr(batch_module, "joint_chain", lambda model: None)
    monkeypatch.setattr(batch_module, "cached_chain", lambda robot: None)
    assert robot_batch_key(first) == batch_key(first.model) == b"model " + model_key(first.model)
    assert robot_batch_key(first) != robot_batch_key(later)


@pytest.mark.parametrize("compiled", [False, True])
def test_a_model_with_min_lanes_runs_keeps_its_own_batch_only_without_the_kernel(
    compiled: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without the compiled kernel, MIN_LANES runs of one payload class are a batch of their
    own (ABA: their lanes cost least) and the runs of three other payloads, too few each, are
    pooled in one batch. With it, a lane costs the same pooled (every state goes through the
    kernel with its own bodies' parameters): all of them are one batch."""
    monkeypatch.setattr(chain_dynamics, "runs", lambda: compiled)
    scenario = vp.load_scenario(SCENARIOS_DIR / "ur10_annex_b.yaml")
    rng = np.random.default_rng(3)
    others = [
        dataclasses.replace(scenario.problem, robot=attach_payload(scenario.robot, _payload(rng)))
        for _ in range(3)
    ]
    problems = [scenario.problem] * MIN_LANES + others
    reasons: list[str | None] = [None] * len(problems)
    keys = _model_keys(problems, reasons)
    assert keys[MIN_LANES:] == [robot_model_key(p.robot) for p in others]
    groups = _groups(problems, [scenario.integrator] * len(problems), reasons, 1, keys)
    if compiled:
        assert list(groups.values()) == [list(range(MIN_LANES + 3))]
    else:
        assert sorted(groups.values()) == [
            list(range(MIN_LANES)),
            list(range(MIN_LANES, MIN_LANES + 3)),
        ]
    assert reasons == [None] * len(problems)
    _groups(problems, [scenario.integrator] * len(problems), reasons, 4, keys)
    few = [FEW_LANES.format(min_lanes=4)] * 3
    assert reasons[-3:] == ([None] * 3 if compiled else few) and reasons[0] is None


def test_numba_that_cannot_run_here_leaves_the_numpy_path_with_one_warning(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Numba installed but refusing to import here (a NumPy it does not support) or to compile:
    the first kernel call says so in one warning, and the NumPy path answers from then on,
    with the same results, for the locked dynamics and the bodies' motions alike (before, the
    batch failed and its runs went to the scalar engine)."""
    robot = vp.load_robot("ur10")
    base, n = robot.model, robot.nv
    rng = np.random.default_rng(5)
    B = 12
    models = [attach_payload(robot, _payload(rng)).model for _ in range(B)]
    q = rng.uniform(-3.0, 3.0, (B, n))
    v = rng.uniform(-2.0, 2.0, (B, n))
    tau = rng.uniform(-50.0, 50.0, (B, n))
    locked = rng.random((B, n)) < 0.5
    v[locked] = tau[locked] = 0.0
    lanes = np.arange(B)
    _path(monkeypatch, False)
    expected = _Dynamics(base, threads=1, models=models).accelerations(q, v, tau, locked, lanes)
    chain = kinematics.joint_chain(base)
    motions = kinematics.body_motions(chain, q, v, (6,), base.gravity.vector)

    def refuse() -> None:
        raise ImportError("Numba needs NumPy 2.3 or less; got NumPy 9.9.\nmore detail")

    _path(monkeypatch, True)
    monkeypatch.setattr(chain_dynamics, "_compiled", refuse)
    monkeypatch.setattr(body_kernel, "_compiled", refuse)
    dynamics = _Dynamics(base, threads=1, models=models)
    assert dynamics.compiled
    with pytest.warns(
        VtmWarning, match=r"cannot run here \(ImportError: Numba needs NumPy 2.3"
    ) as seen:
        got = dynamics.accelerations(q, v, tau, locked, lanes)
        again = dynamics.accelerations(q, v, tau, locked, lanes)
    assert len(seen) == 1 and "more detail" not in str(seen[0].message)
    assert not dynamics.compiled and dynamics.kernel_states == 0
    assert not chain_dynamics.runs() and not body_kernel.AVAILABLE
    for one, other in ((expected, got), (expected, again)):
        np.testing.assert_array_equal(one[0], other[0])
        np.testing.assert_array_equal(one[1], other[1])

    _path(monkeypatch, True)  # the bodies' motions: their first compiled call falls back too
    with pytest.warns(VtmWarning, match="cannot run here"):
        fallen = kinematics.body_motions(chain, q, v, (6,), base.gravity.vector)
    for one, other in zip(motions, fallen, strict=True):
        np.testing.assert_array_equal(one, other)
    assert not body_kernel.AVAILABLE
