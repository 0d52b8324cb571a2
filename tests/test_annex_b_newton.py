"""The Annex-B pose by Newton's method on the KKT system (issue 27), against the SLSQP path.

For e < 1 the pose nearest to the guess is found by Newton's method on the KKT conditions of
min |x - g|^2 / 2 subject to r(x) = e R, h(x) = 0; SLSQP (the earlier method, kept) decides
when Newton does not reach a regular local minimum along a path within the limits. The SLSQP
pose is obtained here by switching Newton off (``annex_b._newton`` returning None).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin
import pytest
import yaml
from conftest import SCENARIOS, robot
from hypothesis import given, settings
from hypothesis import strategies as st

from vtm_pin.physics.payload import Payload, attach_payload
from vtm_pin.scene import annex_b
from vtm_pin.scene.annex_b import (
    DIRECTIONS,
    RESIDUAL_TOL,
    Conditions,
    compute_test_state,
    extension_pose,
    horizontal_reach,
    max_reach,
)

#: [rad] Newton's and SLSQP's poses agree to this. SLSQP stops once |x - g|^2 / 2 changes by
#: less than POSE_FTOL = 1e-10 rad^2 in an iteration; near a minimum whose reduced Hessian has
#: curvature kappa ~ 0.02-1 that leaves x within sqrt(2 POSE_FTOL / kappa) ~ 1.4e-5-1e-4 rad of
#: it (Newton's pose is the minimum to round-off). Measured on these draws: at most ~5e-6 rad.
POSE_AGREE = 1.0e-4
#: [rad] Newton's distance to the guess may exceed SLSQP's by this at most: both poses meet
#: the constraints to <= RESIDUAL_TOL = 1e-9 m, and a pose that meets them only to that can be
#: nearer than the exact minimum by |lambda| x 1e-9 m (multipliers of a few rad/m). Measured:
#: at most ~1e-12 rad.
DISTANCE_SLACK = 1.0e-9
#: [m] Step of the central differences of dr, dh: their truncation error is ~h^2 |d4 p| ~ 1e-12
#: and their round-off ~1e-16 |dr| / h ~ 1e-10, both far below the 1e-6 tolerance.
FD_STEP, FD_TOL = 1.0e-6, 1.0e-6
#: The UR10 Annex-B base: its guess and the payload classes of studies/ur10_envelope.yaml.
UR10_GUESS = np.array(
    yaml.safe_load((SCENARIOS / "ur10_annex_b.yaml").read_text())["initial"]["q"], dtype=float
)
PAYLOADS = (0.0, 2.0, 4.0, 6.0, 8.0, 10.0)  # [kg]


def slsqp_only(monkeypatch: pytest.MonkeyPatch) -> None:
    """Switch Newton off: every pose is SLSQP's (the path before issue 27)."""
    monkeypatch.setattr(annex_b, "_newton", lambda *args: None)


def spy_newton(monkeypatch: pytest.MonkeyPatch) -> list[bool]:
    """Record, per Newton solve, whether it returned a pose."""
    calls: list[bool] = []
    newton = annex_b._newton

    def spy(*args):
        out = newton(*args)
        calls.append(out is not None)
        return out

    monkeypatch.setattr(annex_b, "_newton", spy)
    return calls


def fresh_pose(r, e: float, g: np.ndarray) -> np.ndarray:
    annex_b._POSE_CACHE.clear()  # the two methods must each solve, not recall the other's pose
    return extension_pose(r, r.tool_frame, e, g)


def assert_meets_constraints(r, q: np.ndarray, e: float, g: np.ndarray) -> None:
    """r(q) = e R and the tool in the shoulder plane, both to RESIDUAL_TOL."""
    R = max_reach(r, r.tool_frame, g)
    assert abs(horizontal_reach(r, r.tool_frame, q) - e * R) <= RESIDUAL_TOL
    chain = annex_b._chain(r.model, r.tool_frame)
    assert abs(annex_b._Evaluator(r.model, chain, q).h) <= RESIDUAL_TOL


