"""The batched engine's right-hand side leaves out the brake terms no lane has, exactly.

Without a lane with a normal-force ramp, a viscous brake or a motor shorted, the factor is 1,
the viscous term 0 and the short-circuit torque 0: ``BatchEngine.rhs`` then skips them. A lane
outside the evaluated rows that has all three switches the full expressions back on for the
same rows; the result must be the same to the bit (1 x, x (1 + 0) and x + 0 are exact in
floating point), derivatives and holding torques alike.
"""

from __future__ import annotations

import example_robot_data as erd
import numpy as np
import pytest

from vtm_pin.core.batch import BatchEngine, _Lanes
from vtm_pin.numerics.integrators.dop853 import DOP853


@pytest.mark.parametrize("seed", range(4))
def test_the_terms_no_lane_has_are_left_out_exactly(seed: int) -> None:
    model = erd.load("ur10").model
    model.armature[:] = 0.5
    n, size = model.nv, 9
    rng = np.random.default_rng(seed)
    engine = BatchEngine(model, DOP853())
    lanes = _Lanes(n, size)
    lanes.ratio[:] = rng.uniform(50.0, 120.0, (size, n))
    lanes.sign[:] = rng.choice([-1.0, 0.0, 1.0], (size, n))
    lanes.torque[:] = rng.uniform(0.5, 20.0, (size, n))
    lanes.engaged[:] = rng.uniform(0.0, 0.1, (size, n))
    lanes.locked[:] = rng.random((size, n)) < 0.3
    lanes.sign[lanes.locked] = 0.0
    y = np.zeros((size, lanes.ny))
    y[:, :n] = rng.uniform(-np.pi, np.pi, (size, n))
    y[:, n : 2 * n] = np.where(lanes.locked, 0.0, rng.uniform(-2.0, 2.0, (size, n)))
    t = rng.uniform(0.0, 0.2, size - 1)
    rows = np.arange(size - 1)  # the last lane is not evaluated

    lean, lean_lam = engine.rhs(lanes, rows, t, y[rows])
    last = size - 1
    lanes.ramp[last] = 0.05  # a ramp, a viscous brake and a shorted motor, in the last lane
    lanes.viscous[last] = 1.0 / 300.0
    lanes.short_torque[last], lanes.short_speed[last] = 2.0, 150.0
    full, full_lam = engine.rhs(lanes, rows, t, y[rows])

    assert np.isfinite(lean).all() and np.abs(lean[:, n : 2 * n]).max() > 0.0
    np.testing.assert_array_equal(lean, full)
    np.testing.assert_array_equal(lean_lam, full_lam)
    # and the terms are live where a lane has them: the last lane's own torques change
    lanes.sign[last] = 1.0
    lanes.locked[last] = False
    y[last, n : 2 * n] = 1.0
    with_terms = engine.rhs(lanes, np.array([last]), np.array([0.01]), y[[last]])[0]
    lanes.ramp[last] = lanes.viscous[last] = lanes.short_torque[last] = 0.0
    without = engine.rhs(lanes, np.array([last]), np.array([0.01]), y[[last]])[0]
    assert not np.allclose(with_terms[:, 2 * n + 3 :], without[:, 2 * n + 3 :])
