"""Category-2 stops: the drives ramp the rates to zero, then hold the arm; no brake engages.

The 3R pendulum (gear ratio 1, torques joint side) starts at q0 = (1, 0.5, -0.3) rad moving at
v0 = (1.5, -1, 0.5) rad/s; its gravity torques there are about (4308, 2079, 494) N m, so the
limits (8000, 4000, 1500) N m hold it and 500 N m does not.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import SCENARIOS, robot

from vtm_pin import Problem, simulate
from vtm_pin.cli import main
from vtm_pin.core.batch import fallback_reason
from vtm_pin.exceptions import BrakeError
from vtm_pin.numerics.integrators import DOP853
from vtm_pin.outputs.analysis import compute_energy_momentum
from vtm_pin.outputs.stopping import compute_stopping_report
from vtm_pin.physics.brakes import Brake
from vtm_pin.physics.friction import Coulomb
from vtm_pin.physics.stop import DEFAULT_REST_SPEED, Stop

Q0 = np.array([1.0, 0.5, -0.3])  # [rad]
V0 = np.array([1.5, -1.0, 0.5])  # [rad/s]
RAMP = 0.2  # [s]
HOLDING_LIMIT = np.array([8000.0, 4000.0, 1500.0])  # [N m], above the gravity torques
#: A brake on two joints, to show that none engages in category 2.
BRAKES = (Brake("joint1", delay=0.0), Brake("joint2", friction=Coulomb(50.0, 60.0)))
#: After the ramp the rates stay below this [rad/s]: dop853 (rtol 1e-8) tracks the ramp to
#: about 1e-10 rad/s, and the hold's feedback keeps them there; 1e-6 leaves margin.
HOLD_RATE = 1e-6
#: Drift of the held joints after the ramp [rad]: the rates above over 0.4 s, with margin.
HOLD_DRIFT = 1e-6
#: Energy-balance residual, relative to the energy moved [-] (measured 2e-11).
BALANCE_RTOL = 1e-7
#: The stopping time vs the ramp's closed form [s]: the tracking error is ~1e-10 rad/s, which
#: moves the rest-speed crossing by ~1e-10 x RAMP / |v0| s; 1e-6 s leaves margin.
STOP_TIME_TOL = 1e-6


def run(limit: np.ndarray = HOLDING_LIMIT, duration: float = 0.6):
    stop = Stop(0.0, category=2, ramp_time=RAMP, torque_limit=limit)
    problem = Problem(robot("planar_3r"), Q0, V0, duration, brakes=BRAKES, stop=stop)
    return simulate(problem, DOP853())


def test_category_two_ramps_then_holds_without_brakes():
    result = run()
    after = result.t >= RAMP
    assert np.max(np.abs(result.v[after])) <= HOLD_RATE
    assert np.max(np.abs(result.q[after] - result.q[after][0])) <= HOLD_DRIFT
    # No brake is signalled: no brake event, no lock, no brake work, every joint free.
    assert result.brake_events == () and result.events == ()
    assert np.all(result.modes == 0) and np.all(result.free)
    assert result.brake_work[-1] == 0.0
    # The ramp ends where the constant deceleration takes each joint: q0 + v0 T / 2.
    np.testing.assert_allclose(result.q[-1], Q0 + V0 * RAMP / 2.0, atol=HOLD_DRIFT)


def test_category_two_drive_energy_balance_closes():
    """Lost mechanical energy = brake + short-circuit work - drive work (here: drives only)."""
    result = run()
    energy = compute_energy_momentum(robot("planar_3r"), result)
    lost = float(energy.total[0] - energy.total[-1])
    work = result.brake_work[-1] + result.short_circuit_work[-1] - result.drive_work[-1]
    scale = max(float(np.max(energy.kinetic)), abs(float(result.drive_work[-1])))
    assert abs(result.drive_work[-1]) > 1.0  # the drives did the stopping (about -53 J)
    assert abs(lost - work) <= BALANCE_RTOL * scale


def test_category_two_stopping_time_is_the_ramps_end():
    """Each joint crosses the rest speed where the linear ramp does: T (1 - rest / |v0|)."""
    result = run()
    report = compute_stopping_report(robot("planar_3r"), result, BRAKES)
    expected = RAMP * (1.0 - DEFAULT_REST_SPEED / np.abs(V0))
    times = np.array([j.stop_time for j in report.joints])
    np.testing.assert_allclose(times, expected, atol=STOP_TIME_TOL)
    assert report.all_stopped_time == pytest.approx(RAMP, abs=RAMP * 1e-3 + STOP_TIME_TOL)
    assert all(math.isnan(j.latch_time) for j in report.joints)  # no brake latches


def test_category_two_stop_settings_are_checked():
    limit = np.ones(3)
    with pytest.raises(BrakeError, match="Category-2 stop needs a ramp time"):
        Stop(0.0, category=2, torque_limit=limit)
    with pytest.raises(BrakeError, match=r"time_limit .* belongs to category 1"):
        Stop(0.0, category=2, ramp_time=0.1, torque_limit=limit, time_limit=0.1)
    with pytest.raises(BrakeError, match="is not 0, 1 or 2"):
        Stop(0.0, category=3)
    assert Stop(0.0, category=2, ramp_time=0.1, torque_limit=limit).brake_signal == math.inf


def test_batched_engine_falls_back_for_category_two():
    """The batched engine has no drive laws: a category-2 run goes to the scalar engine."""
    stop = Stop(0.0, category=2, ramp_time=RAMP, torque_limit=HOLDING_LIMIT)
    problem = Problem(robot("planar_3r"), Q0, V0, 0.6, brakes=BRAKES, stop=stop)
    assert fallback_reason(problem, DOP853()) == (
        "category-2 stop (drives ramp the rates down, then hold the arm)"
    )


def _pendulum(tmp_path: Path, stop: dict) -> Path:
    raw = {
        "robot": "planar_3r",
        "initial": {"q": Q0.tolist(), "v": V0.tolist()},
        "duration": 0.6,
        "integrator": {"method": "dop853"},
        "brakes": {"joint1": {"delay": 0.0, "ideal": True}},
        "stop": {"t": 0.0, "category": 2, "ramp_time": RAMP, **stop},
    }
    path = tmp_path / "cat2.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def test_drives_that_cannot_hold_are_flagged(tmp_path, capsys):
    """500 N m cannot hold the pendulum's ~4500 N m: flagged, not a brake flag, holds false."""
    path = _pendulum(tmp_path, {"torque_limit": 500.0})
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--no-plots"]) == 0
    printed = capsys.readouterr().out
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    kinds = [f["kind"] for f in summary["flags"]]
    assert "drive_cannot_hold" in kinds and "FLAG drive_cannot_hold" in printed
    assert not any(k.startswith("brake_") for k in kinds)  # the brakes never act
    assert summary["holds"] is False and summary["brake_events"] == []