@pytest.mark.parametrize("name", ["ur10", "panda", "rx160l"])
def test_the_hessians_of_r_and_h_match_central_differences(name):
    # The Lagrangian's Hessian with multipliers (1, 0) and (0, 1), less the identity.
    r = robot(name)
    chain = annex_b._chain(r.model, r.tool_frame)
    lo, hi = r.model.lowerPositionLimit, r.model.upperPositionLimit
    rng = np.random.default_rng(27)
    for _ in range(3):
        q = rng.uniform(np.maximum(lo, -3.0), np.minimum(hi, 3.0))
        ev = annex_b._Evaluator(r.model, chain, q)
        x = q[chain.free]
        ev.at(x)
        eye = np.eye(len(x))
        Hr = ev.lagrangian_hessian(np.array([1.0, 0.0])) - eye  # d2r
        Hh = ev.lagrangian_hessian(np.array([0.0, 1.0])) - eye  # d2h
        for i in range(len(x)):
            step = np.zeros(len(x))
            step[i] = FD_STEP
            up = ev.at(x + step)
            dr_up, dh_up = up.dr.copy(), up.dh.copy()
            down = ev.at(x - step)
            np.testing.assert_allclose(Hr[i], (dr_up - down.dr) / (2 * FD_STEP), atol=FD_TOL)
            np.testing.assert_allclose(Hh[i], (dh_up - down.dh) / (2 * FD_STEP), atol=FD_TOL)


