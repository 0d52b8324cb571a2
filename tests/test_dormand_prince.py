"""The one Dormand-Prince step of both engines: many lanes step each as one lane alone.

``vtm_pin.numerics.integrators.dormand_prince`` is written once for one lane (a state vector,
floats: the scalar engine) and for many (states (lanes, n): the batched engine). Each lane of a
batched call must be the one-lane call on that lane's values: the controller's factors
exactly (the same IEEE operations on each element), the step and its dense output to the
round-off of a sum taken in another order (a per-lane matrix product against a vector dot,
and this right-hand side's own matrix product for one row or many).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from vtm_pin.numerics.integrators import dormand_prince as dp

#: Agreement of a lane with the one-lane call, relative to the states and stages (~1 here)
#: [-]: a few ulps of a 13-term sum taken in another order. The dense coefficients F[3:] and
#: the error estimates are sums with cancellation (differences of stages of size ~1), so they
#: are compared in absolute terms against that size.
ROUND_OFF = 1e-13
#: Error norms [-]: the estimate's round-off (~1e-16 of stages ~1, times h ~0.2) over the
#: tolerance rtol |y| + atol ~1e-8 is ~2e-9 of the norm, which is compared with 1; measured
#: 2e-10.
NORM_ROUND_OFF = 1e-8
RTOL, ATOL = 1e-8, 1e-10  # [-], [state units]

#: y' = M y + sin(t) b for a lane: a damped, driven oscillator pair (4 states).
M = np.array([[0, 0, 1, 0], [0, 0, 0, 1], [-4, 1, -0.1, 0], [1, -2, 0, -0.3]], dtype=float)
DRIVE = np.array([0.0, 0.0, 1.0, 0.5])


def f(t: float | np.ndarray, y: np.ndarray) -> np.ndarray:
    """The right-hand side of one lane (t a float, y (4,)) or many (t (L,), y (L, 4))."""
    return y @ M.T + np.multiply.outer(np.sin(t), DRIVE)


def into(t: float | np.ndarray, y: np.ndarray, out: np.ndarray) -> None:
    out[...] = f(t, y)


T = np.array([0.0, 0.3, 1.7])  # [s]
H = np.array([0.05, 0.2, 0.01])  # [s]
Y = np.array([[1.0, 0.0, 0.0, 0.5], [0.2, -0.4, 1.0, 0.0], [0.0, 0.0, 0.0, 0.0]])


def one_lane_step(b: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Lane b stepped alone: new state, stages, error norm."""
    work = dp.Stages(4)
    work.K[0] = f(T[b], Y[b])
    y_new = dp.step(into, float(T[b]), Y[b], float(H[b]), work)
    err = dp.error_norm(Y[b], y_new, float(H[b]), work.K, RTOL, ATOL, dp.ONE_LANE, 4)
    return y_new, work.K.copy(), err


def test_each_lane_steps_as_it_would_alone() -> None:
    work = dp.Stages(4, lanes=3)
    work.K[:, 0] = f(T, Y)
    y_new = dp.step(into, T, Y, H, work)
    err = dp.error_norm(Y, y_new, H, work.K, RTOL, ATOL, dp.LANES, np.full(3, 4))
    for b in range(3):
        alone, K, err_alone = one_lane_step(b)
        np.testing.assert_allclose(y_new[b], alone, rtol=ROUND_OFF, atol=1e-300)
        np.testing.assert_allclose(work.K[b, : dp.S + 1], K[: dp.S + 1], rtol=ROUND_OFF)
        assert isinstance(err_alone, float)
        assert abs(err[b] - err_alone) <= NORM_ROUND_OFF
    # the two outer lanes need smaller steps at these tolerances, the one from rest does not
    assert err[2] < 1.0


