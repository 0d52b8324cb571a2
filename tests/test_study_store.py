"""A study's output folder under faults, races and mistakes: its lock, its checked case store,
its staging folders, Ctrl-C, and the command-line mistakes it refuses.

Every test drives the command line (``main([...])`` or the real executable) and checks the exit
code, the one line on stderr, and what is left on disk.
"""

from __future__ import annotations

import errno
import json
import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pandas as pd
import pytest
import yaml

from vtm_pin import cli
from vtm_pin.cli import main
from vtm_pin.files.staging import _staging_prefix
from vtm_pin.study.cases import load_study
from vtm_pin.study.runner import run_study
from vtm_pin.study.store import (
    CASES_FOLDER,
    RECORDS_SUFFIX,
    STATE_FILE,
    check_record,
    count_stored,
    seal,
)

#: Columns that depend on the machine, not on the physics.
TIMING = ["wall_time"]


def write_study(folder: Path, vary: dict, name: str = "study.yaml", **extra: object) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text(
        yaml.safe_dump({"scenario": "ur10_annex_b", "vary": vary, **extra}, sort_keys=False)
    )
    return path


#: Three cases of the UR10 Annex-B base, shortened to 0.9 s (each stops well within it).
SMALL = {"joint": ["shoulder_lift_joint", "elbow_joint", "wrist_1_joint"], "duration": [0.9]}


def physics(table: pd.DataFrame) -> pd.DataFrame:
    return table.drop(columns=TIMING).sort_values("case").reset_index(drop=True)


def one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    errors = [line for line in lines if line.startswith("vtm-pin: error:")]
    assert len(errors) == 1, err
    assert "Traceback" not in err
    return errors[0]


@pytest.fixture(scope="module")
def clean(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, pd.DataFrame]:
    """The small study run once, untouched: its study file and table."""
    folder = tmp_path_factory.mktemp("clean")
    path = write_study(folder, SMALL)
    return path, run_study(load_study(path), folder / "out", workers=1).table


@pytest.fixture
def finished(clean: tuple[Path, pd.DataFrame], tmp_path: Path) -> tuple[Path, Path]:
    """A finished copy of the small study in ``tmp_path``: (study file, output folder)."""
    path = write_study(tmp_path, SMALL)
    out = tmp_path / "out"
    assert main(["study", str(path), "--out", str(out), "--workers", "1", "--quiet"]) == 0
    return path, out


