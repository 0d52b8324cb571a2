"""The benchmark library, benchmarks/benchlib.py (outside the package, so put on the path)."""

import subprocess
import sys

import numpy as np
import pytest
from conftest import ROOT, SCENARIOS

from vtm_pin import load_scenario

sys.path.insert(0, str(ROOT / "benchmarks"))
from benchlib import (
    COST_KEYS,
    WorkPoint,
    compute_reference,
    format_transition_costs,
    format_work_precision,
    make_integrator,
    measure_transition_costs,
    measure_work_precision,
    plot_transition_costs,
    plot_work_precision,
    time_to_accuracy,
)


def test_time_to_accuracy_interpolates_log_log_and_prefers_cheaper_accurate_points():
    points = [WorkPoint("a", 0, 1e-2, 0, 0, 1e-3), WorkPoint("a", 0, 1e-6, 0, 0, 1e-1)]
    # halfway in log error is halfway in log time
    assert time_to_accuracy(points, "a", 1e-4) == pytest.approx(1e-2, rel=1e-12)
    assert time_to_accuracy(points, "a", 1e-2) == pytest.approx(1e-3)
    assert np.isnan(time_to_accuracy(points, "a", 1e-7))  # never reached
    assert np.isnan(time_to_accuracy(points, "b", 1e-2))  # no such method
    faster = [*points, WorkPoint("a", 0, 1e-8, 0, 0, 5e-3)]
    assert time_to_accuracy(faster, "a", 1e-4) == pytest.approx(5e-3)


def test_work_precision_of_the_paper_example_shows_each_methods_order():
    scenario = load_scenario(SCENARIOS / "pendulum3r.yaml")
    q_ref = compute_reference(scenario)
    ladders = {"rk4": [2e-3, 1e-3], "euler": [2e-4, 1e-4], "dop853": [1e-8]}
    seen = []
    points = measure_work_precision(scenario, q_ref, ladders, 1, lambda k, n: seen.append(k))
    assert seen == [1, 2, 3, 4, 5]
    error = {(p.method, p.setting): p.error for p in points}
    # halving dt divides the error by 2^order: RK4 order 4 (16), Euler order 1 (2)
    assert 12 < error["rk4", 2e-3] / error["rk4", 1e-3] < 20
    assert 1.8 < error["euler", 2e-4] / error["euler", 1e-4] < 2.2
    assert error["dop853", 1e-8] < 1e-7
    assert all(p.wall_time > 0 and p.rhs_evals >= p.steps > 0 for p in points)
    table = format_work_precision(points, [1e-6])
    assert "dop853" in table and "1e-06" in table
    assert plot_work_precision(points, "pendulum3r").axes[0].get_xscale() == "log"


def test_transition_costs_are_measured_for_every_key():
    rows = [measure_transition_costs(n, budget=0.01) for n in (3, 6)]
    assert [(r["n"], r["m1"], r["m2"]) for r in rows] == [(3, 1, 1), (6, 3, 1)]
    assert all(np.isfinite(r[k]) and r[k] > 0 for r in rows for k in COST_KEYS)
    docked = measure_transition_costs(12, spatial=True, general=True, budget=0.01)
    assert docked["m1"] == 6  # a 6-row pose docking fills m1 = n // 2
    assert format_transition_costs(rows).count("\n") == 2
    assert len(plot_transition_costs(rows, "t").axes[0].lines) == len(COST_KEYS)


def test_unknown_method_is_refused():
    with pytest.raises(ValueError, match="unknown method 'rk45'; allowed: dop853, euler, rk4"):
        make_integrator("rk45", 1e-3)


def test_the_runtime_modules_do_not_import_benchmark_code():
    code = (
        "import sys, vtm_pin.cli, vtm_pin.outputs.plotting, vtm_pin.outputs.report, "
        "vtm_pin.outputs.drawing; "
        "print(sorted(m for m in sys.modules if 'bench' in m))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
