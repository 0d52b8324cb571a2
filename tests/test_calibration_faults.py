"""Calibration under faults: every row error names the table file, the row and the column;
a table too long, in the wrong units or of another robot is refused before anything is
fitted; a named pipe or a folder as TABLE is refused at once.

Each test fails before the fit starts (a second or two), except the one that fits a one-row
table to check what --robot-differs writes (a few seconds).
"""

from __future__ import annotations

import csv
import json
import os
import pickle
import subprocess
import sys
from pathlib import Path

import pytest

from vtm_pin.calibration.fit import CalibrationError, check_table
from vtm_pin.calibration.table import (
    COLUMNS,
    MAX_MEAN_SPEED_RATIO,
    MAX_ROWS,
    TableError,
    read_stopping_table,
    robot_matches,
)
from vtm_pin.cli import main
from vtm_pin.exceptions import SimulationError, VtmError
from vtm_pin.physics.robot import ROBOTS_DIR

UR5_TABLE = Path(__file__).resolve().parents[2] / "shared" / "data" / "ur5_cb3_stopping_cat0.csv"
ROBOT = "ur5_cb3"
#: Longest a refused command may take through the real executable [s]: importing vtm_pin and
#: loading the robot take a few seconds; a reader that hangs on a named pipe never returns.
SUBPROCESS_TIMEOUT = 60.0


def ur5_rows() -> list[dict[str, str]]:
    """The rows of UR's published UR5 (CB3) table, as text."""
    with UR5_TABLE.open(newline="") as file:
        return list(csv.DictReader(file))


