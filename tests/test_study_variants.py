"""A study case is built as a variant of its validated base (``vtm_pin.study.cases.FAST_CASES``).

Only the top-level values a case sets are copied, only what differs from the base is checked
against the schema, and the merge does not check again what the schema check has just
checked. These tests run the same cases with that path on and off (off: every case deep-copied
and checked whole, ``valid=None``, as a fresh scenario) and compare what comes out.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from vtm_pin.scene import scenario as scenario_module
from vtm_pin.scene.scenario import SCENARIOS_DIR, build_scenario
from vtm_pin.study import cases as cases_module
from vtm_pin.study.cases import Case, Study, case_scenario, find_study, load_study
from vtm_pin.study.runner import CaseTask, run_cases

#: Record keys that depend on the machine, not on the case.
TIMING = ("timing", "wall_time", "engine_split")


def tasks(study: Study, count: int | None = None) -> list[CaseTask]:
    """The first ``count`` cases of ``study`` as a worker receives them."""
    folder, source = str(study.scenario.parent), str(study.scenario)
    return [
        CaseTask(study.base, folder, source, study.scenario.stem, case, study.fingerprint)
        for case in study.cases()[:count]
    ]


def records(
    monkeypatch: pytest.MonkeyPatch, study: Study, fast: bool, count: int | None = None, **kw: Any
) -> list[dict[str, Any]]:
    """The records of the study's first cases, with the variant path on or off."""
    with monkeypatch.context() as patch:
        patch.setattr(cases_module, "FAST_CASES", fast)
        out = run_cases(tasks(study, count), **kw)
    return [{k: v for k, v in r.items() if k not in TIMING} for r in out]


def write(folder: Path, text: str) -> Path:
    path = folder / "study.yaml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("name", ["ur10_envelope", "ur10_brake_wear"])
def test_records_are_the_same_with_the_variant_path_on_and_off(
    monkeypatch: pytest.MonkeyPatch, name: str
) -> None:
    """30 cases of a shipped study, batched: every record equal, key by key (floats exactly)."""
    study = load_study(find_study(name))
    fast = records(monkeypatch, study, True, 30)
    fresh = records(monkeypatch, study, False, 30)
    assert [r["status"] for r in fast] == ["ok"] * 30
    for one, other in zip(fast, fresh, strict=True):
        assert one.keys() == other.keys()
        for key in one:
            assert one[key] == other[key], (one["case"], key)