def test_drives_that_hold_raise_no_flag(tmp_path, capsys):
    path = _pendulum(tmp_path, {"torque_limit": HOLDING_LIMIT.tolist()})
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--no-plots"]) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["flags"] == [] and summary["holds"] is True
    assert summary["brake_events"] == [] and summary["energy"]["brake_work"] == 0.0


def test_category_two_refuses_a_time_limit_in_one_line(tmp_path, capsys):
    path = _pendulum(tmp_path, {"torque_limit": 500.0, "time_limit": 0.1})
    assert main(["run", str(path), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("vtm-pin: error: ")
    assert "cat2.yaml" in err[0] and "time_limit" in err[0] and "category 1" in err[0]
    assert not (tmp_path / "out").exists()


def test_shipped_ur10_category_two_scenario(tmp_path, capsys):
    """The ramp ends the motion at T (1 - 1e-3 / 1 rad/s) = 0.2997 s and the drives hold."""
    out = tmp_path / "out"
    args = ["run", str(SCENARIOS / "ur10_estop_cat2.yaml"), "--out", str(out), "--no-plots"]
    assert main([*args, "--integrator", "dop853"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    values = summary["figures"]["values"]
    assert values["robot_stop_time"] == pytest.approx(0.2997, abs=STOP_TIME_TOL)
    assert summary["flags"] == [] and summary["brake_events"] == []
    assert max(abs(v) for v in summary["final"]["v"]) <= HOLD_RATE
