"""Calibration with the new laws, and conservative bounds (issue 23).

* Synthetic round trips: a table simulated with each new law (the viscous brake, the motors'
  short-circuit braking) calibrates back to the figures it was made with.
* Coverage: over synthetic truths drawn from a stated prior (a UR3 base brake: sliding torque
  uniform in [40, 80] N m, delay uniform in [20, 60] ms), each published table perturbed by
  Gaussian noise of the stated scatter (5 % distances, 20 % times), calibrated, then asked for
  a stop it was not fitted to (60 % speed, 1 kg, 66 % reach): the 95 % upper bound covers the
  truth's stopping angle and time in at least 90 % of the draws.
* The upper bound is never below the nominal figure (a hypothesis property of the formula).
"""

from __future__ import annotations

import csv
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

import vtm_pin as vp
from vtm_pin.calibration.fit import calibrate, make_figures, priors, simulate_row
from vtm_pin.calibration.report import calibrated_fragment, uncertainty_section
from vtm_pin.calibration.table import COLUMNS, read_stopping_table
from vtm_pin.outputs.pipeline import run
from vtm_pin.physics.robot import load_robot
from vtm_pin.scene.scenario import build_scenario
from vtm_pin.standards.bounds import (
    BoundSpec,
    Uncertainty,
    error_gain,
    shortfall_allowance,
    upper_bounds,
    variants,
)

ROBOT = "ur3"  # example-robot-data, no gear ratio: torques and speeds joint side
ROWS = [  # joint, label, speed [deg/s], payload [kg], extension [%], motion
    ("shoulder_pan_joint", "J0", 180.0, 3.0, 100.0, "horizontal"),
    ("shoulder_pan_joint", "J0", 100.0, 3.0, 100.0, "horizontal"),
    ("shoulder_lift_joint", "J1", 180.0, 3.0, 100.0, "down"),
    ("shoulder_lift_joint", "J1", 100.0, 3.0, 100.0, "down"),
]