def test_cases_invalid_together_fail_as_a_fresh_scenario(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Values each valid alone: a stop after a shorter run's end, a drawn count not whole."""
    grid = load_study(
        write(tmp_path, "scenario: ur10_annex_b\nvary: {stop.t: [0.0, 1.0], duration: [0.9]}\n")
    )
    fast = records(monkeypatch, grid, True, engine="scalar")
    assert fast == records(monkeypatch, grid, False, engine="scalar")
    assert fast[0]["status"] == "ok"
    assert fast[1]["status"].startswith("error: ") and "stop" in fast[1]["status"]
    # min and max are whole (checked when the study is loaded), the draws between are not
    drawn = load_study(
        write(
            tmp_path,
            "scenario: ur10_annex_b\nsamples: 2\n"
            "vary: {integrator.max_steps: {min: 100000, max: 200000}}\n",
        )
    )
    fast = records(monkeypatch, drawn, True, engine="scalar")
    assert fast == records(monkeypatch, drawn, False, engine="scalar")
    for record in fast:
        assert (
            record["status"].startswith("error: ")
            and "'integrator.max_steps'" in (record["status"])
        ), record["status"]


def built(study: Study, values: dict[str, Any]) -> Any:
    """The scenario of a case of ``study`` with ``values``, built as a worker builds it."""
    raw = case_scenario(study.base, Case("c", 0, values))
    return build_scenario(
        raw, source=str(study.scenario), base_dir=study.scenario.parent, valid=study.base
    )


def test_brake_axes_still_change_the_brakes(tmp_path: Path) -> None:
    study = load_study(
        write(tmp_path, "scenario: ur10_annex_b\nvary: {brake_scale: [0.5], failed_brake: [none]}")
    )
    rated = {b.joint: b.friction for b in built(study, {}).brakes}
    worn = built(study, {"brake_scale": 0.5})
    assert {b.joint: b.friction.sliding_torque for b in worn.brakes} == pytest.approx(
        {j: 0.5 * f.sliding_torque for j, f in rated.items()}, rel=1e-15
    )
    assert any("brake_scale" in line for line in worn.assumptions)
    failed = built(study, {"failed_brake": "elbow_joint"})
    assert {b.joint for b in failed.brakes} == set(rated) - {"elbow_joint"}  # not re-merged
    assert {b.joint for b in built(study, {}).brakes} == set(rated)  # the base is untouched


def test_the_cases_of_a_base_share_its_merge_and_brakes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Cases that hold what the merge reads as their base's own are merged and braked once:
    the robot data file is read for the first only, and each scenario equals a fresh build
    (its keys in the same order). A case whose axes change the brakes, and the cases of
    another base, are merged anew."""
    reads: list[str] = []
    robot_data = scenario_module.robot_data

    def counted(*args: Any) -> Any:
        reads.append(str(args[0]))
        return robot_data(*args)

    monkeypatch.setattr(scenario_module, "robot_data", counted)
    study = load_study(find_study("ur10_envelope"))
    assert reads  # loading the study built its base
    reads.clear()
    values = [dict(case.values) for case in study.cases()[:4]]
    first, *others = [built(study, v) for v in values]
    assert not reads  # its cases read nothing more
    for v, scenario in zip(values, [first, *others], strict=True):
        raw = case_scenario(study.base, Case("c", 0, v))
        fresh = build_scenario(raw, source=str(study.scenario), base_dir=study.scenario.parent)
        assert list(scenario.raw) == list(fresh.raw) and scenario.raw == fresh.raw
        assert scenario.brakes == fresh.brakes and scenario.brakes is first.brakes
        assert scenario.problem.q0.tolist() == fresh.problem.q0.tolist()
    worn_study = load_study(write(tmp_path, "scenario: ur10_annex_b\nvary: {brake_scale: [0.5]}"))
    assert reads  # another base: merged anew
    reads.clear()
    worn = built(worn_study, {"brake_scale": 0.5})
    again = built(worn_study, {"brake_scale": 0.5})
    assert len(reads) == 2  # the brakes are the case's own: merged each time
    assert worn.brakes == again.brakes and worn.brakes != built(worn_study, {}).brakes
    assert len(reads) == 2  # a case without axes is its base


def test_an_edited_fragment_is_not_served_stale(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The same study loaded again after its base's fragment changed runs the new fragment."""
    fragment = tmp_path / "brakes.yaml"
    base = yaml.safe_load((SCENARIOS_DIR / "ur10_annex_b.yaml").read_text())
    base["include"] = ["brakes.yaml"]
    (tmp_path / "base.yaml").write_text(yaml.safe_dump(base))
    path = write(tmp_path, "scenario: base.yaml\nvary: {joint: [elbow_joint], duration: [0.9]}\n")
    runs = []
    for torque in (40.0, 20.0):
        fragment.write_text(
            f"assumptions: [elbow brake at {torque:g} N m]\n"
            f"brakes:\n  elbow_joint: {{sliding_torque: {torque}}}\n"
        )
        study = load_study(path)
        elbow = next(b for b in built(study, {}).brakes if b.joint == "elbow_joint")
        assert elbow.friction.sliding_torque == torque
        (record,) = records(monkeypatch, study, True, engine="scalar")
        assert f"elbow brake at {torque:g} N m" in record["assumptions"]
        runs.append(record)
    weaker, stronger = (run["metrics"]["stop_angle"] for run in reversed(runs))
    assert weaker > stronger  # the weaker brake stops later


def test_a_case_copies_only_what_its_axes_set(monkeypatch: pytest.MonkeyPatch) -> None:
    """With the variant path, untouched values are the base's objects (nothing modifies them)."""
    study = load_study(find_study("ur10_brake_wear"))
    case = study.cases()[0]
    raw = case_scenario(study.base, case)
    touched = {"annex_b", "payload", "brakes", "assumptions"}
    assert {k for k in raw if raw[k] is not study.base[k]} == touched
    monkeypatch.setattr(cases_module, "FAST_CASES", False)
    fresh = case_scenario(study.base, case)
    containers = [k for k, v in fresh.items() if isinstance(v, (dict, list))]
    assert fresh == raw and all(fresh[k] is not study.base[k] for k in containers)


_LEAVES = st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text()
_DOCUMENTS = st.recursive(
    _LEAVES | st.dates(),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=3), inner),
    max_leaves=20,
)


@settings(max_examples=200, deadline=None)
@given(document=_DOCUMENTS, alias=st.booleans())
def test_the_copy_of_a_touched_value_is_deepcopys(document: Any, alias: bool) -> None:
    """A case's touched values are copied as copy.deepcopy copies them (hypothesis, 200 draws).

    Equal values, no mapping or list shared with the base, a YAML alias (one object twice)
    still one object, and leaves of other types (dates) copied as deepcopy copies them.
    """
    base = {"a": {"x": document, "y": [document, 1]}, "b": document}
    if alias:
        base["a"]["z"] = base["a"]["y"]
    mine = cases_module._variant(base, [("a",)])
    theirs = copy.deepcopy(base)
    assert mine == theirs and mine["b"] is base["b"]

    def containers(value: Any) -> list[Any]:
        if isinstance(value, dict):
            return [value, *(c for item in value.values() for c in containers(item))]
        if isinstance(value, list):
            return [value, *(c for item in value for c in containers(item))]
        return []

    original = {id(c) for c in containers(base["a"])}
    assert not original & {id(c) for c in containers(mine["a"])}
    if alias:
        assert mine["a"]["z"] is mine["a"]["y"]