@settings(max_examples=20, deadline=None, derandomize=True, database=None)
@given(
    joint=st.sampled_from(["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]),
    extension=st.floats(0.3, 1.0, exclude_max=True),
    payload=st.sampled_from(PAYLOADS),
    direction=st.sampled_from(DIRECTIONS),
)
def test_newton_gives_slsqps_pose_on_the_ur10_annex_b_base(joint, extension, payload, direction):
    r = robot("ur10")
    if payload > 0.0:
        r = attach_payload(r, Payload(mass=payload, com=(0.0, 0.0, 0.05), frame=r.tool_frame))
    conditions = Conditions(joint, extension=extension, direction=direction)
    with pytest.MonkeyPatch.context() as mp:
        calls = spy_newton(mp)
        annex_b._POSE_CACHE.clear()
        new = compute_test_state(r, r.tool_frame, conditions, UR10_GUESS)
    assert calls == [True]  # Newton's pose is the one taken
    with pytest.MonkeyPatch.context() as mp:
        slsqp_only(mp)
        annex_b._POSE_CACHE.clear()
        old = compute_test_state(r, r.tool_frame, conditions, UR10_GUESS)
    assert_meets_constraints(r, new.q, extension, UR10_GUESS)
    near_new = np.linalg.norm(new.q - UR10_GUESS)
    assert near_new <= np.linalg.norm(old.q - UR10_GUESS) + DISTANCE_SLACK
    np.testing.assert_allclose(new.q, old.q, rtol=0.0, atol=POSE_AGREE)
    assert new.speed == old.speed and new.vertical == old.vertical


@pytest.mark.parametrize(
    ("name", "g"),
    [("ur5_cb3", np.zeros(6)), ("ur5", np.array([0.0, -1.2, 1.4, -1.2, -1.57, 0.0]))],
)
def test_newton_gives_slsqps_pose_on_the_ur5_arms(name, g, monkeypatch):
    # ur5_cb3 with its Annex-B scenario's guess (none: the zero pose), seeded extensions.
    r = robot(name)
    for e in np.random.default_rng(5).uniform(0.3, 1.0, 6):
        calls = spy_newton(monkeypatch)
        new = fresh_pose(r, e, g)
        assert calls == [True]
        monkeypatch.undo()
        slsqp_only(monkeypatch)
        old = fresh_pose(r, e, g)
        monkeypatch.undo()
        assert_meets_constraints(r, new, e, g)
        assert np.linalg.norm(new - g) <= np.linalg.norm(old - g) + DISTANCE_SLACK
        np.testing.assert_allclose(new, old, rtol=0.0, atol=POSE_AGREE)


def test_an_active_joint_limit_falls_back_to_slsqp(monkeypatch):
    # At e = 0.6 the UR10's nearest pose opens the elbow by ~0.2 rad from the guess (1.4 rad):
    # with the elbow limited to 1.45 rad the nearest pose has the elbow on its limit. Newton's
    # path leaves the limits, so SLSQP (bounded) decides, and its pose is the one taken.
    base = robot("ur10")
    model = pin.Model(base.model)
    upper = model.upperPositionLimit.copy()
    upper[2] = 1.45  # [rad]
    model.upperPositionLimit = upper
    r = dataclasses.replace(base, model=model)
    slsqp_calls = []
    slsqp = annex_b._slsqp
    monkeypatch.setattr(annex_b, "_slsqp", lambda *a: slsqp_calls.append(1) or slsqp(*a))
    newton_calls = spy_newton(monkeypatch)
    q = fresh_pose(r, 0.6, UR10_GUESS)
    assert newton_calls == [False] and slsqp_calls
    assert q[2] == 1.45  # on the limit
    assert_meets_constraints(r, q, 0.6, UR10_GUESS)
    monkeypatch.setattr(annex_b, "_newton", lambda *args: None)
    np.testing.assert_array_equal(q, fresh_pose(r, 0.6, UR10_GUESS))


def test_the_folded_rx160l_falls_back_to_slsqp(monkeypatch):
    # From its zero guess (straight up) at e = 0.12, near its smallest reach (0.101 R), the
    # RX160L's nearest pose folds the elbow onto its limit: Newton gives up, SLSQP's pose is
    # taken unchanged.
    r, g = robot("rx160l"), np.zeros(6)
    calls = spy_newton(monkeypatch)
    q = fresh_pose(r, 0.12, g)
    assert calls == [False]
    assert_meets_constraints(r, q, 0.12, g)
    slsqp_only(monkeypatch)
    np.testing.assert_array_equal(q, fresh_pose(r, 0.12, g))


def test_newton_out_of_iterations_falls_back_to_slsqp(monkeypatch):
    # One Newton iteration cannot converge from the guess: SLSQP's pose is taken, bit for bit.
    r = robot("ur10")
    monkeypatch.setattr(annex_b, "NEWTON_MAXITER", 1)
    calls = spy_newton(monkeypatch)
    q = fresh_pose(r, 0.5, UR10_GUESS)
    assert calls == [False]
    monkeypatch.setattr(annex_b, "_newton", lambda *args: None)
    np.testing.assert_array_equal(q, fresh_pose(r, 0.5, UR10_GUESS))


def test_full_extension_keeps_the_slsqp_path(monkeypatch):
    calls = spy_newton(monkeypatch)
    fresh_pose(robot("ur10"), 1.0, UR10_GUESS)
    assert calls == []


def test_a_maximizer_is_not_a_regular_point(monkeypatch):
    # At a pose of maximum reach dr and dh are parallel (a constrained maximum of r): Newton's
    # regularity check refuses it, whatever the multipliers.
    r = robot("ur10")
    model, chain = r.model, annex_b._chain(r.model, r.tool_frame)
    reach = annex_b._max_reach(model, chain, UR10_GUESS)
    ev = annex_b._Evaluator(model, chain, UR10_GUESS)
    assert not annex_b._regular_minimum(ev, reach.poses[0], np.zeros(2))
    # The pose Newton returns passes it, with the multipliers of its KKT point.
    x = annex_b._newton(ev, UR10_GUESS[chain.free], 0.5 * reach.R, annex_b._bounds(model, chain))
    assert x is not None
    ev.at(x)
    lam = -np.linalg.lstsq(np.array([ev.dr, ev.dh]).T, x - UR10_GUESS[chain.free], rcond=None)[0]
    assert annex_b._regular_minimum(ev, x, lam)