def write_table(path: Path, rows) -> Path:
    with path.open("w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(COLUMNS)
        writer.writerows(rows)
    return path


def synthetic_table(folder: Path, fit: list[str], truth: dict, rows=ROWS, noise=None) -> Path:
    """The table the model with ``truth`` gives (times and distances to 12 digits), optionally
    multiplied by 1 + ``noise`` (distance, time) per row."""
    draft = read_stopping_table(
        write_table(
            folder / "draft.csv",
            [("UR3", 0, j, lab, s, p, e, m, 100.0, 0.1, "draft") for j, lab, s, p, e, m in rows],
        )
    )
    robot = load_robot(ROBOT)
    figures = make_figures(fit, draft.joints, robot.joints)
    prior = priors(robot)
    out = []
    for k, (row, spec) in enumerate(zip(draft.rows, rows, strict=True)):
        simulated = simulate_row(row, ROBOT, truth, figures, prior)
        assert simulated.stopped
        e_d, e_t = (0.0, 0.0) if noise is None else noise[k]
        out.append(
            (
                "UR3",
                0,
                *spec[:2],
                *spec[2:],
                f"{1e3 * simulated.time * (1.0 + e_t):.12g}",
                f"{simulated.distance * (1.0 + e_d):.12g}",
                "synthetic",
            )
        )
    return write_table(folder / "synthetic.csv", out)


LAWS = {
    "viscous": (
        ["delay", "sliding", "viscous:shared"],
        {
            "delay": 0.02,
            "sliding.shoulder_pan_joint": 40.0,
            "sliding.shoulder_lift_joint": 70.0,
            "viscous": 4.0,  # [rad/s]: the torque doubles at 4 rad/s
        },
    ),
    "short_circuit": (
        ["delay", "sliding", "short_circuit:shared", "short_circuit_speed:shared"],
        {
            "delay": 0.02,
            "sliding.shoulder_pan_joint": 40.0,
            "sliding.shoulder_lift_joint": 70.0,
            "short_circuit": 30.0,  # [N m] peak
            "short_circuit_speed": 2.0,  # [rad/s] of the peak
        },
    ),
}


#: The default run's round trips: the law's own figures (and a sliding torque), on the base
#: alone at two speeds (the other brake figures at their priors, in the truth as in the fit).
QUICK = {
    "viscous": (
        ["sliding", "viscous:shared"],
        {"sliding.shoulder_pan_joint": 40.0, "viscous": 4.0},
    ),
    "short_circuit": (
        ["short_circuit:shared", "short_circuit_speed:shared"],
        {"short_circuit": 30.0, "short_circuit_speed": 2.0},
    ),
}


def round_trip(folder: Path, fit: list[str], truth: dict, rows) -> None:
    """Exact data: every figure within 1e-3 relative (finite differences of 1e-3 steps on
    stops integrated to rtol 1e-10)."""
    table = read_stopping_table(synthetic_table(folder, fit, truth, rows))
    calibration = calibrate(table, ROBOT, fit)
    assert calibration.success and calibration.cost < 1e-6
    for name, value in truth.items():
        assert calibration.determined[name], name
        assert calibration.values[name] == pytest.approx(value, rel=1e-3), name


@pytest.mark.parametrize("law", QUICK)
def test_a_table_made_with_each_new_law_calibrates_back_to_its_figures(tmp_path, law):
    round_trip(tmp_path, *QUICK[law], ROWS[:2])


@pytest.mark.slow
@pytest.mark.parametrize("law", LAWS)
def test_every_figure_of_each_new_law_calibrates_back_on_two_joints(tmp_path, law):
    """With the delay and both joints' sliding torques fitted too (30-70 s each)."""
    round_trip(tmp_path, *LAWS[law], ROWS)


def test_the_calibrated_fragment_carries_the_covariance_and_bounds_use_it(tmp_path):
    fit, truth = QUICK["viscous"]
    table = read_stopping_table(synthetic_table(tmp_path, fit, truth, ROWS[:2]))
    calibration = calibrate(table, ROBOT, fit)
    (tmp_path / "calibrated.yaml").write_text(calibrated_fragment(calibration, table))
    fragment = yaml.safe_load((tmp_path / "calibrated.yaml").read_text())
    section = fragment["calibration"]
    assert [f["name"] for f in section["figures"]] == [f.name for f in calibration.figures]
    assert np.allclose(section["covariance"], calibration.covariance)
    # the shared w_v covers the table's joint: its brake follows the viscous law
    assert fragment["brakes"]["shoulder_pan_joint"]["friction"] == "viscous"
    assert "friction" not in fragment["brakes"]["elbow_joint"]
    raw = prediction(tmp_path, bounds={"confidence": 0.95, "brake_wear": 0.1})
    output = run(build_scenario(raw, base_dir=tmp_path))
    upper, values = output.figures.upper, output.figures.metrics
    for name in ("robot_stop_time", "stop_angle", "tcp_max_displacement"):
        assert upper[f"{name}_upper"] > values[name] > 0.0
    assert output.summary["figures"]["bounds"]["figures"] == list(output.scenario.uncertainty.names)
    assert "10 % lower" in output.summary["figures"]["bounds"]["text"]


def test_bounds_refuse_an_undetermined_figure_in_one_line(tmp_path, capsys):
    section = {
        "figures": [{"name": "x", "value": 1.0, "keys": ["brakes.shoulder_pan_joint.delay"]}],
        "covariance": [[0.1]],
        "undetermined": ["sliding.elbow_joint"],
    }
    err = refusal(tmp_path, capsys, section)
    assert "'bounds'" in err and "sliding.elbow_joint" in err, err


def refusal(folder: Path, capsys, section: dict) -> str:
    """The one line ``vtm-pin run`` refuses a bounded scenario with this calibration in."""
    from vtm_pin.cli import main

    raw = prediction(folder, bounds={}, include=False)
    raw["calibration"] = section
    path = folder / "s.yaml"
    path.write_text(yaml.safe_dump(raw))
    assert main(["run", str(path), "--out", str(folder / "o")]) == 1
    assert not (folder / "o").exists()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def prediction(folder: Path, bounds=None, include=True, brakes=None) -> dict:
    """The stop the coverage test predicts: the UR3 base at 60 % speed, 1 kg, 66 % reach."""
    raw = {
        "robot": ROBOT,
        "annex_b": {
            "joint": "shoulder_pan_joint",
            "speed": 0.6,
            "extension": 0.66,
            "direction": "positive",
        },
        "payload": {"mass": 1.0},
        "duration": 1.5,
        "integrator": {"method": "dop853", "rtol": 1e-10, "atol": 1e-12, "output_dt": 1e-3},
        "stop": {"t": 0.0, "category": 0},
    }
    if include:
        raw["include"] = ["calibrated.yaml"]
    if bounds is not None:
        raw["bounds"] = bounds
    if brakes is not None:
        raw["brakes"] = brakes
    return raw


#: The coverage test's prior, noise and size.
COVERAGE_ROWS = [ROWS[0]]
SCATTER = (0.05, 0.20)


def coverage(draws: int, seed: int, folder: Path) -> tuple[float, float]:
    """The fraction of draws whose 95 % upper bound covers the truth's angle and time."""
    rng = np.random.default_rng(seed)
    fit = ["delay", "sliding"]
    covered_angle = covered_time = 0
    for k in range(draws):
        truth = {
            "delay": rng.uniform(0.02, 0.06),
            "sliding.shoulder_pan_joint": rng.uniform(40, 80),
        }
        noise = [(rng.normal(0, SCATTER[0]), rng.normal(0, SCATTER[1]))]
        here = folder / f"draw{k}"
        here.mkdir()
        table = read_stopping_table(synthetic_table(here, fit, truth, COVERAGE_ROWS, noise))
        calibration = calibrate(table, ROBOT, fit, scatter=SCATTER)
        (here / "calibrated.yaml").write_text(calibrated_fragment(calibration, table))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", vp.VtmWarning)
            bound = run(build_scenario(prediction(here, bounds={}), base_dir=here)).figures
            true_brake = {
                "delay": truth["delay"],
                "sliding_torque": truth["sliding.shoulder_pan_joint"],
                "static_torque": 1.25 * truth["sliding.shoulder_pan_joint"],
            }
            brakes = {j: dict(true_brake) for j in load_robot(ROBOT).joints}
            raw = prediction(here, include=False, brakes=brakes)
            true = run(build_scenario(raw, base_dir=here)).figures.metrics
        covered_angle += true["stop_angle"] <= bound.upper["stop_angle_upper"]
        covered_time += true["test_stop_time"] <= bound.upper["test_stop_time_upper"]
    return covered_angle / draws, covered_time / draws


@pytest.mark.slow
def test_the_95_percent_bound_covers_the_truth_in_at_least_90_percent_of_cases(tmp_path):
    """200 draws from the prior (about 6 minutes)."""
    angle, time = coverage(200, seed=23, folder=tmp_path)
    assert angle >= 0.90 and time >= 0.90, (angle, time)


def test_the_bound_covers_the_truth_in_a_small_sample(tmp_path):
    """The default run's smaller sample of the same experiment: 12 draws (fixed seed, about
    20 s), at least 11 covered (>= 90 %); the slow test above is the measurement."""
    angle, time = coverage(12, seed=5, folder=tmp_path)
    assert angle >= 11 / 12 and time >= 11 / 12, (angle, time)


_figure = st.floats(1e-3, 1e3, allow_nan=False)


def random_uncertainty(sigma: np.ndarray, bias: float, seed: int) -> Uncertainty:
    """Figures of value 1 whose covariance has the 1-sigma ``sigma`` and random correlations."""
    k = len(sigma)
    A = np.random.default_rng(seed).normal(size=(k, k))
    return Uncertainty(
        names=tuple(f"f{i}" for i in range(k)),
        values=np.ones(k),
        keys=tuple(("brakes.j.delay",) for _ in range(k)),
        covariance=(A @ A.T) * np.outer(sigma, sigma) / k,
        bias={"stop_time": bias, "stop_distance": bias},
        source="property",
    )


#: A bound's runs and calibration, drawn: the nominal, worn and moved runs' figures, the
#: moved figures' 1-sigma, the calibration's bias and the bound's confidence.
_BOUND_DRAWS = {
    "nominal": _figure,
    "worn": _figure,
    "moved": st.lists(_figure, min_size=1, max_size=4),
    "sigma": st.lists(st.floats(1e-6, 10.0), min_size=4, max_size=4),
    "bias": st.floats(-0.5, 0.5),
    "confidence": st.floats(0.5, 0.9999),
}


@settings(max_examples=200, deadline=None, derandomize=True, database=None)
@given(**_BOUND_DRAWS, wear=st.floats(0.0, 0.9))
def test_the_upper_bound_is_never_below_the_nominal_figure(
    nominal, worn, moved, sigma, bias, wear, confidence
):
    uncertainty = random_uncertainty(np.array(sigma[: len(moved)]), bias, len(moved))
    spec = BoundSpec(confidence, wear)
    metrics = {name: nominal for name in ("robot_stop_time", "stop_angle")}
    runs = [{name: worn for name in metrics}] + [{name: m for name in metrics} for m in moved]
    upper = upper_bounds(metrics, runs, spec, uncertainty)
    for name in metrics:
        assert upper[f"{name}_upper"] >= nominal
        assert upper[f"{name}_upper"] >= worn
        assert math.isfinite(upper[f"{name}_upper"])


@settings(max_examples=200, deadline=None, derandomize=True, database=None)
@given(**_BOUND_DRAWS, seed=st.integers(0, 2**32 - 1))
def test_a_bound_enlarges_its_runs_errors_at_most_by_its_error_gain(
    nominal, worn, moved, sigma, bias, confidence, seed
):
    """Every run's figure moved by at most d moves the upper bound by at most d error_gain.

    This is what lets the batched and scalar engines' bounds be compared at that tolerance
    (tests/test_batch.py::test_shipped_studies_agree). Round-off allowance 1e-12 of the
    figures' scale: the bound's own arithmetic on figures up to 1e3.
    """
    rng = np.random.default_rng(seed)
    uncertainty = random_uncertainty(np.array(sigma[: len(moved)]), bias, seed)
    spec = BoundSpec(confidence, 0.1)
    d = 1e-7
    figures = np.array([nominal, worn, *moved])
    off = figures + rng.uniform(-d, d, figures.size)

    def upper(f: np.ndarray) -> float:
        runs = [{"robot_stop_time": float(x)} for x in f[1:]]
        bound = upper_bounds({"robot_stop_time": float(f[0])}, runs, spec, uncertainty)
        return float(bound["robot_stop_time_upper"])

    gain = error_gain(spec, uncertainty)
    assert abs(upper(off) - upper(figures)) <= d * gain + 1e-12 * figures.max() * gain


def test_uncertainty_section_inflates_by_chi2_and_names_fixed_figures(tmp_path):
    fit, truth = ["delay", "sliding"], {"delay": 0.03, "sliding.shoulder_pan_joint": 60.0}
    noise = [(0.03, -0.2), (-0.02, 0.1)]
    table = read_stopping_table(synthetic_table(tmp_path, fit, truth, ROWS[:2], noise))
    calibration = calibrate(table, ROBOT, fit)
    section = uncertainty_section(calibration, table)
    assert section["inflation"] >= 1.0
    free = [f.name for f in calibration.figures if not calibration.at_bound[f.name]]
    assert [f["name"] for f in section["figures"]] == free
    assert section["bias"]["stop_time"] == pytest.approx(
        np.mean([(r.time - r.row.stop_time) / r.row.stop_time for r in calibration.rows])
    )


@settings(max_examples=200, deadline=None, derandomize=True, database=None)
@given(shortfall=st.floats(-0.9, 0.5), published=st.floats(1e-3, 1e3))
def test_the_shortfall_allowance_brings_a_short_figure_back_to_the_published_one(
    shortfall, published
):
    """A figure short by r = (s - p) / p < 0 plus its allowance is p (1e-12 relative: only
    round-off); a figure that is not short gets nothing."""
    simulated = published * (1.0 + shortfall)
    bounded = simulated + shortfall_allowance(shortfall, simulated)
    assert bounded == pytest.approx(max(published, simulated), rel=1e-12)


def test_a_figure_of_zero_variance_is_not_moved_and_adds_nothing(tmp_path):
    """Its covariance row is 0: no variant run, and the bound is that of the other figure."""
    uncertainty = Uncertainty(
        names=("fixed", "free"),
        values=np.array([0.05, 2.0]),
        keys=(("brakes.j.delay",), ("brakes.j.sliding_torque",)),
        covariance=np.diag([0.0, 0.04]),
        bias={},
        source="test",
    )
    assert list(uncertainty.moved) == [1]
    raw = {"brakes": {"j": {"delay": 0.05, "sliding_torque": 2.0}}}
    runs = variants(raw, BoundSpec(0.95, 0.0), uncertainty)
    assert len(runs) == 2 and runs[1]["brakes"]["j"] == {"delay": 0.05, "sliding_torque": 2.2}
    upper = upper_bounds(
        {"stop_angle": 1.0},
        [{"stop_angle": 1.0}, {"stop_angle": 0.9}],
        BoundSpec(0.95, 0.0),
        uncertainty,
    )
    # g = (0.9 - 1.0) / 0.2 = -0.5 per N m; sigma 0.2 N m: spread 0.1 rad
    assert upper["stop_angle_upper"] == pytest.approx(1.0 + BoundSpec().z * 0.1, rel=1e-12)


def test_a_calibration_figure_of_zero_is_refused_in_one_line(tmp_path, capsys):
    """A bound moves a figure by scaling it: the schema keeps every value > 0."""
    section = {
        "figures": [{"name": "delay", "value": 0.0, "keys": ["brakes.shoulder_pan_joint.delay"]}],
        "covariance": [[1e-4]],
    }
    err = refusal(tmp_path, capsys, section)
    assert "'calibration.figures[0].value': 0.0 must be > 0" in err, err


def test_a_bound_variant_that_has_not_stopped_gives_no_bound_and_a_flag(tmp_path):
    """The nominal stop ends 20 ms before the run does; with every brake 60 % weaker the stop
    takes longer than that, so the worn run still moves at the end."""
    held = ("shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint")
    brakes = {"shoulder_pan_joint": {"sliding_torque": 60.0, "delay": 0.03}}
    brakes |= {joint: {"ideal": True, "delay": 0.03} for joint in held}
    raw = prediction(tmp_path, include=False, brakes=brakes)
    nominal = run(build_scenario(raw, base_dir=tmp_path)).figures
    assert nominal.status == "ok"
    raw["duration"] = nominal.metrics["robot_stop_time"] + 0.02
    raw["bounds"] = {"brake_wear": 0.6}
    with pytest.warns(vp.VtmWarning, match="no upper bound is given"):
        figures = run(build_scenario(raw, base_dir=tmp_path)).figures
    assert figures.status == "ok"
    assert "bounds_not_stopped" in [f.kind for f in figures.flags]
    assert figures.upper and all(value is None for value in figures.upper.values())


def test_command_line_integrator_options_reach_the_bounds_variant_runs(tmp_path):
    import argparse

    from vtm_pin.cli import _with_integrator_options
    from vtm_pin.outputs.figures import bound_variants

    raw = prediction(tmp_path, bounds={"brake_wear": 0.1}, include=False)
    scenario = build_scenario(raw, base_dir=tmp_path)
    options = {"integrator": None, "dt": None, "rtol": 1e-6, "atol": 1e-8, "max_steps": None}
    changed = _with_integrator_options(scenario, argparse.Namespace(**options))
    assert changed.integrator.rtol == 1e-6
    (worn,) = bound_variants(changed)
    assert worn.integrator == changed.integrator
