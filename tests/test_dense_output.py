"""dop853's ``output_dt``: samples of its dense output on the global grid k output_dt.

The grid replaces the accepted steps in each segment; the steps themselves, the events and the
state reached are those of the run without it (only the sampling changes), so what is read
from the samples (the tool path length above all) converges to the continuous solution's.
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import SCENARIOS

from vtm_pin.cli import _with_integrator_options
from vtm_pin.exceptions import ScenarioError
from vtm_pin.numerics.integrators import DOP853, StateEvent
from vtm_pin.numerics.integrators.dop853 import GRID_SLACK
from vtm_pin.outputs.pipeline import RunOutput, run
from vtm_pin.scene.scenario import build_integrator, build_scenario

RTOL, ATOL = 1e-8, 1e-10  # dop853 tolerances of these tests [-], [state units]
T0, T1 = 0.05, 2.03  # [s] an interval that starts and ends off the grid
Y0 = np.array([0.0, 1.0])  # [rad, rad/s]: y = sin(t - T0), y' = cos(t - T0)


def oscillator(t: float, y: np.ndarray) -> np.ndarray:
    """Harmonic oscillator y'' = -y (unit frequency)."""
    return np.array([y[1], -y[0]])


def exact(t: np.ndarray) -> np.ndarray:
    """Closed-form solution from Y0 at T0, shape (len(t), 2)."""
    return np.column_stack([np.sin(t - T0), np.cos(t - T0)])


def on_grid(t: np.ndarray, dt: float) -> np.ndarray:
    """Whether each time is k dt for a whole k, to round-off (a few ulp of k dt)."""
    k = np.round(t / dt)
    return np.abs(t - k * dt) <= 4.0 * np.spacing(np.maximum(np.abs(t), dt))


# --- the integrator on a closed-form ODE ---------------------------------------------------


def test_samples_are_the_grid_and_the_ends_and_match_the_closed_form():
    dt = 0.1  # [s]
    plain = DOP853(RTOL, ATOL).integrate(oscillator, T0, Y0, T1)
    dense = DOP853(RTOL, ATOL, output_dt=dt).integrate(oscillator, T0, Y0, T1)
    # Start and end, and between them exactly the grid times strictly inside (0.1 ... 2.0).
    assert dense.t[0] == T0 and dense.t[-1] == T1
    np.testing.assert_array_equal(dense.t[1:-1], np.arange(1, 21) * dt)
    assert np.all(on_grid(dense.t[1:-1], dt))
    # Only the sampling changes: the same steps, and bit for bit the same final state.
    assert dense.steps == plain.steps == plain.t.size - 1
    np.testing.assert_array_equal(dense.y[0], Y0)
    np.testing.assert_array_equal(dense.y[-1], plain.y[-1])
    # 100 x rtol: the global error of an error-per-step method at rtol 1e-8 over ~2 rad of
    # phase is a few rtol (measured 1.3e-8), and the 7th-order dense output between steps is
    # accurate to the order of the local error tolerance; 100 x leaves a wide margin while
    # a wrong offset or coefficient (errors ~ step^2 ~ 1e-2) would fail by far.
    np.testing.assert_allclose(dense.y, exact(dense.t), rtol=0.0, atol=100 * RTOL)


def test_dense_output_costs_only_the_steps_that_contain_a_grid_time():
    plain = DOP853(RTOL, ATOL).integrate(oscillator, T0, Y0, T1)
    # No grid time inside the interval: no dense output at all, only start and end.
    none_inside = DOP853(RTOL, ATOL, output_dt=T1).integrate(oscillator, T0, Y0, T1)
    assert none_inside.rhs_evals == plain.rhs_evals
    np.testing.assert_array_equal(none_inside.t, [T0, T1])
    # Grid times 1 and 2 s: 3 more evaluations for each step holding one (one or two steps).
    two = DOP853(RTOL, ATOL, output_dt=1.0).integrate(oscillator, T0, Y0, T1)
    np.testing.assert_array_equal(two.t, [T0, 1.0, 2.0, T1])
    assert two.rhs_evals - plain.rhs_evals in (3, 6)


@pytest.mark.parametrize("start", [0.3, 0.7, 3 * 0.1, 0.1 + 0.2, 0.08])
def test_grid_times_at_an_end_up_to_round_off_are_that_end(start):
    # 3 x 0.1 = 0.30000000000000004 > 0.3: a grid time 5e-17 s after an interval's start is
    # that start, not a second sample beside it (GRID_SLACK x output_dt = 1e-11 s).
    dt = 0.1 if start != 0.08 else 1e-3  # [s]
    segment = DOP853(RTOL, ATOL, output_dt=dt).integrate(oscillator, start, Y0, start + 0.6)
    gaps = np.diff(segment.t)
    assert np.all(gaps > GRID_SLACK * dt)
    assert np.all(on_grid(segment.t[1:-1], dt))
    assert segment.t.size == round(0.6 / dt) + 1


def test_a_state_event_ends_the_samples_and_the_grid_resumes_after_it():
    dt = 0.25  # [s]
    falling = StateEvent(lambda t, y: float(y[0]), direction=-1)  # sin(t - T0) = 0 at T0 + pi
    plain = DOP853(RTOL, ATOL).integrate(oscillator, T0, Y0, 5.0, [falling])
    first = DOP853(RTOL, ATOL, output_dt=dt).integrate(oscillator, T0, Y0, 5.0, [falling])
    assert first.event == plain.event == 0
    # The last sample is the located event, bit for bit the state the integrator reached.
    # Its time is off by the solution's error over the slope |y'| = 1: 100 x rtol as below
    # (measured 2.3e-9 s).
    assert first.t[-1] == plain.t[-1] == pytest.approx(T0 + np.pi, abs=100 * RTOL)
    np.testing.assert_array_equal(first.y[-1], plain.y[-1])
    np.testing.assert_array_equal(first.t[1:-1], np.arange(1, 13) * dt)  # 0.25 ... 3.0
    # Restarted at the event (as the hybrid loop does): the next sample is the next grid time
    # of the same global grid, 3.25 s, not event + dt.
    t_event = float(first.t[-1])
    second = DOP853(RTOL, ATOL, output_dt=dt).integrate(oscillator, t_event, first.y[-1], 5.0)
    assert second.t[0] == t_event and second.t[-1] == 5.0
    np.testing.assert_array_equal(second.t[1:-1], np.arange(13, 20) * dt)  # 3.25 ... 4.75
    # Accuracy across the event, as in the closed-form test (100 x rtol, same reasons).
    both = np.concatenate([first.t, second.t])
    samples = np.concatenate([first.y, second.y])
    np.testing.assert_allclose(samples, exact(both), rtol=0.0, atol=100 * RTOL)


def test_an_interval_where_nothing_moves_is_sampled_too():
    segment = DOP853(output_dt=0.1).integrate(oscillator, 0.05, np.zeros(0), 0.35)
    np.testing.assert_array_equal(segment.t, [0.05, 0.1, 0.2, 0.30000000000000004, 0.35])
    assert segment.y.shape == (5, 0)


@pytest.mark.parametrize("output_dt", [0.0, -1e-3, np.inf, np.nan])
def test_the_integrator_refuses_a_bad_output_dt(output_dt):
    with pytest.raises(ValueError, match="output_dt"):
        DOP853(output_dt=output_dt)


# --- a scenario with brakes -----------------------------------------------------------------

BASE = yaml.safe_load((SCENARIOS / "rx160l_estop_cat0.yaml").read_text())


def run_with(integrator: dict) -> RunOutput:
    """rx160l_estop_cat0 (brakes sliding, sticking and locking) with another integrator."""
    raw = copy.deepcopy(BASE)
    raw["integrator"] = integrator
    return run(build_scenario(raw, source="test", base_dir=SCENARIOS, name="cat0"))


@pytest.fixture(scope="module")
def runs() -> dict[float | None, RunOutput]:
    """dop853 rtol 1e-8 without output_dt (None) and with 1e-2, 1e-3 and 3e-4 s."""
    return {
        dt: run_with(
            {"method": "dop853", "rtol": RTOL, **({} if dt is None else {"output_dt": dt})}
        )
        for dt in (None, 1e-2, 1e-3, 3e-4)
    }


@pytest.fixture(scope="module")
def reference_length() -> float:
    """Tool path length by rk4 dt = 5e-5 s [m]: its polygon is 1.4e-9 m short of the arc.

    (Measured against rk4 dt = 1e-5: 0.6106489256 vs 0.6106489269 m; a chord error falls as
    dt^2.) The run takes ~0.8 s.
    """
    output = run_with({"method": "rk4", "dt": 5e-5})
    return output.stopping[output.rule].tcp_path_length


def test_scenario_samples_are_on_the_grid_or_at_events(runs):
    dt = 1e-3  # [s]
    result = runs[dt].result
    events = {0.0, 1.0, *(e.t for e in result.events), *(e.t for e in result.brake_events)}
    off_grid = result.t[~on_grid(result.t, dt)]
    assert set(off_grid.tolist()) <= events
    # Every grid time is sampled while a joint moves (the grid is not thinned by events); once
    # every joint is locked nothing moves, and only the ends of that phase are recorded.
    moving = result.free.any(axis=1)
    last_free = float(result.t[np.flatnonzero(moving)[-1]])
    grid = np.arange(1, 1000) * dt
    assert np.all(np.isin(grid[grid < last_free], result.t))
    locked = result.t[result.t > last_free]
    assert locked.size <= 3 and locked[-1] == 1.0
    # The accepted steps of the plain run are gone (except where they are events).
    plain = runs[None].result
    steps = set(plain.t.tolist()) - events
    assert steps and not steps & set(result.t.tolist())


def test_scenario_dynamics_do_not_change_only_the_sampling(runs):
    plain, dense = runs[None], runs[1e-3]
    a, b = plain.result, dense.result
    # Same steps and events, bit for bit the same final state: step choice ignores output_dt.
    assert a.steps == b.steps
    assert [e.t for e in a.events] == [e.t for e in b.events]
    np.testing.assert_array_equal(a.q[-1], b.q[-1])
    assert b.rhs_evals > a.rhs_evals  # measured 149 -> 167: 3 more per step holding samples
    ra, rb = plain.stopping[plain.rule], dense.stopping[dense.rule]
    for ja, jb in zip(ra.joints, rb.joints, strict=True):
        # Exact: q at the signal (t = 0, a sample of both) and at the end are the same states.
        assert ja.stop_angle == jb.stop_angle
        assert ja.latch_time == jb.latch_time or np.isnan(ja.latch_time)
        # Stopping times interpolate |v| linearly across the rest speed between samples:
        # one adaptive step apart without output_dt, 1 ms apart with it. |v| falls almost
        # linearly there (a constant sliding torque), so they differ by the interpolation's
        # curvature error only: measured 2e-7 s; 1e-6 s is 0.1 % of output_dt.
        assert jb.stop_time == pytest.approx(ja.stop_time, abs=1e-6)


def test_scenario_path_length_converges_to_the_reference(runs, reference_length):
    lengths = {dt: r.stopping[r.rule].tcp_path_length for dt, r in runs.items()}
    errors = {dt: abs(length - reference_length) for dt, length in lengths.items()}
    # Without output_dt the path is a polygon through 12 steps: 1e-3 m short (measured).
    assert errors[None] > 1e-4
    # A polygon's chord error falls as dt^2: 10x finer gives ~100x less (measured 5e-5 m,
    # 5.5e-7 m, 5e-8 m); require 30x per decade, and sub-micrometre at 1 ms.
    assert errors[1e-2] < errors[None] / 10
    assert errors[1e-3] < errors[1e-2] / 30
    assert errors[3e-4] < errors[1e-3]
    assert errors[1e-3] < 1e-6
    # The polygon is inscribed: never longer than the arc (up to the reference's 1.4e-9 m).
    assert all(length < reference_length + 1e-8 for length in lengths.values())


def test_summary_reports_output_dt(runs):
    assert runs[1e-3].summary["integrator"]["output_dt"] == 1e-3
    assert "output_dt" not in runs[None].summary["integrator"]


# --- refused settings ------------------------------------------------------------------------


@pytest.mark.parametrize("method", ["rk4", "euler"])
def test_fixed_step_methods_refuse_output_dt(method):
    with pytest.raises(ScenarioError, match="already samples every dt") as info:
        build_integrator({"method": method, "dt": 1e-3, "output_dt": 1e-3}, 1.0, "s.yaml")
    assert info.value.key == "integrator.output_dt"


@pytest.mark.parametrize("output_dt", [0.0, -1e-3, 2.0, 1e-7, "1e-3", None])
def test_out_of_range_output_dt_is_refused(output_dt):
    # 0, negative and non-numbers break the schema; 2 s is longer than the run (1 s); 1e-7 s
    # gives 1e7 samples, more than max_steps = 1e6.
    with pytest.raises(ScenarioError) as info:
        build_integrator({"method": "dop853", "output_dt": output_dt}, 1.0, "s.yaml")
    assert info.value.key == "integrator.output_dt"


def test_output_dt_equal_to_the_duration_is_accepted():
    integrator = build_integrator({"method": "dop853", "output_dt": 1.0}, 1.0, "s.yaml")
    assert isinstance(integrator, DOP853) and integrator.output_dt == 1.0


def options(**given: object) -> argparse.Namespace:
    """Command-line integrator options, unset unless given."""
    names = ("integrator", "dt", "rtol", "atol", "max_steps")
    return argparse.Namespace(**{name: given.get(name) for name in names})


def test_command_line_options_keep_output_dt():
    raw = copy.deepcopy(BASE)
    raw["integrator"] = {"method": "dop853", "output_dt": 1e-3}
    scenario = build_scenario(raw, source="test", base_dir=Path(SCENARIOS), name="cat0")
    for args in (options(rtol=1e-9), options(integrator="dop853", atol=1e-12)):
        integrator = _with_integrator_options(scenario, args).integrator
        assert isinstance(integrator, DOP853) and integrator.output_dt == 1e-3
    # A fixed-step method asked for on the command line samples every dt instead.
    fixed = _with_integrator_options(scenario, options(integrator="rk4", dt=1e-4)).integrator
    assert fixed.name == "rk4"
