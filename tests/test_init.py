"""``vtm-pin init``: a shipped file copied next to the user works there; ``list`` says where."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from vtm_pin.cli import main
from vtm_pin.physics.robot import ROBOTS_DIR, load_robot
from vtm_pin.scene.scenario import SCENARIOS_DIR, load_scenario
from vtm_pin.schemas import schema_file
from vtm_pin.shipped import shipped_names
from vtm_pin.study.cases import STUDIES_DIR, load_study


@pytest.mark.parametrize("name", shipped_names("scenario"))
def test_every_shipped_scenario_builds_from_its_copy(name, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["init", "scenario", name, "--to", "mine"]) == 0
    written = capsys.readouterr().out.strip().removeprefix("wrote ").split(", ")
    assert written[0] == f"mine/{name}.yaml"
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    copy = load_scenario(f"../mine/{name}.yaml")
    shipped = load_scenario(SCENARIOS_DIR / f"{name}.yaml")
    assert copy.raw == shipped.raw  # the same scenario, fragments merged
    assert (copy.q0 == shipped.q0).all() and copy.brakes == shipped.brakes
    assert_schema_line(tmp_path / "mine" / f"{name}.yaml", "scenario")


def assert_schema_line(copy, kind):
    """The copy's editor schema line names the installed schema by an absolute path."""
    first = copy.read_text().splitlines()[0]
    assert first.startswith("# yaml-language-server: $schema=/"), first
    named = Path(first.split("=", 1)[1])
    assert named.is_file() and named.samefile(Path(str(schema_file(kind))))


def test_a_copied_scenario_with_a_fragment_runs_from_another_folder(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["init", "scenario", "ur5_cb3_annex_b"]) == 0
    assert capsys.readouterr().out == "wrote ur5_cb3_annex_b.yaml, ur5_cb3_calibrated.yaml\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "ur5_cb3_annex_b.yaml",
        "ur5_cb3_calibrated.yaml",
    ]
    assert "include: [ur5_cb3_calibrated.yaml]" in (tmp_path / "ur5_cb3_annex_b.yaml").read_text()
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    assert main(["run", "../ur5_cb3_annex_b.yaml", "--no-plots", "--json", "--out", "o"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["robot"] == "ur5_cb3" and (tmp_path / "elsewhere/o/summary.json").is_file()


@pytest.mark.parametrize("name", shipped_names("study"))
def test_every_shipped_study_loads_from_its_copy(name, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["init", "study", name, "--to", "mine"]) == 0
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    copy = load_study(f"../mine/{name}.yaml")
    shipped = load_study(STUDIES_DIR / f"{name}.yaml")
    assert copy.scenario.resolve() == shipped.scenario.resolve()
    assert copy.size == shipped.size and copy.base == shipped.base
    assert_schema_line(tmp_path / "mine" / f"{name}.yaml", "study")


def test_a_copied_robot_runs_beside_its_data(tmp_path, monkeypatch, capsys):
    """ur10 ships only its data file: the copy brings example-robot-data's URDF beside it."""
    monkeypatch.chdir(tmp_path)
    assert main(["init", "robot", "ur10"]) == 0
    assert capsys.readouterr().out.strip() == "wrote ur10.urdf, ur10.yaml"
    copy, shipped = load_robot("ur10.urdf"), load_robot("ur10")
    assert copy.rated_payload == shipped.rated_payload == 10.0
    assert copy.joints == shipped.joints and copy.drives == shipped.drives
    text = (SCENARIOS_DIR / "ur10_estop_cat0.yaml").read_text()
    (tmp_path / "mine.yaml").write_text(text.replace("robot: ur10", "robot: ur10.urdf", 1))
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    assert (
        load_scenario("../mine.yaml").brakes
        == load_scenario(SCENARIOS_DIR / "ur10_estop_cat0.yaml").brakes
    )  # the robot data's brakes, found beside the copied URDF


def test_init_refuses_to_overwrite_and_writes_nothing(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "rx160l.yaml").write_text("mine\n")
    assert main(["init", "robot", "rx160l"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "rx160l.yaml exists; nothing copied" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rx160l.yaml"]  # no rx160l.urdf
    assert (tmp_path / "rx160l.yaml").read_text() == "mine\n"


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["init", "robots", "ur10"], "'KIND': 'robots' is not one of scenario, study, robot"),
        (["init", "study", "nope"], "the shipped ones are: ur10_annex_b, ur10_brake_wear"),
        (["init", "scenario", "../x"], "is not a shipped scenario; the shipped ones are: fivebar"),
    ],
)
def test_init_refuses_unknown_kinds_and_names_in_one_line(
    argv, expected, tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.startswith("vtm-pin: error: ") and err.count("\n") == 1 and expected in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("what", "folder"),
    [("scenarios", SCENARIOS_DIR), ("studies", STUDIES_DIR), ("robots", ROBOTS_DIR)],
)
def test_list_says_where_the_shipped_files_live(what, folder, capsys):
    assert main(["list", what]) == 0
    out = capsys.readouterr().out
    assert f"\nin {folder} ('vtm-pin init {what.removesuffix('s').replace('ie', 'y')} NAME'" in out
