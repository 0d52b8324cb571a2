"""Studies: study files, cases, running them (in process, on a pool, resumed), their outputs."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import UR_JOINTS
from hypothesis import given, settings
from hypothesis import strategies as st

import vtm_pin as vp
from vtm_pin.cli import main
from vtm_pin.exceptions import StudyError
from vtm_pin.scene.scenario import SCENARIOS_DIR
from vtm_pin.study.cases import NAMED_AXES, find_study, load_study, resolve_case
from vtm_pin.study.runner import run_study
from vtm_pin.study.store import count_stored

#: Columns that depend on the machine, not on the physics.
TIMING = ["wall_time"]


def write_study(folder: Path, vary: dict, **extra: object) -> Path:
    path = folder / "study.yaml"
    path.write_text(
        yaml.safe_dump({"scenario": "ur10_annex_b", "vary": vary, **extra}, sort_keys=False)
    )
    return path


#: A small grid: 4 cases of the UR10 Annex-B base, shortened to 0.9 s.
SMALL = {
    "joint": ["shoulder_lift_joint", "elbow_joint"],
    "speed": [0.5, 1.0],
    "duration": [0.9],
}
#: SMALL, and a stop 1 s after the start of those 0.9 s runs: 8 cases, 4 of which fail when
#: they run (each value is valid alone, so the study file passes its checks).
FAILING = {**SMALL, "stop.t": [0.0, 1.0]}


def physics(table: pd.DataFrame) -> pd.DataFrame:
    return table.drop(columns=TIMING).sort_values("case").reset_index(drop=True)


# -- study files and cases ------------------------------------------------------------------


def test_grid_is_the_full_product_in_file_order(tmp_path: Path) -> None:
    joints = ["shoulder_lift_joint", "elbow_joint"]
    study = load_study(write_study(tmp_path, {"joint": joints, "speed": [0.1, 0.2, 0.3]}))
    cases = study.cases()
    assert study.mode == "grid"
    assert [tuple(c.values.values()) for c in cases] == [
        (j, s) for j in joints for s in (0.1, 0.2, 0.3)
    ]
    assert len({c.id for c in cases}) == 6
    # the id is derived from the values only: the same values give the same id in another file
    again = load_study(write_study(tmp_path, {"joint": ["elbow_joint"], "speed": [0.2]}))
    assert again.cases()[0].id == cases[4].id


def test_sampled_study_draws_ranges_and_lists(tmp_path: Path) -> None:
    vary = {"speed": {"min": 0.3, "max": 1.0}, "joint": list(UR_JOINTS[:3])}
    study = load_study(write_study(tmp_path, vary, samples=64, seed=3))
    cases = study.cases()
    speeds = np.array([c.values["speed"] for c in cases])
    assert len(cases) == 64
    assert np.all((speeds >= 0.3) & (speeds <= 1.0))
    # quasi-random: 64 Halton points fill [0.3, 1] evenly, each eighth of it gets 8 +- 2
    counts, _ = np.histogram(speeds, bins=8, range=(0.3, 1.0))
    assert counts.min() >= 6 and counts.max() <= 10
    assert {c.values["joint"] for c in cases} == set(UR_JOINTS[:3])
    assert [c.id for c in load_study(write_study(tmp_path, vary, samples=64, seed=3)).cases()] == [
        c.id for c in cases
    ]
    other = load_study(write_study(tmp_path, vary, samples=64, seed=4)).cases()
    assert [c.values["speed"] for c in other] != list(speeds)


@pytest.mark.parametrize(
    ("vary", "extra", "key", "phrase"),
    [
        ({"spede": [1.0]}, {}, "vary.spede", "not a named axis"),
        ({"speed": {"min": 0.1, "max": 0.2}}, {}, "vary.speed", "needs samples"),
        ({"speed": {"min": 0.3, "max": 0.2}}, {"samples": 4}, "vary.speed", "min must be <= max"),
        ({"failed_brake": ["wrist_9"]}, {}, "vary.failed_brake", "has no brake"),
        ({"brakes.wrist_9.delay": [0.1]}, {}, "vary.brakes.wrist_9.delay", "no brake on"),
        ({"speed": []}, {}, "vary.speed", ""),
        ({}, {}, "vary", ""),
    ],
)
def test_bad_study_files_are_refused_naming_the_key(
    tmp_path: Path, vary: dict, extra: dict, key: str, phrase: str
) -> None:
    with pytest.raises(StudyError) as info:
        load_study(write_study(tmp_path, vary, **extra))
    assert info.value.key == key
    assert phrase in info.value.problem


def test_missing_base_scenario_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "s.yaml"
    path.write_text("scenario: no_such.yaml\nvary: {speed: [1.0]}\n")
    with pytest.raises(StudyError) as info:
        load_study(path)
    assert info.value.key == "scenario"


def test_resolve_sets_named_axes_and_key_paths_without_touching_the_base(tmp_path: Path) -> None:
    study = load_study(write_study(tmp_path, {"speed": [1.0]}))
    base = json.loads(json.dumps(study.base))
    values = {
        "joint": "elbow_joint",
        "speed": 0.5,
        "extension": 0.66,
        "payload": 2.5,
        "category": 1,
        "brake_scale": 0.5,
        "failed_brake": "elbow_joint",
        "brakes.*.delay": 0.1,
        "stop.t": 0.2,
    }
    raw = resolve_case(study.base, values)
    assert raw["annex_b"] == {
        **base["annex_b"],
        "joint": "elbow_joint",
        "speed": 0.5,
        "extension": 0.66,
    }
    assert raw["payload"]["mass"] == 2.5 and raw["payload"]["com"] == base["payload"]["com"]
    assert raw["stop"]["category"] == 1 and raw["stop"]["t"] == 0.2
    assert raw["brakes"]["elbow_joint"] is None  # no brake, not even the robot data's
    lift, base_lift = raw["brakes"]["shoulder_lift_joint"], base["brakes"]["shoulder_lift_joint"]
    assert lift["sliding_torque"] == 0.5 * base_lift["sliding_torque"]
    assert lift["static_torque"] == 0.5 * base_lift["static_torque"]
    assert {b["delay"] for b in raw["brakes"].values() if b is not None} == {0.1}
    assert json.loads(json.dumps(study.base)) == base  # the base is not modified
    assert set(NAMED_AXES) >= {"joint", "speed", "payload", "extension", "category"}


def test_shipped_studies_load() -> None:
    grid = load_study(find_study("ur10_annex_b"))
    assert grid.mode == "grid" and len(grid.cases()) == 162
    sampled = load_study(find_study("ur10_brake_wear"))
    assert sampled.mode == "sampled" and len(sampled.cases()) == 200
    with pytest.raises(StudyError, match="ur10_annex_b"):
        find_study("no_such_study")


# -- running ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, pd.DataFrame]:
    folder = tmp_path_factory.mktemp("study")
    out = folder / "out"
    output = run_study(load_study(write_study(folder, FAILING)), out, workers=1)
    return out, output.table


def test_a_study_writes_its_table_summary_and_report(small_run: tuple[Path, pd.DataFrame]) -> None:
    out, table = small_run
    assert {"results.parquet", "results.csv", "summary.json", "report.html"} <= {
        p.name for p in out.iterdir()
    }
    assert len(table) == 8 and table["case"].is_unique
    assert list(table.columns[:6]) == ["case", "joint", "speed", "duration", "stop.t", "status"]
    pd.testing.assert_frame_equal(pd.read_parquet(out / "results.parquet"), table)
    csv = pd.read_csv(out / "results.csv")
    assert list(csv.columns) == list(table.columns) and len(csv) == len(table)
    ok = table[table["status"] == "ok"]
    assert len(ok) == 4
    # a faster start stops later and farther, for both joints
    for _, rows in ok.groupby("joint"):
        rows = rows.sort_values("speed")
        assert rows["stop_angle"].is_monotonic_increasing
        assert rows["robot_stop_time"].is_monotonic_increasing
    assert np.all(ok["tcp_path"] >= ok["tcp_distance"] - 1e-12)  # a path is never shorter
    assert np.allclose(
        ok["test_speed"], ok["speed"] * np.where(ok["joint"] == "elbow_joint", 3.15, 2.16)
    )
    summary = json.loads((out / "summary.json").read_text())
    assert summary["counts"] == {
        "cases": 8,
        "ok": 4,
        "not_stopped": 0,
        "error": 4,
        "cannot_hold": 0,
        "flagged": 0,
    }
    assert summary["study"]["mode"] == "grid" and "pin" in summary["versions"]
    assert any("ASSUMED drives" in line for line in summary["assumptions"])  # robot data


def test_a_failed_case_is_recorded_with_its_message(small_run: tuple[Path, pd.DataFrame]) -> None:
    _, table = small_run
    failed = table[table["stop.t"] == 1.0]
    assert len(failed) == 4
    for status in failed["status"]:
        assert status.startswith("error: ") and "'stop.t': 1.0 s is after the end" in status
        assert "\n" not in status
    assert failed["robot_stop_time"].isna().all()


def test_a_finished_study_run_again_computes_nothing(
    small_run: tuple[Path, pd.DataFrame], tmp_path: Path
) -> None:
    out, table = small_run
    study = load_study(out.parent / "study.yaml")
    again = run_study(study, out, workers=1)
    assert again.computed == 0
    pd.testing.assert_frame_equal(again.table, table)


def test_a_changed_study_is_refused(small_run: tuple[Path, pd.DataFrame]) -> None:
    out, _ = small_run
    (out.parent / "changed").mkdir()
    changed = write_study(out.parent / "changed", {**SMALL, "speed": [0.4]})
    with pytest.raises(StudyError, match=r"different study.*delete that folder"):
        run_study(load_study(changed), out, workers=1)


def test_a_process_pool_gives_the_same_table(
    small_run: tuple[Path, pd.DataFrame], tmp_path: Path
) -> None:
    _, table = small_run
    pooled = run_study(load_study(write_study(tmp_path, FAILING)), tmp_path / "out", workers=2)
    assert pooled.computed == 8
    pd.testing.assert_frame_equal(physics(pooled.table), physics(table))


@pytest.mark.slow  # ~10 s: a killed study resumed
def test_resume_after_sigkill_equals_a_clean_run(
    small_run: tuple[Path, pd.DataFrame], tmp_path: Path
) -> None:
    _, table = small_run
    path = write_study(tmp_path, FAILING)
    out = tmp_path / "out"
    command = [sys.executable, "-m", "vtm_pin", "study", str(path), "--out", str(out)]
    # The scalar engine stores case by case (the batched one a batch at a time); the
    # re-run takes the default, batched engine: the two engines' records mix in one table.
    process = subprocess.Popen([*command, "--workers", "1", "--engine", "scalar", "--quiet"])
    deadline = time.monotonic() + 120.0
    while count_stored(out) < 2 and time.monotonic() < deadline:
        assert process.poll() is None, "the study ended before it could be killed"
        time.sleep(0.02)
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    stored = count_stored(out)
    assert 2 <= stored < 8
    assert not (out / "results.parquet").exists()  # nothing but finished cases was written
    rerun = subprocess.run([*command, "--workers", "1", "--json"], capture_output=True, text=True)
    assert rerun.returncode == 0, rerun.stderr
    resumed = pd.read_parquet(out / "results.parquet")
    assert resumed["case"].is_unique and len(resumed) == 8
    pd.testing.assert_frame_equal(physics(resumed), physics(table))
    assert json.loads(rerun.stdout)["counts"]["cases"] == 8


# -- the command line ------------------------------------------------------------------------


def test_study_command_prints_counts_and_refuses_bad_input(
    small_run: tuple[Path, pd.DataFrame], capsys: pytest.CaptureFixture[str]
) -> None:
    out, _ = small_run
    assert main(["study", str(out.parent / "study.yaml"), "--out", str(out), "--workers", "1"]) == 0
    printed = capsys.readouterr().out
    assert "8 cases: 4 ok, 0 not stopped, 4 failed" in printed and "0 computed now" in printed
    assert main(["study", "no_such_study", "--out", str(out)]) == 1
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "not the name of a shipped study" in error
    assert main(["study", "ur10_annex_b", "--workers", "0"]) == 2


def test_run_no_plots_writes_no_figures(tmp_path: Path) -> None:
    assert main(["run", "pendulum3r", "--out", str(tmp_path), "--no-plots", "--quiet"]) == 0
    assert not list(tmp_path.glob("*.png"))
    assert (tmp_path / "summary.json").is_file()


# -- the shipped studies ---------------------------------------------------------------------


@pytest.fixture(scope="module")
def annex_b_study(tmp_path_factory: pytest.TempPathFactory) -> pd.DataFrame:
    """The shipped UR10 Annex-B study, all 162 cases on two workers (about 10 s)."""
    out = tmp_path_factory.mktemp("annex_b") / "out"
    return run_study(load_study(find_study("ur10_annex_b")), out, workers=2).table


def test_shipped_annex_b_study_stops_every_case(annex_b_study: pd.DataFrame) -> None:
    assert len(annex_b_study) == 162 and (annex_b_study["status"] == "ok").all()


def test_stopping_angle_grows_with_speed(annex_b_study: pd.DataFrame) -> None:
    """Everything else fixed, a faster start travels farther (both categories)."""
    fixed = ["joint", "payload", "extension", "category"]
    for key, rows in annex_b_study.groupby(fixed):
        angles = rows.sort_values("speed")["stop_angle"].to_numpy()
        assert np.all(np.diff(angles) > 0.0), key


def test_stopping_angle_grows_with_payload_moving_down(annex_b_study: pd.DataFrame) -> None:
    """Shoulder and elbow (horizontal axes) moving down: gravity drives them, so more payload
    travels farther in category 0; in category 1 the drives' ramp sets the travel until their
    torque limit is reached, so it may stay equal but never shrinks (1e-9 rad: the same ramp)."""
    down = annex_b_study[annex_b_study["joint"] != "shoulder_pan_joint"]
    for key, rows in down.groupby(["joint", "speed", "extension", "category"]):
        angles = rows.sort_values("payload")["stop_angle"].to_numpy()
        if key[3] == 0:
            assert np.all(np.diff(angles) > 0.0), key
        else:
            assert np.all(np.diff(angles) > -1e-9), key


@pytest.mark.slow  # ~20-40 s: the shipped 200-case study
def test_shipped_brake_wear_study_runs(tmp_path: Path) -> None:
    """The sampled study: 200 cases; worn brakes stop later (rank correlation > 0.1)."""
    output = run_study(load_study(find_study("ur10_brake_wear")), tmp_path / "out", workers=2)
    table = output.table
    assert len(table) == 200 and "distribution.csv" in output.files
    ok = table[table["status"] == "ok"]
    assert len(ok) >= 150
    correlation = ok["brake_scale"].corr(ok["stop_angle"], method="spearman")
    assert correlation < -0.1


def test_a_sampled_study_writes_a_distribution(tmp_path: Path) -> None:
    vary = {
        "joint": ["elbow_joint"],
        "speed": {"min": 0.5, "max": 1.0},
        "brake_scale": {"min": 0.8, "max": 1.0},
        "duration": [0.9],
    }
    output = run_study(
        load_study(write_study(tmp_path, vary, samples=3, seed=7)), tmp_path / "out", workers=1
    )
    assert {"distribution.csv", "report.html"} <= set(output.files)
    assert output.summary["study"]["mode"] == "sampled" and output.summary["study"]["seed"] == 7
    assert output.table["speed"].between(0.5, 1.0).all() and len(output.table) == 3


# -- review fixes: includes, fingerprints, axis values, schedulers, all-failed studies ---------


def test_brake_axes_act_on_included_brakes(tmp_path: Path) -> None:
    """ur5_cb3_annex_b takes its brakes from an included fragment: brake_scale scales them."""
    path = tmp_path / "wear.yaml"
    path.write_text(
        "scenario: ur5_cb3_annex_b\nvary:\n  brake_scale: [0.8, 1.0]\n  duration: [0.9]\n"
    )
    study = load_study(path)
    assert "include" not in study.base and "shoulder_lift_joint" in study.base["brakes"]
    with pytest.warns(vp.VtmWarning, match="cases are flagged"):  # the worn case's brakes
        table = run_study(study, tmp_path / "out", workers=1).table
    worn, rated = table.sort_values("brake_scale")["stop_angle"]
    assert worn > rated  # weaker brakes stop later
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert any("brake_scale" in line for line in summary["assumptions"])


def test_a_changed_fragment_changes_the_fingerprint(tmp_path: Path) -> None:
    fragment = tmp_path / "brakes.yaml"
    fragment.write_text("brakes:\n  elbow_joint: {sliding_torque: 1.3}\n")
    base = yaml.safe_load((SCENARIOS_DIR / "ur10_annex_b.yaml").read_text())
    base["include"] = ["brakes.yaml"]  # the fragment's elbow brake replaces the robot data's
    (tmp_path / "base.yaml").write_text(yaml.safe_dump(base))
    study_file = tmp_path / "s.yaml"
    study_file.write_text("scenario: base.yaml\nvary: {speed: [1.0]}\n")
    before = load_study(study_file).fingerprint
    fragment.write_text("brakes:\n  elbow_joint: {sliding_torque: 1.2}\n")
    assert load_study(study_file).fingerprint != before


@pytest.mark.parametrize(
    ("vary", "phrase"),
    [
        ({"speed": ["fast"]}, "'fast' is not a fraction in (0, 1]"),
        ({"speed": [1.5]}, "1.5 is not a fraction in (0, 1]"),
        ({"category": [3]}, "3 is not 0, 1 or 2"),
        ({"category": [True]}, "True must be a number, a string or null"),  # the schema's
        ({"payload": [-1.0]}, "-1.0 is not a mass >= 0 kg"),
        ({"brake_scale": ["worn"]}, "'worn' is not a factor > 0"),
        ({"speed": [0.5, 0.5]}, "0.5 is listed twice"),
        ({"joint": [1]}, "1 is not a joint name"),
    ],
)
def test_axis_values_of_the_wrong_kind_are_refused(tmp_path: Path, vary: dict, phrase: str) -> None:
    with pytest.raises(StudyError) as info:
        load_study(write_study(tmp_path, vary))
    assert info.value.key.startswith(f"vary.{next(iter(vary))}") and phrase in info.value.problem


def test_a_study_whose_cases_all_fail_is_an_error(tmp_path: Path) -> None:
    path = write_study(tmp_path, {"duration": [0.9], "stop.t": [1.0]})  # valid apart
    with pytest.raises(StudyError, match=r"all 1 cases failed.*stop\.t"):
        run_study(load_study(path), tmp_path / "out", workers=1)
    assert not (tmp_path / "out").exists()  # it could not run: it leaves nothing
    # so the same folder takes the study once its file is fixed
    fixed = write_study(tmp_path, {"duration": [0.9], "stop.t": [0.0]})
    assert run_study(load_study(fixed), tmp_path / "out", workers=1).computed == 1


@pytest.mark.parametrize("address", ["nonsense", "tcp://127.0.0.1:1"])
def test_a_bad_scheduler_fails_fast_and_writes_nothing(tmp_path: Path, address: str) -> None:
    path = write_study(tmp_path, {"speed": [1.0], "duration": [0.9]})
    begin = time.monotonic()
    with pytest.raises(StudyError) as info:
        run_study(load_study(path), tmp_path / "out", scheduler=address)
    assert info.value.key == "--scheduler"
    assert time.monotonic() - begin < 20.0  # CONNECT_TIMEOUT is 10 s
    assert not (tmp_path / "out").exists()


@settings(max_examples=200, deadline=None)
@given(count=st.integers(0, 30_000), workers=st.integers(1, 16))
def test_a_study_is_cut_into_batches_with_a_last_round_in_halves(count: int, workers: int) -> None:
    """`_chunks` (hypothesis, 200 draws): every case once, in order; batches of a quarter of a
    worker's share (at most BATCH_CASES); with several workers, the last round (one batch a
    worker and what is left over) in halves where a half keeps TAIL_CASES or more; the scalar
    engine case by case."""
    from vtm_pin.study.runner import BATCH_CASES, TAIL_CASES, _chunks

    tasks = list(range(count))
    chunks = _chunks(tasks, workers, "batched")  # type: ignore[arg-type]
    assert [t for chunk in chunks for t in chunk] == tasks
    assert all(chunks)
    size = max(1, min(BATCH_CASES, -(-count // (4 * workers))))
    half = -(-size // 2)
    halved = workers > 1 and half >= TAIL_CASES
    step = half if halved else size
    sizes = [len(chunk) for chunk in chunks]
    head = [n for n in sizes if n > step]  # whole batches, then the last round's pieces
    assert all(n == size for n in head) and sizes[: len(head)] == head
    tail = sizes[len(head) :]
    assert all(n == step for n in tail[:-1]) and (not tail or tail[-1] <= step)
    if halved and count > workers * size:  # the last round: one batch a worker at least
        assert workers * size <= sum(tail) < (workers + 1) * size
    assert [len(c) for c in _chunks(tasks, workers, "scalar")] == [1] * count  # type: ignore[arg-type]
