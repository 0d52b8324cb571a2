"""``vtm-pin program``: stops triggered along a robot program, separation distances, override.

One run of the shipped UR10 pick-and-place program (every 1 s of program time, plus the
peak-speed instants, at F = 0.5 and 1, with an override search) feeds most tests; the
bisection's logic is also tested on a figure with a known answer.
"""

from __future__ import annotations

import html
import json
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from test_study_report import PROBE, chromium, run_chromium

from vtm_pin.cli import main
from vtm_pin.outputs.pipeline import run
from vtm_pin.scene.scenario import build_scenario
from vtm_pin.study.cases import case_scenario
from vtm_pin.study.sweep import (
    ProgramStudy,
    find_override,
    load_program_study,
    make_triggers,
    tool_speeds,
)

PROGRAM, BASE = "ur10_pick_place", "ur10_program_cat0"
#: The allowed S_p of the search [m]: between the largest S_p at F = 0.5 and at F = 1 on the
#: shipped program, so that the answer lies inside (0.5, 1).
ALLOWED = 1.43


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    out = tmp_path_factory.mktemp("program") / "out"
    argv = [
        "program",
        PROGRAM,
        "--scenario",
        BASE,
        "--every",
        "2.0",
        "--override",
        "0.5",
        "1.0",
        "--within",
        str(ALLOWED),
        "--tolerance",
        "0.05",
        "--workers",
        "2",
        "--json",
        "--out",
        str(out),
    ]
    assert main(argv) == 0
    return out, pd.read_csv(out / "program.csv"), json.loads((out / "summary.json").read_text())


def test_the_run_writes_the_program_files(swept):
    out, table, summary = swept
    for name in ("program.csv", "program.png", "swept.png", "swept.npz", "program.html"):
        assert (out / name).is_file(), name
    assert (out / "program_at_override.csv").is_file()
    study = load_program_study(PROGRAM, BASE, every=2.0, overrides=(0.5, 1.0))
    assert len(table) == study.size == 2 * len(study.triggers)
    reasons = ";".join(table["trigger"])
    assert "peak joint speed" in reasons and "peak tool speed" in reasons
    for column in ("robot_stop_time", "overall_stop_time", "tcp_max_displacement", "ssm_distance"):
        assert table[column].notna().all() and f"{column}_upper" in table.columns
    assert (table["overall_stop_time"] > table["robot_stop_time"]).all()  # T is not T_robot
    swept_points = np.load(out / "swept.npz")
    assert swept_points["reached"].shape[1] == 3 and len(swept_points["reached"]) > 100
    assert summary["worst_trigger"]["ranked_by"] == "ssm_distance_upper"


def test_a_trigger_is_the_one_off_run_from_the_same_state(swept):
    """A trigger's figures are those of `vtm-pin run` from the program's state there."""
    _, table, _ = swept
    study = load_program_study(PROGRAM, BASE, every=2.0, overrides=(0.5, 1.0))
    case = study.cases()[-3]
    raw = case_scenario(study.base, case)
    assert raw["initial"]["q"] == case.settings["initial.q"]
    one_off = run(build_scenario(raw, source="test", base_dir=study.scenario.parent))
    row = table[
        (table["override"] == case.values["override"])
        & np.isclose(table["program_time"], case.values["program_time"], rtol=0, atol=1e-12)
    ].iloc[0]
    # 1e-8: the batched and the scalar engine agree to it (tests/test_batch.py); the table
    # holds the batched run, the one-off the scalar one.
    for name in ("robot_stop_time", "tcp_max_displacement", "ssm_distance", "stop_angle"):
        assert row[name] == pytest.approx(one_off.figures.metrics[name], rel=1e-8, abs=1e-10)


def test_stopping_distance_grows_with_the_override_where_the_brakes_hold(swept):
    """S_s grows with F wherever the arm's own motion, not the fall, makes the stop.

    Below 0.1 m/s at F = 0.5 the fall during the brake delay dominates: an arm moving slowly
    upward can travel less at the higher speed (measured at program time 1 s: 12.2 mm at
    F = 0.5, 7.8 mm at F = 1), so those triggers are not compared.
    """
    _, table, _ = swept
    slow = table[table["override"] == 0.5].set_index("program_time")
    fast = table[table["override"] == 1.0].set_index("program_time")
    moving = slow["tcp_speed_at_signal"] >= 0.1  # [m/s]
    holds = slow["holds"].astype(bool) & fast["holds"].astype(bool)
    compared = moving & holds
    assert compared.sum() >= 3
    grows = fast["tcp_max_displacement"] >= slow["tcp_max_displacement"] - 1e-9
    assert grows[compared].all(), pd.concat([slow, fast], axis=1)[compared & ~grows]


def test_the_worst_trigger_is_near_peak_speed(swept):
    """The worst trigger moves the arm at least 80 % of the program's peak joint speed."""
    _, _, summary = swept
    study = load_program_study(PROGRAM, BASE, every=1.0)
    program = study.program
    assert program is not None
    worst = summary["worst_trigger"]["program_time"]
    speed = np.linalg.norm(program.state_at(worst)[1])
    assert speed >= 0.8 * np.linalg.norm(program.v, axis=1).max()


