"""Scenario keys of studies: payload, annex_b, and the category-1 torque limits' default."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from vtm_pin.exceptions import ScenarioError
from vtm_pin.files.inputs import read_yaml
from vtm_pin.outputs.pipeline import run
from vtm_pin.scene.scenario import SCENARIOS_DIR, build_scenario

BASE = read_yaml(SCENARIOS_DIR / "ur10_annex_b.yaml", ScenarioError)


def scenario(**changes: object) -> dict:
    raw = copy.deepcopy(BASE)
    raw["duration"] = 0.9
    for key, value in changes.items():
        if value is None:
            raw.pop(key, None)
        else:
            raw[key] = value
    return raw


def stop_angle(raw: dict) -> float:
    output = run(build_scenario(raw, base_dir=SCENARIOS_DIR))
    report = output.stopping[output.rule]
    state = output.scenario.test_state
    assert state is not None and not report.moving
    return abs(report.joints[state.joint_index].stop_angle)


def test_payload_and_test_state_are_reported() -> None:
    output = run(build_scenario(scenario(), base_dir=SCENARIOS_DIR))
    summary = output.summary
    assert summary["payload"]["mass"] == 10.0 and summary["payload"]["frame"] == "tool0"
    assert summary["annex_b"]["joint"] == "shoulder_lift_joint"
    assert summary["annex_b"]["speed"] == pytest.approx(2.16)  # the URDF velocity limit
    assert summary["annex_b"]["extension"] == pytest.approx(1.0, abs=1e-6)
    assumptions = " ".join(summary["assumptions"])
    assert "Payload 10 kg" in assumptions and "Annex-B" in assumptions
    v0 = output.scenario.v0
    assert np.count_nonzero(v0) == 1 and v0[1] == pytest.approx(2.16)


@pytest.mark.parametrize("joint", ["shoulder_lift_joint", "elbow_joint"])
def test_a_heavier_payload_stops_a_joint_moving_down_later(joint: str) -> None:
    """Gravity drives a joint moving down: more payload, more travel before the brake holds."""
    angles = [
        stop_angle(scenario(annex_b={**BASE["annex_b"], "joint": joint}, payload={"mass": m}))
        for m in (0.0, 5.0, 10.0)
    ]
    assert angles[0] < angles[1] < angles[2]


def test_a_faster_start_stops_later() -> None:
    angles = [
        stop_angle(scenario(annex_b={**BASE["annex_b"], "speed": s})) for s in (0.33, 0.66, 1.0)
    ]
    assert angles[0] < angles[1] < angles[2]


def test_category_1_torque_limits_default_to_the_urdf_efforts() -> None:
    built = build_scenario(scenario(stop={"t": 0.0, "category": 1, "ramp_time": 0.3}))
    assert built.stop is not None and built.stop.torque_limit is not None
    assert np.array_equal(built.stop.torque_limit, built.robot.model.effortLimit)
    assert any("URDF effort limits [330, 330, 150, 54, 54, 54] N m" in a for a in built.assumptions)
    given = build_scenario(scenario(stop={"category": 1, "ramp_time": 0.3, "torque_limit": 100}))
    assert not any("effort limits" in a for a in given.assumptions)


@pytest.mark.parametrize(
    ("changes", "key"),
    [
        ({"payload": {"mass": -1.0}}, "payload.mass"),
        ({"payload": {"mass": 1.0, "frame": "nowhere"}}, "payload.frame"),
        (
            {"payload": {"mass": 1.0, "inertia": {"ixx": 1.0, "iyy": 1.0, "izz": 5.0}}},
            "payload.inertia",
        ),
        ({"annex_b": {"joint": "nope"}}, "annex_b.joint"),
        ({"annex_b": {"joint": "elbow_joint", "speed": 0.0}}, "annex_b.speed"),
        ({"annex_b": {"joint": "elbow_joint", "extension": 1.5}}, "annex_b.extension"),
        ({"annex_b": None, "initial": None}, "initial"),
    ],
)
def test_bad_payload_and_conditions_name_their_key(changes: dict, key: str) -> None:
    with pytest.raises(ScenarioError) as info:
        build_scenario(scenario(**changes), source="s.yaml")
    assert info.value.key == key
    assert str(info.value).startswith("s.yaml: ") and "\n" not in str(info.value)