def write_rows(path: Path, rows: list[dict[str, str]]) -> Path:
    with path.open("w", newline="") as file:
        writer = csv.DictWriter(file, COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    return path


def changed(path: Path, line: int, **cells: str) -> Path:
    """The UR5 table with ``cells`` changed in the row of file line ``line`` (header: 1)."""
    rows = ur5_rows()
    rows[line - 2] |= cells
    return write_rows(path, rows)


def refusal(capsys: pytest.CaptureFixture[str], table: Path, out: Path, *extra: str) -> str:
    """The one error line of ``vtm-pin calibrate TABLE``, checking that nothing is written."""
    code = main(["calibrate", str(table), "--robot", ROBOT, "--out", str(out), *extra])
    err = capsys.readouterr().err
    assert code == 1, err
    assert err.count("\n") == 1 and err.startswith("vtm-pin: error: "), err
    assert not out.exists()
    return err


@pytest.fixture
def no_fit(monkeypatch: pytest.MonkeyPatch) -> list[object]:
    """Stop the CLI where the fit would start; the table it would fit is recorded."""
    reached: list[object] = []

    def stop(args, table, scatter, show):
        reached.append(table)
        raise VtmError("fit reached")

    monkeypatch.setattr("vtm_pin.cli._fit_or_compare", stop)
    return reached


# --- 1. Every error about a row names the file, the row and the column ---------------------


@pytest.mark.parametrize(
    ("line", "cells", "key", "phrase"),
    [
        (2, {"speed_deg_s": "fast"}, "row 2, column speed_deg_s", "is not a number"),
        (3, {"joint": "wrist_9_joint"}, "row 3, column joint", "is not a joint of the robot"),
        (3, {"category": "1"}, "row 3, column category", "category-1 rows need"),
        (3, {"motion": "horizontal"}, "row 3, column motion", "moves the tool vertically"),
        (4, {"extension_pct": "1"}, "row 4, column extension_pct", "cannot be posed"),
    ],
    ids=["reading", "joint", "category", "motion", "extension"],
)
def test_row_errors_name_the_file_row_and_column(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    no_fit: list[object],
    line: int,
    cells: dict[str, str],
    key: str,
    phrase: str,
) -> None:
    table = changed(tmp_path / "table.csv", line, **cells)
    err = refusal(capsys, table, tmp_path / "out")
    assert err.startswith(f"vtm-pin: error: {table}: '{key}': "), err
    assert phrase in err
    assert not no_fit  # refused before the fit


def test_a_row_whose_simulation_fails_during_the_fit_is_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A run that fails in the fit (here: made to chatter) names the file and the row."""

    def chatter(*args, **kwargs):
        raise SimulationError("More than 10000 brake state events by t = 0.1 s (chatter)")

    monkeypatch.setattr("vtm_pin.outputs.pipeline.run", chatter)
    table = write_rows(tmp_path / "table.csv", ur5_rows())
    err = refusal(capsys, table, tmp_path / "out", "--fit", "delay")
    assert err.startswith(f"vtm-pin: error: {table}: 'row 2': simulating it failed at the "), err
    assert "delay 0.05" in err and "(chatter)" in err


def test_row_errors_cross_process_boundaries_whole() -> None:
    """The fits run in worker processes: their errors are pickled back, message intact."""
    for error in (TableError("t.csv", "row 2, column joint", "bad"), CalibrationError("x")):
        again = pickle.loads(pickle.dumps(error))
        assert type(again) is type(error) and str(again) == str(error)


# --- 2. A limit on rows ----------------------------------------------------------------------


def test_a_table_longer_than_max_rows_is_refused_before_the_fit(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], no_fit: list[object]
) -> None:
    row = ur5_rows()[0]
    rows = [row | {"speed_deg_s": f"{10 + k * 0.01:.2f}"} for k in range(MAX_ROWS + 1)]
    table = write_rows(tmp_path / "long.csv", rows)
    err = refusal(capsys, table, tmp_path / "out")
    assert f"{table}: has {MAX_ROWS + 1} rows of stopping data; at most {MAX_ROWS}" in err
    assert not no_fit
    assert len(read_stopping_table(write_rows(tmp_path / "ok.csv", rows[:MAX_ROWS])).rows) == (
        MAX_ROWS
    )


# --- 3. Units: a distance no stop from that speed within that time can travel ----------------


def test_times_in_seconds_are_named_before_the_fit(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], no_fit: list[object]
) -> None:
    rows = [r | {"stop_time_ms": f"{float(r['stop_time_ms']) / 1e3:g}"} for r in ur5_rows()]
    table = write_rows(tmp_path / "seconds.csv", rows)
    err = refusal(capsys, table, tmp_path / "out")
    assert err.startswith(f"vtm-pin: error: {table}: 'row 2, column stop_time_ms': "), err
    assert "the times look like seconds" in err and "write milliseconds" in err
    assert "chatter" not in err and not no_fit


def test_speeds_in_rad_s_are_named_before_the_fit(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], no_fit: list[object]
) -> None:
    rows = [r | {"speed_deg_s": "3.194"} for r in ur5_rows()]  # 183 deg/s in rad/s
    table = write_rows(tmp_path / "rad_s.csv", rows)
    err = refusal(capsys, table, tmp_path / "out")
    assert err.startswith(f"vtm-pin: error: {table}: 'row 2, column speed_deg_s': "), err
    assert "the speed looks like rad/s" in err and "write deg/s" in err
    assert not no_fit


def test_a_distance_no_unit_mistake_explains_is_refused_too(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], no_fit: list[object]
) -> None:
    # 183 deg/s x 0.164 s = 0.52 rad: 90 rad is beyond any unit mistake the message names.
    table = changed(tmp_path / "far.csv", 4, stop_distance_rad="90")
    err = refusal(capsys, table, tmp_path / "out")
    assert f"{table}: 'row 4, column stop_distance_rad': stop_distance_rad 90 rad" in err
    assert "check the units" in err


def test_the_published_ur5_table_passes_every_check(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], no_fit: list[object]
) -> None:
    table = read_stopping_table(UR5_TABLE)
    # Its distances are 0.40-0.42 x speed x time: a delay, then braking.
    for row in table.rows:
        assert 0.3 < row.stop_distance / (row.speed * row.stop_time) < MAX_MEAN_SPEED_RATIO
    assert check_table(table, ROBOT) == table
    assert check_table(table, str(ROBOTS_DIR / f"{ROBOT}.urdf")) == table  # by its file name
    assert main(["calibrate", str(UR5_TABLE), "--robot", ROBOT, "--out", str(tmp_path)]) == 1
    assert capsys.readouterr().err == "vtm-pin: error: fit reached\n"
    assert no_fit == [table]


# --- 4. The table's robot against --robot -----------------------------------------------------


@pytest.mark.parametrize(
    ("table_robot", "names", "same"),
    [
        ("UR5/CB3", ["ur5_cb3"], True),
        ("UR5/CB3", ["ur5"], True),
        ("UR 5", ["ur5"], True),
        ("KUKA KR 16", ["kr16"], True),
        ("Franka Emika Panda", ["panda"], True),
        ("UR5/CB3", ["ur10"], False),
        ("UR5e", ["ur5"], False),
        ("UR5/CB3", ["ur3"], False),
        ("UR5/CB3", ["my_arm", "ur5_cb3"], True),  # a URDF's file name, then <robot name>
        ("///", ["ur5"], False),
    ],
)
def test_robot_names_match_by_their_letters_and_digits(
    table_robot: str, names: list[str], same: bool
) -> None:
    assert robot_matches(table_robot, names) is same


def test_another_robots_table_is_refused_with_a_way_out(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], no_fit: list[object]
) -> None:
    out = tmp_path / "out"
    assert main(["calibrate", str(UR5_TABLE), "--robot", "ur10", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and not out.exists() and not no_fit
    assert err.startswith(f"vtm-pin: error: {UR5_TABLE}: 'row 2, column robot': "), err
    assert "the table is for 'UR5/CB3', not --robot ur10" in err and "--robot-differs" in err


def test_robot_differs_fits_on_purpose_and_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A one-row table measured on a UR10, fitted to ur3 on purpose (one figure: seconds)."""
    row = "UR10,0,elbow_joint,J2,180,1,100,down,100,0.1,doc p. 1"
    table = write_rows(
        tmp_path / "ur10.csv",
        [dict(zip(COLUMNS, row.split(","), strict=True))],
    )
    out = tmp_path / "out"
    command = ["calibrate", str(table), "--robot", "ur3", "--fit", "delay", "--out", str(out)]
    assert main(command) == 1
    assert "--robot-differs" in capsys.readouterr().err and not out.exists()
    assert main([*command, "--robot-differs", "--quiet"]) == 0
    note = "doc p. 1 [measured on UR10; fitted to ur3 by --robot-differs]"
    summary = json.loads((out / "calibration.json").read_text())
    assert summary["sources"] == [note]
    fragment = (out / "calibrated.yaml").read_text()
    assert f"fitted to {note}" in fragment


# --- 5. A named pipe or a folder as TABLE -----------------------------------------------------


def test_a_folder_as_table_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    err = refusal(capsys, tmp_path, tmp_path / "out")
    assert f"{tmp_path}: is a folder, not a regular file" in err


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes need POSIX")
def test_a_named_pipe_as_table_is_refused_without_hanging(tmp_path: Path) -> None:
    fifo = tmp_path / "table.csv"
    os.mkfifo(fifo)
    out = tmp_path / "out"
    root = str(Path(__file__).resolve().parents[1])  # this checkout's vtm_pin
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")])),
    }
    done = subprocess.run(
        [sys.executable, "-m", "vtm_pin", "calibrate", str(fifo), "--robot", ROBOT, "--out", out],
        capture_output=True,
        text=True,
        timeout=SUBPROCESS_TIMEOUT,  # a reader blocked on the pipe fails here
        env=env,
        check=False,
    )
    assert done.returncode == 1, done.stderr
    assert done.stderr == (
        f"vtm-pin: error: {fifo}: is a named pipe (FIFO), not a regular file; give a file\n"
    )
    assert not out.exists()