def test_the_override_search_keeps_every_trigger_within(swept):
    out, _, summary = swept
    search = summary["override_search"]
    assert search["bounded"] is True and search["figure"] == "ssm_distance"
    assert 0.5 < search["override"] < 1.0
    assert search["failing"] - search["override"] <= search["tolerance"]
    at = pd.read_csv(out / "program_at_override.csv")
    assert (at["override"] == search["override"]).all()
    assert at["ssm_distance_upper"].max() <= ALLOWED
    assert at["ssm_distance_upper"].max() == pytest.approx(search["worst"])


def test_bisection_finds_a_known_override():
    """A figure of 1.3 F m against 1 m allowed: F = 1/1.3 within the tolerance, never above."""

    def evaluate(trial: ProgramStudy) -> pd.DataFrame:
        f = trial.overrides[0]
        return pd.DataFrame(
            {
                "program_time": [0.0, 1.0],
                "status": ["ok", "ok"],
                "ssm_distance": [0.5 * f, 1.3 * f],
            }
        )

    study = ProgramStudy("p", "p", "", None, {}, {"program_time": [0.0, 1.0]}, None, 0, "x")  # type: ignore[arg-type]
    for tolerance in (0.01, 0.001):
        found = find_override(study, 1.0, evaluate, tolerance=tolerance)
        assert found.override is not None and found.failing is not None
        assert found.override <= 1 / 1.3 < found.failing
        assert found.failing - found.override <= tolerance
        assert found.binding == 1.0 and found.bounded is False
    assert find_override(study, 2.0, evaluate).override == 1.0  # F = 1 passes: one run
    assert find_override(study, 1e-4, evaluate, tolerance=0.1).override is None


def test_triggers_include_the_peak_speed_instants():
    study = load_program_study(PROGRAM, BASE, every=0.5)
    program = study.program
    assert program is not None
    times = [t.time for t in study.triggers]
    assert times == sorted(times) and len(set(times)) == len(times)
    peak_joint = program.peak_joint_speed_time()
    assert any(math.isclose(t, peak_joint, abs_tol=1e-9) for t in times)
    robot = build_scenario(dict(study.base), source="t", base_dir=study.scenario.parent).robot
    peak_tool = program.t[int(np.argmax(tool_speeds(program, robot)))]
    assert any(math.isclose(t, peak_tool, abs_tol=1e-9) for t in times)
    assert make_triggers(program, robot, 100.0)[0].time == program.t[0]


@pytest.mark.parametrize(
    ("extra", "key"),
    [
        (["--override", "1.5"], "--override"),
        (["--override", "0.5", "0.5"], "--override"),
        (["--every", "1e-5"], "--every"),
    ],
)
def test_bad_options_are_one_line(extra, key, tmp_path, capsys):
    out = tmp_path / "o"
    argv = ["program", PROGRAM, "--scenario", BASE, "--out", str(out), *extra]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("vtm-pin: error:") and key in err
    assert not out.exists()


def test_a_base_with_an_annex_b_state_is_refused(tmp_path, capsys):
    assert main(["program", PROGRAM, "--scenario", "ur10_annex_b", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'annex_b'" in err and "program sets the state" in err


def test_a_bad_program_is_one_line_naming_row_and_column(tmp_path, capsys):
    program = load_program_study(PROGRAM, BASE, every=1.0).program
    assert program is not None
    text = Path(program.source).read_text(encoding="utf-8").splitlines()
    data = [i for i, line in enumerate(text) if line and not line.startswith("#")]
    row = text[data[6]].split(",")  # data[0] is the header: this is data row 6
    row[2] = "9.0"  # shoulder_lift_joint far outside its limits
    text[data[6]] = ",".join(row)
    bad = tmp_path / "p.csv"
    bad.write_text("\n".join(text) + "\n", encoding="utf-8")
    assert main(["program", str(bad), "--scenario", BASE, "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "row 6, column shoulder_lift_joint" in err, err
    assert not (tmp_path / "o").exists()


def test_chromium_shows_the_program_page(swept, tmp_path):
    browser = chromium()
    out, table, _ = swept
    page = (out / "program.html").read_text(encoding="utf-8")
    assert "Worst trigger" in page and "Largest override F" in page
    probed = tmp_path / "probed.html"
    probed.write_text(page.replace("</body>", PROBE + "\n</body>"), encoding="utf-8")
    dom = run_chromium(browser, tmp_path, "dom", "--dump-dom", probed.as_uri())
    found = re.search(r'<pre id="probe">(.*?)</pre>', dom)
    assert found is not None, dom[-2000:]
    shown = json.loads(html.unescape(found.group(1)))
    assert shown["images"] == 2  # program.png and swept.png, decoded
    assert shown["rows"] == page.count("<tr>") >= len(table)
    assert shown["tables"] == page.count("<table ")


def test_list_programs_says_where_they_live(capsys):
    assert main(["list", "programs", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["program"] for r in rows] == [PROGRAM]
    assert rows[0]["rows"] == 376 and float(rows[0]["duration [s]"]) == pytest.approx(7.457, 1e-3)
    assert main(["list", "programs"]) == 0
    assert "vtm-pin init program NAME" in capsys.readouterr().out
