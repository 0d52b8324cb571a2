"""The library pipeline: run a scenario, derive its reports, write its files all or nothing."""

import json

import numpy as np
import pytest
from conftest import SCENARIOS
from matplotlib.figure import Figure

from vtm_pin import ScenarioError, load_scenario
from vtm_pin.exceptions import OutputError
from vtm_pin.outputs.pipeline import (
    RunOutput,
    check_output_folder,
    find_scenario,
    run,
    write_outputs,
)
from vtm_pin.scene.scenario import SCENARIOS_DIR


@pytest.fixture(scope="module")
def paper() -> RunOutput:
    return run("pendulum3r", compare=["naive", "kkt", "naive"])


def test_run_holds_every_rule_main_first(paper):
    assert list(paper.results) == ["kkt", "naive"] and paper.rule == "kkt"
    assert paper.result is paper.results["kkt"]
    assert set(paper.energies) == {"kkt", "naive"} and paper.stopping == {}
    for rule, (result, energy) in paper.runs.items():
        assert result.transition == rule and energy.total.shape == result.t.shape
    assert paper.summary["transition"] == "kkt" and list(paper.summary["compare"]) == ["naive"]
    assert paper.summary["energy"]["initial_total"] == paper.energies["kkt"].total[0]


def test_run_takes_a_scenario_a_path_or_a_name_and_a_transition():
    scenario = load_scenario(SCENARIOS / "pendulum3r.yaml")
    by_object = run(scenario, transition="minimal")
    by_path = run(SCENARIOS / "pendulum3r.yaml", transition="minimal")
    assert by_object.scenario is scenario and by_object.rule == "minimal"
    np.testing.assert_array_equal(by_object.result.q, by_path.result.q)


def test_progress_is_called_per_rule_up_to_the_end(paper):
    calls = []
    run(paper.scenario, compare=["naive"], progress=lambda rule, t: calls.append((rule, t)))
    rules = [rule for rule, _ in calls]
    assert rules == sorted(rules, key=["kkt", "naive"].index) and set(rules) == {"kkt", "naive"}
    assert max(t for rule, t in calls if rule == "naive") == pytest.approx(2.0)


def test_a_stop_gives_stopping_reports_per_rule():
    output = run("rx160l_estop_cat0", compare=["naive"])
    assert set(output.stopping) == {"kkt", "naive"}
    assert "stopping" in output.summary and "stopping" in output.summary["compare"]["naive"]


def test_find_scenario_prefers_an_existing_path(tmp_path, monkeypatch):
    assert find_scenario("pendulum3r") == SCENARIOS_DIR / "pendulum3r.yaml"
    assert find_scenario("pendulum3r.yaml") == SCENARIOS_DIR / "pendulum3r.yaml"
    monkeypatch.chdir(tmp_path)
    (tmp_path / "pendulum3r.yaml").write_text("mine")
    assert find_scenario("pendulum3r.yaml").resolve() == tmp_path / "pendulum3r.yaml"
    missing = tmp_path / "sub" / "pendulum3r.yaml"  # a path is not a name: its reader says why
    assert find_scenario(missing) == missing


def test_find_scenario_names_the_shipped_ones():
    with pytest.raises(ScenarioError) as info:
        find_scenario("pendulum4r")
    assert str(info.value) == (
        "pendulum4r: no such file, and not the name of a shipped scenario ("
        + ", ".join(sorted(p.stem for p in SCENARIOS.glob("*.yaml")))
        + ")"
    )


def test_write_outputs_writes_every_file(paper, tmp_path):
    out = tmp_path / "a" / "b"
    written = write_outputs(paper, out)
    assert written == sorted(p.name for p in out.iterdir())
    assert {"summary.json", "trajectory.csv", "trajectory_naive.csv", "poses.png"} <= set(written)
    assert json.loads((out / "summary.json").read_text()) == paper.summary
    assert [p.name for p in tmp_path.iterdir()] == ["a"]  # no staging folder left


def test_write_outputs_is_all_or_nothing(paper, tmp_path):
    class Broken(Figure):
        def savefig(self, *args, **kwargs):
            raise OSError(28, "No space left on device")

    out = tmp_path / "out"
    with pytest.raises(OutputError) as info:
        write_outputs(paper, out, {"a.png": Figure(), "b.png": Broken()})
    assert str(info.value) == (
        f"Cannot write the results: cannot write '{out}' (No space left on device)"
    )
    assert list(tmp_path.iterdir()) == []


def test_check_output_folder_refuses_a_file(tmp_path):
    (tmp_path / "afile").write_text("x")
    check_output_folder(tmp_path / "new" / "folder")
    with pytest.raises(OutputError, match=r"'.*afile' is a file, not a folder$"):
        check_output_folder(tmp_path / "afile" / "out")
    assert [p.name for p in tmp_path.iterdir()] == ["afile"]
