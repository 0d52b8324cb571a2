"""Runs without the samples' holding torques (``run_many(holding=False)``, a study's records).

A study's records hold no holding torque, so its runs leave them out: the batched engine
evaluates no right-hand side at the output samples (~70 of a UR10 case's ~290), and the
hybrid loop computes none for its instant segments. Nothing else may change: the motion,
the brakes' decisions and the events are the same to the bit, on both engines.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yaml

import vtm_pin as vp
from vtm_pin.core.batch import run_many
from vtm_pin.physics.payload import Payload, attach_payload
from vtm_pin.scene.scenario import SCENARIOS_DIR


@pytest.mark.parametrize("engine", ["batched", "scalar"])
def test_runs_without_holding_torques_move_and_decide_alike_to_the_bit(engine: str) -> None:
    raw = yaml.safe_load((SCENARIOS_DIR / "ur10_annex_b.yaml").read_text())
    raw["duration"] = 0.6  # [s] the stops are over by then
    scenario = vp.build_scenario(raw, source="test", base_dir=SCENARIOS_DIR, name="holding")
    rng = np.random.default_rng(3)
    problems = [
        dataclasses.replace(
            scenario.problem,
            robot=attach_payload(
                scenario.robot, Payload(float(rng.uniform(0.0, 10.0)), (0.0, 0.0, 0.05))
            ),
            v0=scenario.problem.v0 * rng.uniform(0.3, 1.0),
        )
        for _ in range(12)
    ]
    integrators = [scenario.integrator] * len(problems)
    kept = run_many(problems, integrators, engine=engine, min_lanes=12)
    left = run_many(problems, integrators, engine=engine, min_lanes=12, holding=False)
    assert kept.engines == left.engines == (engine,) * 12
    for one, other in zip(kept.results, left.results, strict=True):
        assert isinstance(one, vp.SimulationResult) and isinstance(other, vp.SimulationResult)
        for name in ("t", "q", "v", "free", "modes", "brake_work", "brake_impulse"):
            np.testing.assert_array_equal(getattr(one, name), getattr(other, name), name)
        assert one.brake_events == other.brake_events
        assert [(e.t, e.lock) for e in one.events] == [(e.t, e.lock) for e in other.events]
        assert one.rhs_evals == other.rhs_evals
        assert np.isfinite(one.holding).any()  # the locks' torques, where they are kept
        assert np.isnan(other.holding).all()  # not computed, nor kept block by block
        assert other.holding.shape == one.holding.shape
