"""Annex-B poses of many cases at once (issue 27): Newton over the lanes against Newton alone.

:mod:`vtm_pin.scene.annex_b_batch` runs ``annex_b._newton``'s iteration for many extensions at
once with NumPy kinematics; a study's runner solves its cases' poses so, after its first
Annex-B case (:class:`vtm_pin.study.runner._Poses`), and the cases' builds find them cached.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
import yaml
from conftest import SCENARIOS, robot

from vtm_pin.scene import annex_b, annex_b_batch
from vtm_pin.scene.scenario import build_scenario, solve_variant_poses
from vtm_pin.study import runner
from vtm_pin.study.cases import find_study, load_study

#: [rad] Newton over the lanes and Newton alone reach the same KKT point; both stop once its
#: residual is <= KKT_TOL = 1e-11 rad and the constraints' <= 1e-13 m, after quadratic
#: convergence, so their poses differ by the round-off of the two kinematics (NumPy's and
#: Pinocchio's, ~1e-16 per product). Measured: at most 4e-15 rad on these draws.
POSE_TOL = 1.0e-12
#: [s, rad, m, m/s] The figures of a case whose pose differs by round-off: the issue's 1e-8 (the
#: UR10 envelope's Coulomb brakes; viscous bound variants can amplify it, see test_batch.py).
FIGURES = 1.0e-8
UR10_GUESS = np.array(
    yaml.safe_load((SCENARIOS / "ur10_annex_b.yaml").read_text())["initial"]["q"], dtype=float
)


def alone(model: pin.Model, chain: annex_b._Chain, guess: np.ndarray, target: float):
    """``annex_b._newton`` for one target reach [m]: the free joints' values or None."""
    ev = annex_b._Evaluator(model, chain, guess)
    return annex_b._newton(ev, guess[chain.free], target, annex_b._bounds(model, chain))


@pytest.mark.parametrize("name", ["ur10", "ur5"])
def test_newton_over_the_lanes_is_newton_alone(name: str) -> None:
    """For three guesses (the UR10 Annex-B base's, the neutral pose, a random one) and 40
    extensions each in (0, 1), among them ones Newton refuses (a folded arm, a stretched
    one), each lane returns the pose Newton alone returns, within POSE_TOL, and refuses where
    it refuses."""
    the = robot(name)
    model = the.model
    chain = annex_b._chain(model, the.tool_frame)
    rng = np.random.default_rng(27)
    lower = np.maximum(model.lowerPositionLimit, -np.pi)
    guesses = [pin.neutral(model), rng.uniform(lower, np.minimum(model.upperPositionLimit, np.pi))]
    if name == "ur10":
        guesses.append(UR10_GUESS)
    refused = found = 0
    for guess in guesses:
        guess = annex_b._clip(model, guess)
        R = annex_b._max_reach(model, chain, guess).R
        es = np.concatenate([rng.uniform(0.02, 0.999, 36), [0.001, 0.01, 0.9999, 0.99999]])
        lanes = annex_b_batch._Lanes(the, chain, annex_b_batch.joint_chain(model), guess)
        many = annex_b_batch.newton_many(
            lanes, guess[chain.free], es * R, annex_b._bounds(model, chain)
        )
        for e, x in zip(es, many, strict=True):
            one = alone(model, chain, guess, e * R)
            assert (x is None) == (one is None), f"e = {e}: lanes {x}, alone {one}"
            if one is not None:
                assert x is not None and np.abs(x - one).max() <= POSE_TOL
                found += 1
            else:
                refused += 1
    assert found >= 20 * len(guesses) and refused > 0  # both outcomes were exercised


def test_a_studys_cases_find_their_poses_solved_together() -> None:
    """solve_variant_poses solves every later case's e < 1 pose in one go; the cases' builds
    then find them cached: the test states equal those built with an empty cache (within
    POSE_TOL), and their builds solve nothing more (Newton alone is not called)."""
    study = load_study(find_study("ur10_envelope"))
    cases = study.cases()[:40]
    raws = [runner._case_raw(runner.CaseTask(study.base, "", "", "", c)) for c in cases]

    def build(raw):
        return build_scenario(raw, base_dir=study.scenario.parent, loader=runner._ROBOTS)

    annex_b._POSE_CACHE.clear()
    alone_states = [build(raw).test_state for raw in raws]
    annex_b._POSE_CACHE.clear()
    first = build(raws[0])
    solved = solve_variant_poses(first, raws[0], raws[1:])
    assert solved == len({float(r["annex_b"]["extension"]) for r in raws[1:]})
    calls = []
    newton = annex_b._newton
    try:
        annex_b._newton = lambda *args: calls.append(1) or newton(*args)  # type: ignore[assignment]
        states = [build(raw).test_state for raw in raws[1:]]
    finally:
        annex_b._newton = newton  # type: ignore[assignment]
    assert calls == []
    for state, reference in zip(states, alone_states[1:], strict=True):
        assert state is not None and reference is not None
        assert np.abs(state.q - reference.q).max() <= POSE_TOL
        np.testing.assert_array_equal(state.v, reference.v)


def test_variants_it_cannot_read_are_left_to_their_builds() -> None:
    """A variant with another robot, another tool frame, a bad guess or no annex_b key is
    skipped, not refused: only the readable variants' poses are solved."""
    raw = yaml.safe_load((SCENARIOS / "ur10_annex_b.yaml").read_text())
    first = build_scenario(raw, base_dir=SCENARIOS)
    annex_b._POSE_CACHE.clear()

    def variant(e: float, **changes):
        out = {**raw, "annex_b": {**raw["annex_b"], "extension": e}}
        out.update(changes)
        return out

    variants = [
        variant(0.41),
        variant(0.42, robot="ur5"),
        variant(0.43, tool_frame="wrist_3_link"),
        variant(0.44, initial={"q": [0.0, "x"]}),
        {k: v for k, v in variant(0.45).items() if k != "annex_b"},
        variant(0.46, initial={"q": [0.1, -1.2, 1.0, -1.4, -1.57, 0.0]}),  # another guess
    ]
    assert solve_variant_poses(first, raw, variants) == 2


def test_a_failing_joint_solve_leaves_every_case_to_its_own_build(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Solving the poses together is an optimisation: if it fails (here Newton over the lanes
    raising LinAlgError), no case fails: each build solves its own pose, with Pinocchio's
    Newton, and the figures equal those of a run whose joint solve works within FIGURES (the
    poses differ by round-off, ~1e-15 rad)."""
    study = load_study(find_study("ur10_envelope"))
    tasks = [
        runner.CaseTask(study.base, str(study.scenario.parent), "", "t", c)
        for c in study.cases()[:6]
    ]
    annex_b._POSE_CACHE.clear()
    good = runner.run_cases(tasks, engine="scalar")

    def broken(*args: object) -> None:
        raise np.linalg.LinAlgError("SVD did not converge")

    monkeypatch.setattr(annex_b_batch, "newton_many", broken)
    annex_b._POSE_CACHE.clear()
    records = runner.run_cases(tasks, engine="scalar")
    assert [r["status"] for r in records] == ["ok"] * len(tasks)
    for record, reference in zip(records, good, strict=True):
        assert record["metrics"].keys() == reference["metrics"].keys()
        for key, value in reference["metrics"].items():
            if isinstance(value, float):
                assert abs(record["metrics"][key] - value) <= FIGURES, key
            else:
                assert record["metrics"][key] == value, key