def test_dense_output_of_each_lane_is_its_own() -> None:
    work = dp.Stages(4, lanes=3)
    work.K[:, 0] = f(T, Y)
    y_new = dp.step(into, T, Y, H, work)
    K = work.K.copy()
    F = dp.dense_coefficients(into, T, Y, y_new, H, K, dp.LANES)
    x = np.array([0.0, 0.37, 1.0])
    lanes = dp.dense_value(F, x, Y, dp.LANES)
    for b in range(3):
        alone, K1, _ = one_lane_step(b)
        F1 = dp.dense_coefficients(into, float(T[b]), Y[b], alone, float(H[b]), K1, dp.ONE_LANE)
        np.testing.assert_allclose(F[b], F1, rtol=0.0, atol=ROUND_OFF)
        value = dp.dense_value(F1, float(x[b]), Y[b], dp.ONE_LANE)
        np.testing.assert_allclose(lanes[b], value, rtol=0.0, atol=ROUND_OFF)
    # the extension ends on the step's ends: y at x = 0, y_new at x = 1 (to round-off)
    np.testing.assert_array_equal(lanes[0], Y[0])
    np.testing.assert_allclose(lanes[2], y_new[2], rtol=0.0, atol=ROUND_OFF)


#: Error norms of accepted steps (<= 1, a zero among them) and of rejected ones.
ACCEPTED = [0.0, 1e-12, 4e-9, 5e-9, 0.3, 1.0]
REJECTED = [1.0 + 1e-15, 7.5, 1e6, math.inf, math.nan]


def test_controller_factors_are_the_same_for_one_lane_and_many() -> None:
    for rejected in (False, True):
        grow = dp.grow(np.array(ACCEPTED), np.full(len(ACCEPTED), rejected), dp.LANES)
        for e, g in zip(ACCEPTED, grow, strict=True):
            assert dp.grow(e, rejected, dp.ONE_LANE) == g
    shrink = dp.shrink(np.array(REJECTED), dp.LANES)
    for e, s in zip(REJECTED, shrink, strict=True):
        assert dp.shrink(e, dp.ONE_LANE) == s
    # DOP853's constants: the largest growth for a zero error (10, 1 right after a
    # rejection), 0.9 err^(-1/8) between, the smallest shrink for a non-finite error
    assert dp.grow(0.0, False, dp.ONE_LANE) == 10.0
    assert dp.grow(0.0, True, dp.ONE_LANE) == 1.0
    assert dp.grow(0.3, False, dp.ONE_LANE) == 0.9 * 0.3**-0.125
    assert dp.shrink(math.nan, dp.ONE_LANE) == dp.shrink(math.inf, dp.ONE_LANE) == 0.2


def test_last_step_lands_on_the_end_for_one_lane_and_many() -> None:
    t = np.array([0.0, 0.95, 1.0 - 1e-15])
    h = np.array([0.1, 0.1, 0.1])
    steps, last = dp.clamp(t, 1.0, h, 0.08, dp.LANES)
    for b in range(3):
        one, one_last = dp.clamp(float(t[b]), 1.0, float(h[b]), 0.08, dp.ONE_LANE)
        assert (one, one_last) == (steps[b], last[b])
    # max_step 0.08 s caps the first; the others end exactly on t1 = 1 s
    assert list(last) == [False, True, True] and steps[0] == 0.08
    assert t[1] + steps[1] == 1.0 and t[2] + steps[2] == 1.0


def test_first_step_guess_of_each_lane_is_its_own() -> None:
    tolerances = (RTOL, ATOL, 0.5)
    active = np.ones_like(Y, dtype=bool)
    spans = np.array([2.0, 2.0, 1e-3])
    lanes = dp.first_step(f, T, Y, f(T, Y), spans, tolerances, dp.LANES, np.full(3, 4), active)
    for b in range(3):
        one = dp.first_step(
            f, float(T[b]), Y[b], f(T[b], Y[b]), float(spans[b]), tolerances, dp.ONE_LANE, 4
        )
        assert one == pytest.approx(lanes[b], rel=ROUND_OFF)
    # from rest (y = 0): 100 times the trial step of 1e-6 s; a 1 ms span would cap it
    assert lanes[2] == pytest.approx(1e-4, rel=1e-12)
    capped = dp.first_step(f, 0.0, Y[2], f(0.0, Y[2]), 5e-5, tolerances, dp.ONE_LANE, 4)
    assert capped == 5e-5
