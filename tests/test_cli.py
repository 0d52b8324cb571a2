import json
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml
from conftest import SCENARIOS

from vtm_pin.cli import main

PAPER = SCENARIOS / "pendulum3r.yaml"


def test_run_paper_example_writes_summary_trajectory_and_plots(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", str(PAPER), "--out", str(out), "--compare", "naive"]) == 0
    printed = capsys.readouterr().out
    assert "joint2" in printed and "final pose naive - kkt" in printed
    files = {p.name for p in out.iterdir()}
    assert {"summary.json", "trajectory.csv", "trajectory_naive.csv"} <= files
    assert {"joint_angles.png", "joint_rates.png", "momenta.png", "energy.png"} <= files
    summary = json.loads((out / "summary.json").read_text())
    assert summary["joints"] == ["joint1", "joint2", "joint3"]
    first = summary["events"][0]
    assert first["t"] == 0.8 and first["lock"] == ["joint2"]
    np.testing.assert_allclose(first["v_plus"], [-2.0245, 0.0, 1.3059], atol=5e-5)
    assert first["energy_loss"] > 0 and len(first["impulse"]) == 1
    assert summary["final"]["t"] == 2.0 and len(summary["final"]["q"]) == 3
    assert max(np.abs(summary["compare"]["naive"]["final_q_difference"])) > 0.1
    header = (out / "trajectory.csv").read_text().splitlines()[0]
    assert header == "t,q_joint1,q_joint2,q_joint3,v_joint1,v_joint2,v_joint3"


def test_transition_option_overrides_scenario(tmp_path):
    out = tmp_path / "o"
    assert main(["run", str(PAPER), "--out", str(out), "--transition", "minimal"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["transition"] == "minimal"


@pytest.mark.parametrize(
    "content, message",
    [
        ({"robot": "planar_3r", "initial": {"q": [0, 0, 0]}, "duration": 1, "x": 1}, "unknown key"),
        ({"robot": "nope", "initial": {"q": [0]}, "duration": 1}, "Robot 'nope' not found"),
        (
            {
                "robot": "planar_3r",
                "initial": {"q": [0, 0, 0]},
                "duration": 1,
                "events": [{"t": 0.5, "lock": ["elbow"]}],
            },
            "unknown joint 'elbow'",
        ),
    ],
)
def test_bad_scenario_prints_one_line_and_writes_nothing(tmp_path, capsys, content, message):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(content))
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("vtm-pin: error: ") and message in err
    assert err.count("\n") == 1
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir()] == ["bad.yaml"]  # no staging left behind


def test_usage_errors_exit_2(capsys):
    assert main([]) == 2
    assert main(["run", str(PAPER), "--transition", "magic"]) == 2
    assert "invalid choice" in capsys.readouterr().err


def test_estop_run_writes_stopping_report_and_brake_plots(tmp_path, capsys):
    out = tmp_path / "estop"
    scenario = SCENARIOS / "rx160l_estop_cat0.yaml"
    assert main(["run", str(scenario), "--out", str(out), "--compare", "naive"]) == 0
    printed = capsys.readouterr().out
    assert "stopping report (kkt)" in printed and "stopping report (naive)" in printed
    assert "assumptions behind these figures" in printed
    files = {p.name for p in out.iterdir()}
    assert {"brakes.png", "tcp_path.png", "motor_angles.png", "motor_rates.png"} <= files
    summary = json.loads((out / "summary.json").read_text())
    stopping = summary["stopping"]
    assert [j["joint"] for j in stopping["joints"]] == summary["joints"]
    assert stopping["joints"][3]["holding_margin"] == "ideal"
    assert abs(summary["energy"]["balance_residual"]) < 1e-8
    assert {e["kind"] for e in summary["brake_events"]} == {"engage", "lock", "stick"}
    assert "stopping" in summary["compare"]["naive"]


def test_bad_brake_writes_nothing(tmp_path, capsys):
    path = tmp_path / "bad.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "robot": "planar_3r",
                "initial": {"q": [0, 0, 0]},
                "duration": 1,
                "stop": {"t": 0},
                "brakes": {"joint1": {"sliding_torque": 5, "static_torque": 1}},
            }
        )
    )
    assert main(["run", str(path), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert "'brakes.joint1': static torque 1 N m is not a finite number >= the sliding" in err
    assert err.count("\n") == 1
    assert [p.name for p in tmp_path.iterdir()] == ["bad.yaml"]


def test_redundant_constraint_is_one_line_and_no_output(tmp_path, capsys):
    path = tmp_path / "loop.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "robot": "planar_fivebar",
                "initial": {"q": [-0.4, 0.57978007700581935, 0.2, 0.16334925102132061]},
                "duration": 0.2,
                "integrator": {"method": "dop853"},
                "events": [
                    {
                        "t": 0.1,
                        "activate": [{"type": "loop", "frame_a": "tip_l", "frame_b": "tip_r"}],
                    }
                ],
            }
        )
    )
    assert main(["run", str(path), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert err == (
        f"vtm-pin: error: {path}: Constraints are redundant: 'loop0.y' depends on the others "
        "(rank 2 of 3 rows); drop them (a planar loop keeps axes [x, z])\n"
    )
    assert [p.name for p in tmp_path.iterdir()] == ["loop.yaml"]


def test_closed_loop_run_writes_drift_plot_and_warns_once(tmp_path, capsys):
    path = tmp_path / "fivebar.yaml"
    raw = yaml.safe_load((SCENARIOS / "fivebar_lock.yaml").read_text())
    raw["initial"]["v"] = [1.0, 0.0, 0.0, 0.0]  # not on the constraint: projected, with a warning
    raw["duration"] = 1.0
    path.write_text(yaml.safe_dump(raw))
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert err.startswith("vtm-pin: warning: Initial state moved onto the constraints by up to")
    assert err.count("\n") == 1
    assert (out / "constraint_drift.png").exists()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["constraints"] == ["loop"]
    assert summary["constraint_drift"]["position_max"] < 1e-8
    assert summary["events"][0]["impulse_rows"] == ["lock joint_r1"]
    assert summary["events"][0]["impulse_persistent_rows"] == ["loop.x", "loop.z"]


def test_run_draws_initial_and_final_poses(tmp_path):
    out = tmp_path / "out"
    assert main(["run", str(PAPER), "--out", str(out), "--compare", "naive", "--quiet"]) == 0
    assert (out / "poses.png").stat().st_size > 10_000


def test_json_prints_the_summary_and_quiet_prints_nothing(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", str(PAPER), "--out", str(out), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed == json.loads((out / "summary.json").read_text())
    assert main(["run", str(PAPER), "--out", str(out), "--quiet"]) == 0
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == ""
    assert main(["run", str(PAPER), "--quiet", "--json"]) == 2
    assert "not allowed with argument" in capsys.readouterr().err


@pytest.mark.slow  # ~15-35 s: runs under a pseudo-terminal
def test_progress_bar_on_a_terminal_only(tmp_path, capsys, monkeypatch):
    import vtm_pin.cli

    monkeypatch.setattr(vtm_pin.cli, "PROGRESS_DELAY", 0.0)
    out = tmp_path / "out"
    assert main(["run", str(PAPER), "--out", str(out), "--compare", "naive"]) == 0
    assert "%|" not in capsys.readouterr().err  # not a terminal: no bar
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    assert main(["run", str(PAPER), "--out", str(out), "--compare", "naive"]) == 0
    err = capsys.readouterr().err
    assert "pendulum3r (kkt):" in err and "pendulum3r (naive):" in err
    assert "100%|" in err and "t = 2.000 of 2 s" in err
    assert main(["run", str(PAPER), "--out", str(out), "--json"]) == 0
    assert "%|" not in capsys.readouterr().err  # --json: no bar


def test_interrupt_exits_130_and_writes_nothing(tmp_path, capsys, monkeypatch):
    import vtm_pin.outputs.pipeline

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(vtm_pin.outputs.pipeline, "run_scenario", interrupted)
    out = tmp_path / "out"
    assert main(["run", str(PAPER), "--out", str(out)]) == 130
    assert capsys.readouterr().err == "vtm-pin: interrupted; nothing written\n"
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_help_explains_units_and_exit_codes(capsys):
    assert main(["--help"]) == 0
    text = capsys.readouterr().out
    assert "exit status:" in text and "130" in text and "rates rad/s" in text
    assert main(["run", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "step [s]" in text and "[rad for angles, rad/s for rates]" in text
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.startswith("vtm-pin 0.")


def test_list_robots_and_scenarios(capsys):
    assert main(["list", "robots"]) == 0
    text = capsys.readouterr().out
    assert "planar_3r       3       tip" in text and "rx160l" in text
    assert "ur5" in text.split("example-robot-data names", 1)[1]
    assert main(["list", "scenarios", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert [e["scenario"] for e in listed] == sorted(p.stem for p in SCENARIOS.glob("*.yaml"))
    paper = next(e for e in listed if e["scenario"] == "pendulum3r")
    assert paper["robot"] == "planar_3r" and paper["duration [s]"] == "2"


def test_list_scenarios_marks_invalid_files_and_bad_folders(tmp_path, capsys):
    (tmp_path / "good.yaml").write_text("robot: planar_3r\ninitial: {q: [0, 0, 0]}\nduration: 1\n")
    (tmp_path / "bad.yaml").write_text("robot: planar_3r\ninitial: {q: [0, 0, 0]}\n")
    assert main(["list", "scenarios", "--dir", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].split() == ["bad", "-", "-", "INVALID:", "'duration'", "is", "missing"]
    assert lines[2].split() == ["good", "planar_3r", "1"]
    assert main(["list", "scenarios", "--dir", str(tmp_path / "nowhere")]) == 1
    assert capsys.readouterr().err.strip().endswith("nowhere: is not a folder")


def fail_if_simulated(*args, **kwargs):
    raise AssertionError("the simulation must not start")


@pytest.mark.parametrize("where", ["afile/out", "afile", "afile/a/b"])
def test_out_under_a_file_is_refused_before_the_simulation(tmp_path, capsys, monkeypatch, where):
    import vtm_pin.outputs.pipeline

    monkeypatch.setattr(vtm_pin.outputs.pipeline, "run_scenario", fail_if_simulated)
    (tmp_path / "afile").write_text("x")
    assert main(["run", str(PAPER), "--out", str(tmp_path / where)]) == 1
    err = capsys.readouterr().err
    afile = tmp_path / "afile"
    assert err == f"vtm-pin: error: command line: '--out': '{afile}' is a file, not a folder\n"
    assert [p.name for p in tmp_path.iterdir()] == ["afile"]


def test_out_in_an_unwritable_place_is_refused_before_the_simulation(capsys, monkeypatch):
    import vtm_pin.outputs.pipeline

    monkeypatch.setattr(vtm_pin.outputs.pipeline, "run_scenario", fail_if_simulated)
    assert main(["run", str(PAPER), "--out", "/proc/vtm-pin-test/out"]) == 1
    assert capsys.readouterr().err.startswith("vtm-pin: error: command line: '--out': cannot write")


def test_interrupt_during_the_imports_exits_130_in_one_line(capsys, monkeypatch):
    """The console entry imports the CLI (Pinocchio, Matplotlib) inside its Ctrl-C guard."""
    import importlib.abc

    from vtm_pin.__main__ import entry_point

    class Interrupting(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name == "vtm_pin.cli":
                raise KeyboardInterrupt
            return None

    monkeypatch.delitem(sys.modules, "vtm_pin.cli")
    monkeypatch.setattr(sys, "meta_path", [Interrupting(), *sys.meta_path])
    assert entry_point() == 130
    assert capsys.readouterr().err == "vtm-pin: interrupted; nothing written\n"


def test_an_interrupt_swallowed_during_the_imports_still_exits_130(capsys, monkeypatch):
    """Python drops a Ctrl-C raised in a weakref callback of the import machinery; not us."""
    import importlib.abc

    from vtm_pin.__main__ import entry_point

    class Dropped:
        def __del__(self):  # Python reports an exception here and drops it, as in a callback
            signal.raise_signal(signal.SIGINT)

    class Swallowing(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name == "vtm_pin.cli":
                Dropped()  # Ctrl-C inside __del__: "Exception ignored in ...", the import goes on
            return None

    monkeypatch.delitem(sys.modules, "vtm_pin.cli")
    monkeypatch.setattr(sys, "meta_path", [Swallowing(), *sys.meta_path])
    monkeypatch.setattr(sys, "argv", ["vtm-pin", "run", str(PAPER)])
    assert entry_point() == 130
    assert capsys.readouterr().err == "vtm-pin: interrupted; nothing written\n"


def test_the_entry_point_freezes_the_heap_once_its_command_returns(monkeypatch):
    """The interpreter's collections at exit then skip a study's records (~0.2 s of 10,000)."""
    import gc
    import importlib

    from vtm_pin.__main__ import entry_point

    cli = importlib.import_module("vtm_pin.cli")  # the module the entry point imports from
    seen = []
    monkeypatch.setattr(cli, "main", lambda: seen.append(gc.get_freeze_count()) or 3)
    monkeypatch.setattr(sys, "argv", ["vtm-pin", "run", str(PAPER)])
    try:
        assert entry_point() == 3  # the command's own status
        assert seen == [0]  # not frozen while the command ran
        assert gc.get_freeze_count() > 0
    finally:
        gc.unfreeze()


def test_sigint_early_in_a_real_process_exits_130_in_one_line(tmp_path):
    """Ctrl-C 0.3 s after start: during the imports (1-2 s) or the run, one line either way."""
    process = subprocess.Popen(
        [sys.executable, "-m", "vtm_pin", "run", str(PAPER), "--out", str(tmp_path / "out")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    time.sleep(0.3)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130, err
    assert err == "vtm-pin: interrupted; nothing written\n"
    assert list(tmp_path.iterdir()) == []


def test_failure_prints_its_error_only_and_numpy_warnings_never(tmp_path, capsys, monkeypatch):
    import warnings

    import vtm_pin.outputs.pipeline
    from vtm_pin import SimulationError, VtmWarning

    def noisy(*args, **kwargs):
        np.array([1e308]) * 10.0  # overflow: a NumPy RuntimeWarning outside the CLI
        warnings.warn("something was assumed", VtmWarning, stacklevel=1)
        raise SimulationError("it went wrong\non two lines")

    monkeypatch.setattr(vtm_pin.outputs.pipeline, "run_scenario", noisy)
    assert main(["run", str(PAPER), "--out", str(tmp_path / "out")]) == 1
    assert capsys.readouterr().err == "vtm-pin: error: it went wrong on two lines\n"
    assert list(tmp_path.iterdir()) == []


def test_a_bug_is_one_line_too(tmp_path, capsys, monkeypatch):
    import vtm_pin.outputs.pipeline

    def broken(*args, **kwargs):
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr(vtm_pin.outputs.pipeline, "run_scenario", broken)
    assert main(["run", str(PAPER), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("vtm-pin: error: internal error (ZeroDivisionError: division by zero)")
    assert err.count("\n") == 1 and list(tmp_path.iterdir()) == []


def test_usage_errors_are_one_line(capsys):
    assert main(["run", str(PAPER), "--dt", "abc"]) == 2
    err = capsys.readouterr().err
    assert err == "vtm-pin run: error: argument --dt: invalid float value: 'abc' (see --help)\n"


def test_integrator_options_follow_the_scenario_rules(tmp_path, capsys):
    out = str(tmp_path / "out")
    assert main(["run", str(PAPER), "--out", out, "--dt", "inf"]) == 1
    assert capsys.readouterr().err == (
        "vtm-pin: error: command line: '--dt': inf is not a finite number\n"
    )
    assert main(["run", str(PAPER), "--out", out, "--dt", "1e-9"]) == 1
    assert "'--dt': rk4 with dt = 1e-09 s would take 2000000000 steps" in capsys.readouterr().err
    assert main(["run", str(PAPER), "--out", out, "--max-steps", "0"]) == 1
    assert "'--max-steps': 0 must be >= 1" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_run_takes_a_shipped_scenario_name_from_any_folder(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["run", "pendulum3r", "--quiet"]) == 0
    summary = json.loads((tmp_path / "results" / "pendulum3r" / "summary.json").read_text())
    assert summary["scenario"].endswith("pendulum3r.yaml") and summary["duration"] == 2.0
    raw = yaml.safe_load(PAPER.read_text())
    raw.update(duration=0.5, events=[{"t": 0.25, "lock": ["joint2"]}])
    (tmp_path / "pendulum3r").write_text(yaml.safe_dump(raw))  # a file of that name wins
    assert main(["run", "pendulum3r", "--quiet", "--out", "mine"]) == 0
    summary = json.loads((tmp_path / "mine" / "summary.json").read_text())
    assert summary["scenario"] == "pendulum3r" and summary["duration"] == 0.5
    assert main(["run", "pendulum4r"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(
        "vtm-pin: error: pendulum4r: no such file, and not the name of a shipped scenario ("
    )
    assert "pendulum3r, rx160l_dock_point" in err and err.count("\n") == 1
    assert main(["run", "--help"]) == 0
    assert "name of a shipped scenario" in " ".join(capsys.readouterr().out.split())
