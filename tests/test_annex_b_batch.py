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

#: [m] A pose's constraint residuals by Pinocchio's kinematics: Newton stops at 1e-13 m by
#: NumPy's; the two kinematics differ by round-off (~1e-16 m per product on a ~1 m arm).
RESIDUAL = 1.0e-12
#: [rad] Stationarity (x - g) + J_c^T lambda by Pinocchio's gradients, lambda by least squares:
#: Newton stops at KKT_TOL = 1e-11 by NumPy's; 1e-10 leaves room for multipliers of a few rad/m
#: times the round-off of the gradients.
STATIONARY = 1.0e-10
UR10_GUESS = np.array(
    yaml.safe_load((SCENARIOS / "ur10_annex_b.yaml").read_text())["initial"]["q"], dtype=float
)


@pytest.mark.parametrize("name", ["ur10", "ur5"])
def test_a_lanes_pose_is_the_same_alone_and_among_others_and_a_kkt_point(name: str) -> None:
    """For three guesses (the UR10 Annex-B base's, the neutral pose, a random one) and 40
    extensions each in (0, 1), among them ones Newton refuses (a folded arm, a stretched one):
    - each lane's pose, or refusal, is the same to the bit solved alone (a single case's
      build) and among the 40 (a study's): a case's figures do not depend on its company;
    - each pose meets the constraints and the stationarity condition by Pinocchio's frame
      Jacobian (annex_b._Evaluator), within RESIDUAL and STATIONARY."""
    the = robot(name)
    model = the.model
    chain = annex_b._chain(model, the.tool_frame)
    bounds = annex_b._bounds(model, chain)
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
        lanes = annex_b_batch._Lanes(model, chain, annex_b_batch._joints(model, chain), guess)
        many = annex_b_batch.newton_many(lanes, guess[chain.free], es * R, bounds)
        for e, x in zip(es, many, strict=True):
            one = annex_b_batch.newton_alone(model, chain, guess, e * R, bounds)
            assert (x is None) == (one is None), f"e = {e}: among others {x}, alone {one}"
            if x is None:
                refused += 1
                continue
            assert one is not None and np.array_equal(x, one)
            ev = annex_b._Evaluator(model, chain, guess).at(x)
            assert abs(ev.r - e * R) <= RESIDUAL and abs(ev.h) <= RESIDUAL
            Jc = np.array([ev.dr, ev.dh])
            lam = np.linalg.lstsq(Jc.T, -(x - guess[chain.free]), rcond=None)[0]
            assert np.abs((x - guess[chain.free]) + Jc.T @ lam).max() <= STATIONARY
            found += 1
    assert found >= 20 * len(guesses) and refused > 0  # both outcomes were exercised


def test_a_studys_cases_find_their_poses_solved_together() -> None:
    """solve_variant_poses solves every later case's e < 1 pose in one go; the cases' builds
    then find them cached: the test states equal to the bit those built case by case with an
    empty cache, and their builds solve nothing more (Newton is not called)."""
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
        np.testing.assert_array_equal(state.q, reference.q)
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