def rerun(path: Path, out: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    code = main(["study", str(path), "--out", str(out), "--workers", "1", "--json"])
    captured = capsys.readouterr()
    return code, captured.err if code else captured.err + captured.out


# -- the case store is checked, not trusted ---------------------------------------------------


def stored_lines(out: Path) -> dict[str, tuple[Path, int, dict]]:
    """Case id -> (its file, its line's index, its record), over the store's files."""
    found = {}
    for path in sorted((out / CASES_FOLDER).glob(f"*{RECORDS_SUFFIX}")):
        for number, line in enumerate(path.read_text().splitlines()):
            record = json.loads(line)
            assert record["case"] not in found, f"case {record['case']} stored twice"
            found[record["case"]] = (path, number, record)
    return found


def replace_line(out: Path, case: str, text: str) -> None:
    """Put ``text`` (one line) in place of case ``case``'s stored line."""
    path, number, _ = stored_lines(out)[case]
    lines = path.read_text().splitlines(keepends=True)
    lines[number] = text if text.endswith("\n") else text + "\n"
    path.write_text("".join(lines))


def test_a_stored_record_carries_its_case_and_a_checksum(finished: tuple[Path, Path]) -> None:
    path, out = finished
    study = load_study(path)
    lines = stored_lines(out)
    assert sorted(lines) == sorted(case.id for case in study.cases())
    for case in study.cases():
        record = lines[case.id][2]
        assert record["case"] == case.id and len(record["checksum"]) == 64
        assert check_record(record, case, study.fingerprint) is None
        # the same case of another study (its base differs): not this study's record
        assert "another study" in str(check_record(record, case, "0" * 64))
        record["metrics"]["robot_stop_time"] = 0.001  # a changed figure: the checksum fails
        assert "checksum" in str(check_record(record, case, study.fingerprint))


def test_cases_finished_together_are_stored_in_one_file(tmp_path: Path) -> None:
    """A batch's records go into one file a group of finished cases, not one file a case: the
    small study's three cases, one batch on one worker, give one file of three lines."""
    from vtm_pin.study.runner import CaseTask, run_cases

    study = load_study(write_study(tmp_path, SMALL))
    out = tmp_path / "out"
    (out / CASES_FOLDER).mkdir(parents=True)
    folder, source = str(study.scenario.parent), str(study.scenario)
    tasks = [
        CaseTask(study.base, folder, source, study.scenario.stem, case, study.fingerprint)
        for case in study.cases()
    ]
    records = run_cases(tasks, engine="batched", store=str(out))
    lines = stored_lines(out)
    assert sorted(lines) == sorted(r["case"] for r in records)
    assert len({p for p, _, _ in lines.values()}) == 1
    assert all(p.name.startswith(f"{records[0]['case']}-") for p, _, _ in lines.values())
    for record in records:  # the stored record is the one returned, but for the write's time
        assert record["timing"]["write"] > 0
        stored = lines[record["case"]][2]["timing"]
        assert stored == {k: v for k, v in record["timing"].items() if k != "write"}


def test_a_sealed_line_is_its_record_and_its_checksum_covers_the_rest() -> None:
    """The stored line parses back to the record, keys in order (the table's columns follow
    them); its checksum is the other keys' compact JSON, which a record read back gives again."""
    import hashlib

    record = {"case": "c1", "values": {"b": 1.5, "a": [1, None]}, "metrics": {"t": 0.1 + 0.2}}
    line = seal(record)
    assert line.endswith("\n") and line.count("\n") == 1
    back = json.loads(line)
    assert back == record and list(back) == list(record) and list(back["values"]) == ["b", "a"]
    body = json.dumps({k: v for k, v in back.items() if k != "checksum"}, separators=(",", ":"))
    assert record["checksum"] == hashlib.sha256(body.encode()).hexdigest()
    assert seal(back) == line  # read back and sealed again: the same line
    assert json.loads(seal({})) == {"checksum": hashlib.sha256(b"{}").hexdigest()}
    with pytest.raises(ValueError):
        seal({"case": "c1", "metrics": {"t": float("nan")}})


def _foreign_case(out: Path, cases: list[str]) -> str:
    record = stored_lines(out)[cases[0]][2]
    record["case"] = "c-not-in-the-study"
    replace_line(out, cases[0], seal(record))  # a whole record, but of no case of this study
    return "not one of this study's"


def _nan_metric(out: Path, cases: list[str]) -> str:
    record = stored_lines(out)[cases[0]][2]
    record["metrics"]["robot_stop_time"] = float("nan")
    replace_line(out, cases[0], json.dumps(record))  # json writes NaN: what a hand edit could leave
    return "NaN"


def _changed_value(out: Path, cases: list[str]) -> str:
    record = stored_lines(out)[cases[0]][2]
    record["values"]["duration"] = 5.0
    replace_line(out, cases[0], seal(record))  # a fresh checksum, but not the case's values
    return "axis values"


def _wrong_shape(out: Path, cases: list[str]) -> str:
    replace_line(out, cases[0], "[1, 2, 3]")
    return "not a record"


def _not_json(out: Path, cases: list[str]) -> str:
    replace_line(out, cases[0], '{"case": "x",')
    return "cannot be read"


def _not_utf8(out: Path, cases: list[str]) -> str:
    path = stored_lines(out)[cases[0]][0]
    path.write_bytes(path.read_bytes() + b"\xff\n")
    return "not UTF-8"


@pytest.mark.parametrize(
    "damage", [_foreign_case, _nan_metric, _changed_value, _wrong_shape, _not_json, _not_utf8]
)
def test_a_damaged_record_is_computed_again_and_said_so_once(
    damage: object,
    finished: tuple[Path, Path],
    clean: tuple[Path, pd.DataFrame],
    capsys: pytest.CaptureFixture[str],
) -> None:
    path, out = finished
    cases = [case.id for case in load_study(path).cases()]
    reason = damage(out, cases)  # type: ignore[operator]
    code, err = rerun(path, out, capsys)
    assert code == 0, err
    warning = [line for line in err.splitlines() if line.startswith("vtm-pin: warning:")]
    assert len(warning) == 1 and "not kept, computed again" in warning[0], err
    assert str(out / CASES_FOLDER) in warning[0] and reason in warning[0], warning[0]
    table = pd.read_parquet(out / "results.parquet")
    assert table["case"].is_unique and len(table) == len(cases)
    pd.testing.assert_frame_equal(physics(table), physics(clean[1]))
    study = load_study(path)
    lines = stored_lines(out)  # every line is a record again, each case's once
    assert sorted(lines) == sorted(cases) and count_stored(out) == len(cases)
    for case in study.cases():
        assert check_record(lines[case.id][2], case, study.fingerprint) is None
    files = sorted(p.name for p in (out / CASES_FOLDER).iterdir())
    code, err = rerun(path, out, capsys)  # the damaged line went with its warning
    assert code == 0 and "vtm-pin: warning" not in err, err
    assert sorted(p.name for p in (out / CASES_FOLDER).iterdir()) == files  # nothing computed


def test_records_without_a_study_file_are_a_changed_study(
    finished: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    path, out = finished
    (out / STATE_FILE).unlink()
    before = sorted(p.name for p in (out / CASES_FOLDER).iterdir())
    code, err = rerun(path, out, capsys)
    line = one_error_line(err)
    assert code == 1 and STATE_FILE in line and "holds case records" in line
    assert sorted(p.name for p in (out / CASES_FOLDER).iterdir()) == before
    assert not (out / STATE_FILE).exists()


@pytest.mark.parametrize("text", ['{"fingerprint": ', "[1, 2]\n", '{"study": "x"}\n'])
def test_a_damaged_study_file_is_named_and_said_to_be_read(
    text: str, finished: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    path, out = finished
    (out / STATE_FILE).write_text(text)
    code, err = rerun(path, out, capsys)
    line = one_error_line(err)
    assert code == 1 and str(out / STATE_FILE) in line
    assert "cannot read" in line or "damaged" in line
    assert "Cannot write" not in line
    assert (out / STATE_FILE).read_text() == text


def test_a_full_disk_names_the_file_it_could_not_write(
    clean: tuple[Path, pd.DataFrame],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from vtm_pin.files import staging

    def full(*args: object, **kwargs: object) -> object:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    path = write_study(tmp_path, SMALL)
    out = tmp_path / "out"
    monkeypatch.setattr(staging, "_create", full)
    code, err = rerun(path, out, capsys)
    line = one_error_line(err)
    assert code == 1 and "No space left on device" in line and str(out) in line
    assert "study.json" in line  # the first file it writes


# -- the output folder belongs to one run at a time -------------------------------------------

#: A driver that imports vtm_pin, waits at a file barrier for its twin, then runs the
#: study into a fresh folder, 20 times; it prints its exit codes as JSON.
RACER = textwrap.dedent(
    """
    import json, sys, time
    from pathlib import Path
    from vtm_pin.cli import main
    me, other, study, root = sys.argv[1:5]
    codes = []
    for i in range(20):
        Path(root, f"ready-{i}-{me}").touch()
        while not Path(root, f"ready-{i}-{other}").exists():
            time.sleep(0.0005)
        out = str(Path(root, f"out-{i}"))
        codes.append(main(["study", study, "--out", out, "--workers", "1", "--quiet"]))
    print(json.dumps(codes))
    """
)


@pytest.mark.slow  # ~15-40 s: two racing studies, repeated
def test_two_studies_started_at_once_into_one_folder_never_both_succeed(tmp_path: Path) -> None:
    """20 races: the lock lets one study have the folder; the other gets one line, exit 1."""
    a = write_study(tmp_path / "a", {"joint": ["elbow_joint"], "duration": [0.3]})
    b = write_study(tmp_path / "b", {"joint": ["elbow_joint"], "duration": [0.31]})
    racer = tmp_path / "racer.py"
    racer.write_text(RACER)
    runs = [
        subprocess.Popen(
            [sys.executable, str(racer), me, other, str(study), str(tmp_path)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for me, other, study in (("a", "b", a), ("b", "a", b))
    ]
    outputs = [run.communicate(timeout=600) for run in runs]
    codes = [json.loads(out) for out, _ in outputs]
    errors = outputs[0][1] + outputs[1][1]
    assert "Traceback" not in errors
    fingerprints = {"a": load_study(a).fingerprint, "b": load_study(b).fingerprint}
    for i, (code_a, code_b) in enumerate(zip(*codes, strict=True)):
        assert (code_a, code_b) != (0, 0), f"race {i}: both studies exit 0"
        assert 0 in (code_a, code_b), f"race {i}: neither study ran ({errors})"
        winner = "a" if code_a == 0 else "b"
        state = json.loads((tmp_path / f"out-{i}" / STATE_FILE).read_text())
        assert state["fingerprint"] == fingerprints[winner]  # its results, not mixed
        table = pd.read_parquet(tmp_path / f"out-{i}" / "results.parquet")
        assert list(table["duration"]) == [0.3 if winner == "a" else 0.31]
    refusals = [line for line in errors.splitlines() if line.startswith("vtm-pin: error:")]
    assert all(
        "being written by another vtm-pin run" in line or "different study" in line
        for line in refusals
    ), refusals


def test_a_held_folder_is_refused_and_left_as_it_is(
    finished: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    fcntl = pytest.importorskip("fcntl")
    path, out = finished
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    fd = os.open(out, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)  # what another run holds
        code, err = rerun(path, out, capsys)
        assert main(["run", "pendulum3r", "--out", str(out), "--quiet", "--no-plots"]) == 1
        run_err = capsys.readouterr().err
    finally:
        os.close(fd)
    line = one_error_line(err)
    assert code == 1 and "being written by another vtm-pin run" in line and str(out) in line
    assert "being written by another vtm-pin run" in one_error_line(run_err)
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before


def test_a_run_that_writes_nothing_leaves_no_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A study refused before it runs (a scheduler it cannot use) leaves no folder."""
    path = write_study(tmp_path, {"joint": ["elbow_joint"], "duration": [0.3]})
    out = tmp_path / "never"
    code = main(["study", str(path), "--out", str(out), "--scheduler", "inproc://x:1"])
    one_error_line(capsys.readouterr().err)
    assert code == 1 and not out.exists()


def test_a_refused_run_never_removes_the_folder_another_holds(tmp_path: Path) -> None:
    """The loser of a race for a new folder must leave the winner's (still empty) folder."""
    from vtm_pin.exceptions import OutputError
    from vtm_pin.files.staging import output_lock

    fcntl = pytest.importorskip("fcntl")
    out = tmp_path / "new"
    out.mkdir()  # made by the winner, nothing in it yet
    fd = os.open(out, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        with pytest.raises(OutputError, match="being written by another"), output_lock(out):
            pass
        assert out.is_dir()
    finally:
        os.close(fd)
    with output_lock(tmp_path / "mine"):  # a folder this run made and left empty: removed
        assert (tmp_path / "mine").is_dir()
    assert not (tmp_path / "mine").exists()


# -- staging folders of killed runs are cleaned up --------------------------------------------


@pytest.mark.slow  # ~10 s: a killed run
def test_a_staging_folder_left_by_a_killed_run_is_removed_by_the_next(tmp_path: Path) -> None:
    path = write_study(tmp_path, SMALL)
    out = tmp_path / "out"
    command = [sys.executable, "-m", "vtm_pin", "study", str(path), "--out", str(out)]
    process = subprocess.Popen([*command, "--workers", "1", "--quiet"])
    prefix = _staging_prefix(out)
    deadline = time.monotonic() + 180.0
    staged: list[Path] = []
    while not staged and time.monotonic() < deadline:  # the outputs are being written
        assert process.poll() is None, "the study ended before its staging folder was seen"
        staged = list(tmp_path.glob(f"{prefix}*"))
        time.sleep(0.001)
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    assert staged and all(p.exists() for p in staged)  # what a SIGKILL leaves
    again = subprocess.run([*command, "--workers", "1", "--quiet"], capture_output=True)
    assert again.returncode == 0, again.stderr
    assert not list(tmp_path.glob(f"{prefix}*"))
    assert (out / "results.parquet").is_file()


# -- Ctrl-C is prompt and keeps what is finished ----------------------------------------------

#: 12 cases of the UR10 Annex-B base: batches of 3 on one worker with the batched engine.
INTERRUPTED = {
    "joint": ["shoulder_lift_joint", "elbow_joint", "wrist_1_joint"],
    "speed": [0.25, 0.5, 0.75, 1.0],
    "duration": [0.9],
}


@pytest.fixture(scope="module")
def interrupted_clean(tmp_path_factory: pytest.TempPathFactory) -> pd.DataFrame:
    folder = tmp_path_factory.mktemp("interrupted")
    path = write_study(folder, INTERRUPTED)
    return run_study(load_study(path), folder / "out", workers=1).table


@pytest.mark.parametrize(
    ("seed", "workers"),
    [(1, 1), pytest.param(2, 2, marks=pytest.mark.slow)],  # (2, 2): ~20 s
)
def test_ctrl_c_at_a_random_time_exits_promptly_and_keeps_finished_cases(
    seed: int, workers: int, interrupted_clean: pd.DataFrame, tmp_path: Path
) -> None:
    """SIGINT at a random instant after the first stored case: exit within 5 s (the promise),
    every record stored before the signal still there, unchanged, and not computed again."""
    path = write_study(tmp_path, INTERRUPTED)
    out = tmp_path / "out"
    command = [sys.executable, "-m", "vtm_pin", "study", str(path), "--out", str(out)]
    process = subprocess.Popen(
        [*command, "--workers", str(workers), "--quiet"],
        stderr=subprocess.PIPE,
        text=True,
    )
    cases = out / CASES_FOLDER
    deadline = time.monotonic() + 180.0
    while not count_stored(out) and time.monotonic() < deadline:
        assert process.poll() is None, "the study ended before the first case was stored"
        time.sleep(0.005)
    time.sleep(random.Random(seed).uniform(0.0, 0.3))  # the rest and the outputs take longer
    before = {p.name: p.read_bytes() for p in cases.glob(f"*{RECORDS_SUFFIX}")}
    signalled = time.monotonic()
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=60)
    took = time.monotonic() - signalled
    assert process.returncode == 130 and took < 5.0, (process.returncode, took, err)
    assert err.count("\n") == 1 and "interrupted" in err and "Traceback" not in err
    for name, data in before.items():
        assert (cases / name).read_bytes() == data
    assert not (out / "results.parquet").exists()
    stored = count_stored(out)
    again = subprocess.run(
        [*command, "--workers", "1", "--json"], capture_output=True, text=True, timeout=300
    )
    assert again.returncode == 0, again.stderr
    summary = json.loads(again.stdout)
    computed = summary["counts"]["cases"] - stored
    assert computed == len(interrupted_clean) - stored
    table = pd.read_parquet(out / "results.parquet")
    pd.testing.assert_frame_equal(physics(table), physics(interrupted_clean))


# -- command-line mistakes ------------------------------------------------------------------


def test_an_empty_out_or_scheduler_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    path = write_study(tmp_path / "s", {"joint": ["elbow_joint"], "duration": [0.3]})
    assert main(["study", str(path), "--out", ""]) == 2
    assert "empty name is not a folder" in capsys.readouterr().err
    assert main(["run", "pendulum3r", "--out", " "]) == 2
    assert "empty name is not a folder" in capsys.readouterr().err
    assert main(["study", str(path), "--out", "o", "--scheduler", ""]) == 1
    assert "--scheduler" in one_error_line(capsys.readouterr().err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s"]


def test_a_large_study_needs_yes_in_a_script(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(cli, "CONFIRM_CASES", 2)
    path = write_study(tmp_path, SMALL)
    out = tmp_path / "out"
    assert main(["study", str(path), "--out", str(out)]) == 1
    line = one_error_line(capsys.readouterr().err)
    assert "3 cases, more than 2" in line and "--yes" in line and str(path) in line
    assert not out.exists()
    assert main(["study", str(path), "--out", str(out), "--yes", "--quiet", "--workers", "1"]) == 0


def test_a_record_is_written_whole_through_a_temporary_file_of_its_own(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The atomic write: the file has its whole text and the mode a new file gets (0o666 less
    the umask); a temporary name left by a killed process of the same id is skipped, not
    overwritten; a failed rename leaves no temporary file."""
    import itertools

    from vtm_pin.files import staging

    path = tmp_path / "c1.json"
    old = os.umask(0o027)
    try:
        staging.write_atomic(path, '{"a": 1}\n')
    finally:
        os.umask(old)
    assert path.read_text() == '{"a": 1}\n'
    assert path.stat().st_mode & 0o777 == 0o640
    assert [p.name for p in tmp_path.iterdir()] == ["c1.json"]
    monkeypatch.setattr(staging, "_TEMPORARY", itertools.count(5))
    leftover = tmp_path / f".c1.json.{os.getpid()}.5"
    leftover.write_text("partial")
    staging.write_atomic(path, '{"a": 2}\n')
    assert path.read_text() == '{"a": 2}\n' and leftover.read_text() == "partial"

    def broken(*args: object) -> None:
        raise OSError(errno.EIO, os.strerror(errno.EIO))

    monkeypatch.setattr(staging.os, "replace", broken)
    with pytest.raises(OSError):
        staging.write_atomic(path, '{"a": 3}\n')
    assert sorted(p.name for p in tmp_path.iterdir()) == [leftover.name, "c1.json"]
    assert path.read_text() == '{"a": 2}\n'
