"""Programs: reading CSV and Parquet, the checks, interpolation, speed override, the generator.

The shipped program ``programs/ur10_pick_place.csv`` is made by :func:`make_ur10_pick_place`;
``test_shipped_program_is_made_by_its_recipe`` makes it again and compares, so the file cannot
drift from its recipe. To write it anew (after changing the recipe)::

    PYTHONPATH=.:tests python -c "import test_program as t; t.write_ur10_pick_place()"
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import UR_JOINTS, robot

import vtm_pin.scene.program as program_module
from vtm_pin.cli import main
from vtm_pin.exceptions import InputError
from vtm_pin.scene.program import (
    PROGRAMS_DIR,
    Program,
    check_program,
    find_program,
    generate_program,
    read_program,
    write_program,
)
from vtm_pin.shipped import shipped_names

SHIPPED = PROGRAMS_DIR / "ur10_pick_place.csv"

# --- The shipped program's recipe -----------------------------------------------------------

_HALF_PI = math.pi / 2


def _tool_down(pan: float, lift: float, elbow: float, wrist_3: float = 0.0) -> list[float]:
    """A UR10 pose with the flange pointing straight down (wrist 1 makes up the arm's pitch)."""
    return [pan, lift, elbow, round(-(lift + elbow) - _HALF_PI, 4), -round(_HALF_PI, 4), wrist_3]


#: Pick-and-place cycle of the UR10 [rad], flange down; tool0 positions (base frame) from
#: Pinocchio's forward kinematics. Pick at 0.88 m reach, place a quarter turn away at 0.76 m,
#: the part turned 0.785 rad (45 deg) by wrist 3 on the way; each vertical move 0.2-0.25 m.
UR10_PICK_PLACE = {
    "approach (0.40 m above the floor, over the pick)": _tool_down(0.0, -1.211, 1.582),
    "pick (0.15 m)": _tool_down(0.0, -0.989, 1.755),
    "lift (back over the pick)": _tool_down(0.0, -1.211, 1.582),
    "move over (0.45 m, over the place)": _tool_down(1.571, -1.428, 1.768, 0.785),
    "place (0.25 m)": _tool_down(1.571, -1.259, 1.956, 0.785),
    "retreat (over the place)": _tool_down(1.571, -1.428, 1.768, 0.785),
    "return (to the approach: the cycle repeats)": _tool_down(0.0, -1.211, 1.582),
}
#: Joint speed limit: half the UR10's maximum (URDF velocity limits 2.16, 2.16, 3.15, 3.2,
#: 3.2, 3.2 rad/s), a brisk production speed that leaves the speed override room.
UR10_SPEED_FRACTION = 0.5
#: Joint acceleration limit [rad/s^2], ASSUMED: UR publishes no joint acceleration limit.
UR10_ACCELERATION = 2.0
#: Sample spacing [s].
UR10_DT = 0.02


def make_ur10_pick_place() -> Program:
    ur10 = robot("ur10")
    return generate_program(
        ur10,
        list(UR10_PICK_PLACE.values()),
        velocity_limit=UR10_SPEED_FRACTION * np.asarray(ur10.model.velocityLimit),
        acceleration_limit=UR10_ACCELERATION,
        dt=UR10_DT,
        stops=True,
        source="ur10_pick_place",
    )


def _comment() -> str:
    names = "; ".join(UR10_PICK_PLACE)
    return (
        "UR10 pick-and-place cycle, made by vtm_pin.scene.program.generate_program (toppra, "
        "time-optimal)\n"
        f"through 7 waypoints, stopping at each: {names}.\n"
        f"Joint speeds at most {UR10_SPEED_FRACTION:g} x the URDF velocity limits, joint "
        f"accelerations at most {UR10_ACCELERATION:g} rad/s^2 (assumed),\n"
        f"sampled every {UR10_DT:g} s and at each waypoint. Recipe and test: "
        "tests/test_program.py (make_ur10_pick_place)."
    )


def write_ur10_pick_place() -> Path:
    return write_program(make_ur10_pick_place(), SHIPPED, comment=_comment())


# --- Helpers --------------------------------------------------------------------------------

#: An analytic motion of every UR10 joint: q = Q0 + A sin(W t) [rad], v = A W cos(W t).
Q0 = np.array([0.0, -1.2, 1.4, -1.2, -1.57, 0.0])
AMPLITUDE, OMEGA = 0.6, 3.0  # [rad], [rad/s]: peak speed 1.8 rad/s, under every joint's limit


def _analytic(h: float, duration: float = 2.0, scale: float = 0.5) -> tuple[np.ndarray, ...]:
    """Samples every h of the analytic motion (amplitude ``scale`` x AMPLITUDE)."""
    t = np.arange(0.0, duration + h / 2, h)
    a = scale * AMPLITUDE
    q = Q0 + a * np.sin(OMEGA * t)[:, None]
    v = a * OMEGA * np.cos(OMEGA * t)[:, None] * np.ones(6)
    return t, q, v


def _frame(t: np.ndarray, q: np.ndarray, v: np.ndarray | None = None) -> pd.DataFrame:
    columns = {"time": t, **{j: q[:, i] for i, j in enumerate(UR_JOINTS)}}
    if v is not None:
        columns.update({f"v_{j}": v[:, i] for i, j in enumerate(UR_JOINTS)})
    return pd.DataFrame(columns)


def _csv(tmp_path: Path, frame: pd.DataFrame, name: str = "p.csv") -> Path:
    path = tmp_path / name
    frame.to_csv(path, index=False, float_format="%.12g")
    return path


def _refused(path: Path, **kwargs: object) -> InputError:
    with pytest.raises(InputError) as info:
        read_program(path, robot("ur10"), **kwargs)  # type: ignore[arg-type]
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(str(path))
    return info.value


# --- Reading --------------------------------------------------------------------------------


def test_reads_csv_with_velocities(tmp_path):
    t, q, v = _analytic(0.01)
    path = _csv(tmp_path, _frame(t, q, v))
    program = read_program(path, robot("ur10"))
    assert program.joint_names == UR_JOINTS
    assert program.velocity_method == "from the file's columns v_<joint>"
    assert program.source == str(path)
    np.testing.assert_allclose(program.t, t, rtol=0, atol=1e-11)
    np.testing.assert_allclose(program.q, q, rtol=0, atol=1e-11)
    np.testing.assert_allclose(program.v, v, rtol=0, atol=1e-11)
    assert program.duration == pytest.approx(2.0, abs=1e-12)
    with pytest.raises(ValueError, match="read-only"):
        program.q[0, 0] = 1.0


def test_reads_parquet_and_csv_alike(tmp_path):
    t, q, _ = _analytic(0.01)
    from_csv = read_program(_csv(tmp_path, _frame(t, q)), robot("ur10"))
    parquet = tmp_path / "p.parquet"
    _frame(t, q).to_parquet(parquet, index=False)
    from_parquet = read_program(parquet, robot("ur10"))
    np.testing.assert_allclose(from_parquet.q, q, rtol=0, atol=0)  # binary: no rounding
    # 12-digit rounding in the CSV, amplified by differentiation (most at a not-a-knot end)
    np.testing.assert_allclose(from_parquet.v, from_csv.v, rtol=0, atol=1e-8)
    assert from_parquet.velocity_method.startswith("differentiated from the positions")


def test_csv_comments_blank_lines_and_spaces_are_allowed(tmp_path):
    t, q, v = _analytic(0.1)
    path = tmp_path / "p.csv"
    text = _frame(t, q, v).to_csv(index=False).replace(",", ", ")
    path.write_text("# made by hand\n\n" + text.replace("\n", "\n\n", 1), encoding="utf-8")
    program = read_program(path, robot("ur10"))
    np.testing.assert_allclose(program.q, q, atol=1e-12)


def test_write_program_round_trips_within_its_10_digits(tmp_path):
    t, q, v = _analytic(0.01)
    first = Program(UR_JOINTS, t, q, v, "made", "analytic")
    for name in ("p.csv", "p.parquet"):
        again = read_program(write_program(first, tmp_path / name, "a\nb"), robot("ur10"))
        np.testing.assert_allclose(again.q, q, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(again.v, v, rtol=1e-9, atol=1e-12)
    assert (tmp_path / "p.csv").read_text().startswith("# a\n# b\ntime,shoulder_pan_joint,")


def test_velocities_from_positions_match_the_analytic_ones(tmp_path):
    """The spline derivative's error is O(h^3): at most h^3 A W^4 / 4 (Hall and Meyer's bound
    for the clamped cubic spline is h^3/24 max|q''''|; the not-a-knot ends reach about 0.12
    h^3 A W^4, measured), and it falls by about 8 when h is halved."""
    errors = []
    for h in (0.02, 0.01):
        t, q, v = _analytic(h, scale=1.0)
        program = read_program(_csv(tmp_path, _frame(t, q), f"{h}.csv"), robot("ur10"))
        errors.append(float(np.max(np.abs(program.v - v))))
        assert errors[-1] <= h**3 * AMPLITUDE * OMEGA**4 / 4
    assert errors[0] / errors[1] > 6


def test_state_at_interpolates_within_the_hermite_bounds():
    """Cubic Hermite interpolation of exact q and v: position error <= h^4/384 max|q''''|,
    velocity error <= sqrt(3) h^3/216 max|q''''| (both sharp for a sine)."""
    h = 0.05
    t, q, v = _analytic(h, scale=1.0)
    program = Program(UR_JOINTS, t, q, v, "analytic", "exact")
    fine = np.linspace(0.0, t[-1], 4001)
    q_fine, v_fine = program.state_at(fine)
    assert q_fine.shape == v_fine.shape == (4001, 6)
    q4 = AMPLITUDE * OMEGA**4
    assert np.max(np.abs(q_fine - (Q0 + AMPLITUDE * np.sin(OMEGA * fine)[:, None]))) <= (
        h**4 / 384 * q4 * (1 + 1e-9)
    )
    exact_v = AMPLITUDE * OMEGA * np.cos(OMEGA * fine)[:, None]
    assert np.max(np.abs(v_fine - exact_v)) <= math.sqrt(3) * h**3 / 216 * q4 * (1 + 1e-9)
    q_one, v_one = program.state_at(t[7])
    np.testing.assert_allclose(q_one, q[7], atol=1e-14)
    np.testing.assert_allclose(v_one, v[7], atol=1e-14)
    for outside in (-0.01, t[-1] + 0.01, math.nan):
        with pytest.raises(ValueError, match="within"):
            program.state_at(outside)


def test_scaled_stretches_time_and_slows_velocities():
    t, q, v = _analytic(0.02)
    program = Program(UR_JOINTS, t + 1.0, q, v, "analytic", "exact")
    slow = program.scaled(0.25)
    assert slow.duration == pytest.approx(4 * program.duration, rel=1e-14)
    assert slow.t[0] == program.t[0]
    np.testing.assert_array_equal(slow.q, program.q)
    np.testing.assert_allclose(slow.v, 0.25 * program.v, rtol=1e-15)
    assert "speed override 0.25" in slow.velocity_method
    check_program(slow, robot("ur10"))  # checked as given velocities: consistent with q
    # Velocities 4 x too fast for the stretched motion: at 0.08 s steps, the default 50 rad/s^2
    # allows 50 x 0.08^2 / 4 = 0.08 rad between q and the integrated v; 2 rad/s^2, 3.2 mrad.
    wrong = Program(UR_JOINTS, slow.t, slow.q, program.v, "made", "x")
    with pytest.raises(InputError, match="v_ columns must be the positions' time derivative"):
        check_program(wrong, robot("ur10"), acceleration_limit=2.0)
    mid = 1.0 + 0.731  # between samples: the same place, a quarter of the speed
    q_slow, v_slow = slow.state_at(1.0 + 4 * 0.731)
    q_fast, v_fast = program.state_at(mid)
    np.testing.assert_allclose(q_slow, q_fast, atol=1e-12)
    np.testing.assert_allclose(v_slow, 0.25 * v_fast, atol=1e-12)
    assert program.scaled(1.0).duration == program.duration
    for bad in (0.0, -0.5, 1.5, math.nan):
        with pytest.raises(ValueError, match=r"\(0, 1\]"):
            program.scaled(bad)


def test_peak_joint_speed_time():
    t = np.linspace(0.0, 1.0, 11)
    v = np.zeros((11, 6))
    v[3, 1], v[6, 4], v[8, 4] = -2.0, 1.5, 1.5
    program = Program(UR_JOINTS, t, np.zeros((11, 6)), v, "made", "given")
    assert program.peak_joint_speed_time() == pytest.approx(0.3)
    assert program.peak_joint_speed_time("wrist_2_joint") == pytest.approx(0.6)  # earliest
    with pytest.raises(ValueError, match="not one of"):
        program.peak_joint_speed_time("gripper")


# --- Bad files: one line naming the row and the column --------------------------------------


def _slow() -> pd.DataFrame:
    t, q, v = _analytic(0.01, scale=0.2)
    return _frame(t, q, v)


def _set(row: int, column: str, value: object):
    def change(frame: pd.DataFrame) -> pd.DataFrame:
        frame = frame.astype(object)
        frame.loc[row - 1, column] = value
        return frame

    return change


def _step(row: int, column: str, by: float):
    """Add ``by`` to ``column`` from ``row`` on."""

    def change(frame: pd.DataFrame) -> pd.DataFrame:
        frame = frame.copy()
        frame.loc[row - 1 :, column] += by
        return frame

    return change


BAD_FRAMES = {
    "unknown column": (
        lambda f: f.assign(gripper=0.0),
        "column gripper",
        "is not a column of a program for ur10; the columns are time, the joints "
        "(shoulder_pan_joint, shoulder_lift_joint, elbow_joint, wrist_1_joint, wrist_2_joint, "
        "wrist_3_joint) and optionally v_<joint> for every joint",
    ),
    "missing joint": (lambda f: f.drop(columns="elbow_joint"), "column elbow_joint", "missing"),
    "missing time": (lambda f: f.drop(columns="time"), "column time", "is missing"),
    "some velocities only": (
        lambda f: f.drop(columns="v_wrist_3_joint"),
        "column v_wrist_3_joint",
        "given for some joints, so for every joint",
    ),
    "text": (
        _set(12, "shoulder_lift_joint", "abc"),
        "row 12, column shoulder_lift_joint",
        "'abc' is not a number",
    ),
    "empty cell": (_set(3, "elbow_joint", ""), "row 3, column elbow_joint", "is empty"),
    "nan": (_set(5, "v_elbow_joint", "nan"), "row 5, column v_elbow_joint", "nan is not a finite"),
    "infinity": (_set(5, "time", "1e999"), "row 5, column time", "is not a finite number"),
    "time repeats": (_set(4, "time", 0.02), "row 4, column time", "must increase strictly"),
    "one row": (lambda f: f.iloc[:1], "", "has 1 row; a program needs at least 2"),
    "outside the limits": (
        _set(7, "elbow_joint", 3.5),
        "row 7, column elbow_joint",
        "3.5 rad is outside the joint's limits [-3.14159, 3.14159] rad",
    ),
    "too fast": (
        _set(9, "v_shoulder_pan_joint", -2.5),
        "row 9, column v_shoulder_pan_joint",
        "-2.5 rad/s is above the joint's velocity limit 2.16 rad/s",
    ),
    "velocity jump": (
        _step(20, "v_wrist_1_joint", 1.0),
        "row 20, column v_wrist_1_joint",
        "above the acceleration limit 50 rad/s^2",
    ),
    "velocities not the derivative": (
        lambda f: f.assign(v_elbow_joint=f["v_elbow_joint"] * 4),
        "row 2, column v_elbow_joint",
        "v_ columns must be the positions' time derivative",
    ),
}


@pytest.mark.parametrize("case", list(BAD_FRAMES))
def test_bad_values_are_refused_naming_row_and_column(tmp_path, case):
    change, key, words = BAD_FRAMES[case]
    path = _csv(tmp_path, change(_slow()))
    error = _refused(path)
    assert error.key == key
    assert words in error.problem


def test_differentiated_speed_and_acceleration_are_checked(tmp_path):
    t, q, _ = _analytic(0.01, scale=0.2)
    jump = q.copy()
    jump[30:, 2] += 0.05  # a step: 5 rad/s through the spline
    error = _refused(_csv(tmp_path, _frame(t, jump), "jump.csv"))
    assert error.key in ("row 30, column elbow_joint", "row 31, column elbow_joint")  # either side
    assert "the velocity differentiated from the positions" in error.problem
    noisy = q.copy()
    noisy[40, 3] += 0.003  # 3 mrad of noise: slow, but 100s of rad/s^2
    error = _refused(_csv(tmp_path, _frame(t, noisy), "noisy.csv"))
    assert error.key == "row 41, column wrist_1_joint"
    assert "acceleration differentiated from the positions" in error.problem
    assert "(noisy positions? give v_ columns)" in error.problem
    path = _csv(tmp_path, _frame(t, q), "smooth.csv")
    read_program(path, robot("ur10"))
    error = _refused(path, acceleration_limit=0.1)  # 0.2 x 0.6 x 9 = 1.08 rad/s^2 at most
    assert error.problem.endswith("limit 0.1 rad/s^2 (noisy positions? give v_ columns)")


def test_duplicate_columns_are_refused(tmp_path):
    path = tmp_path / "p.csv"
    text = _slow().to_csv(index=False)
    header, rest = text.split("\n", 1)
    path.write_text(header.replace("wrist_3_joint,v_", "time,v_", 1) + "\n" + rest)
    error = _refused(path)
    assert error.key == "column time"
    assert error.problem == "is given twice (columns 1 and 7)"


@pytest.mark.parametrize(
    ("content", "words"),
    [
        (b"", "is empty"),
        (b"time,a\n1,2\n3,4,5\n", "is not a CSV table (Error tokenizing data. C error: Expected 2"),
        (b"time\n\xff\xfe\n", "is not a CSV table ("),
    ],
)
def test_unreadable_csv_is_one_line(tmp_path, content, words):
    path = tmp_path / "p.csv"
    path.write_bytes(content)
    assert words in str(_refused(path))


def test_garbage_parquet_is_one_line(tmp_path):
    path = tmp_path / "p.parquet"
    path.write_bytes(b"time,shoulder_pan_joint\n0,0\n")
    assert "is not a Parquet table (" in _refused(path).problem


def test_parquet_text_and_booleans_are_not_numbers(tmp_path):
    frame = _slow()
    frame["elbow_joint"] = frame["elbow_joint"].astype(str)
    frame.loc[6, "elbow_joint"] = "1,4"
    path = tmp_path / "p.parquet"
    frame.to_parquet(path, index=False)
    error = _refused(path)
    assert (error.key, error.problem) == ("row 7, column elbow_joint", "'1,4' is not a number")
    frame = _slow()
    frame["wrist_3_joint"] = frame["wrist_3_joint"] > 0
    frame.to_parquet(path, index=False)
    assert _refused(path).key == "row 1, column wrist_3_joint"


def test_size_limits(tmp_path, monkeypatch):
    path = _csv(tmp_path, _slow())
    monkeypatch.setattr(program_module, "MAX_ROWS", 50)
    assert "has more than 50 rows" in str(_refused(path))
    parquet = tmp_path / "p.parquet"
    _slow().to_parquet(parquet, index=False)
    assert "has 201 rows; a program has at most 50" in str(_refused(parquet))
    monkeypatch.setattr(program_module, "MAX_PROGRAM_BYTES", 1000)
    assert "bytes; at most 1000 are read" in str(_refused(path))


def test_missing_files_folders_and_pipes_are_refused(tmp_path):
    assert "cannot read the file" in str(_refused(tmp_path / "none.csv"))
    assert "is a folder, not a regular file" in str(_refused(tmp_path))
    if hasattr(os, "mkfifo"):
        fifo = tmp_path / "pipe.csv"
        os.mkfifo(fifo)  # refused at once, not read (which would block)
        assert "named pipe (FIFO)" in str(_refused(fifo))


# --- The generator --------------------------------------------------------------------------


def _finite_difference_accelerations(program: Program) -> np.ndarray:
    return np.abs(np.diff(program.v, axis=0)) / np.diff(program.t)[:, None]


@pytest.mark.parametrize("stops", [True, False])
def test_generator_keeps_the_limits_and_reaches_the_waypoints(stops):
    ur10 = robot("ur10")
    waypoints = np.array(list(UR10_PICK_PLACE.values()))[[0, 1, 3, 4]]
    vlimit = np.array([1.0, 0.8, 1.2, 1.5, 1.5, 1.5])
    program = generate_program(ur10, waypoints, vlimit, 3.0, dt=0.01, stops=stops)
    # The samples keep the limits exactly (the generator stretches time until they do).
    assert np.all(np.abs(program.v) <= vlimit)
    assert np.all(_finite_difference_accelerations(program) <= 3.0)
    # Time-optimal: some joint runs at its speed or acceleration limit (toppra's tolerance
    # and the sampling: within 1 %).
    assert np.max(np.abs(program.v) / vlimit) > 0.99
    np.testing.assert_allclose(program.q[[0, -1]], waypoints[[0, -1]], atol=1e-9)
    np.testing.assert_allclose(program.v[[0, -1]], 0.0, atol=1e-9)
    if stops:  # at rest on every waypoint, in order
        for point in waypoints:
            at = np.flatnonzero(np.all(np.abs(program.q - point) < 1e-9, axis=1))
            assert at.size, point
            np.testing.assert_allclose(program.v[at], 0.0, atol=1e-9)
    else:  # passes each waypoint between two samples (within half a step at full speed)
        for point in waypoints[1:-1]:
            distance = np.max(np.abs(program.q - point), axis=1)
            assert np.min(distance) <= vlimit.max() * 0.01 / 2
            assert np.max(np.abs(program.v[np.argmin(distance)])) > 0.05  # without stopping
    assert "toppra" in program.velocity_method


def test_straight_move_takes_the_analytic_time():
    """One joint, 1 rad at 1 rad/s and 2 rad/s^2: 0.5 s up, 0.5 s cruising, 0.5 s down."""
    ur10 = robot("ur10")
    start = np.array(UR10_PICK_PLACE["pick (0.15 m)"])
    end = start + np.array([1.0, 0, 0, 0, 0, 0])
    program = generate_program(ur10, [start, end], 1.0, 2.0, dt=0.01)
    assert program.duration == pytest.approx(1.5, abs=1e-6)  # toppra's solver tolerance
    np.testing.assert_allclose(program.q[:, 1:], np.tile(start[1:], (len(program.t), 1)))


@pytest.mark.parametrize(
    ("waypoints", "kwargs", "key", "words"),
    [
        ([[0.0] * 6], {}, "waypoints", "at least 2 rows of 6 joint positions"),
        ([[0.0] * 6, [0.0, 0.0, 4.0, 0, 0, 0]], {}, "waypoints[1][2]", "elbow_joint's limits"),
        ([[0.0] * 6, [0.0] * 6], {}, "waypoints[1]", "is the previous waypoint again"),
        ([[0.0] * 6, [0.1] * 6], {"velocity_limit": 3.0}, "velocity_limit", "at most the robot's"),
        ([[0.0] * 6, [0.1] * 6], {"acceleration_limit": -1}, "acceleration_limit", "positive"),
        ([[0.0] * 6, [0.1] * 6], {"dt": 0.0}, "dt", "positive number of seconds"),
    ],
)
def test_generator_refuses_bad_inputs(waypoints, kwargs, key, words):
    with pytest.raises(InputError) as info:
        generate_program(robot("ur10"), waypoints, **kwargs)
    assert info.value.key == key
    assert words in info.value.problem


def test_generator_without_toppra_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "toppra", None)  # import toppra raises ImportError
    extra = r"needs toppra, not installed: pip install 'vtm_pin\[program\]'"
    with pytest.raises(InputError, match=extra):
        generate_program(robot("ur10"), [[0.0] * 6, [0.1] * 6])


# --- The shipped program --------------------------------------------------------------------


def test_shipped_program_loads_and_keeps_its_limits():
    ur10 = robot("ur10")
    program = read_program(SHIPPED, ur10, acceleration_limit=UR10_ACCELERATION)
    assert shipped_names("program") == ["ur10_pick_place"]
    assert 200 <= len(program.t) <= 1000  # a few hundred rows
    assert program.velocity_method == "from the file's columns v_<joint>"
    vlimit = UR10_SPEED_FRACTION * np.asarray(ur10.model.velocityLimit)
    assert np.all(np.abs(program.v) <= vlimit * (1 + 1e-9))  # 10 significant digits
    np.testing.assert_allclose(program.q[0], program.q[-1])  # a cycle
    np.testing.assert_allclose(program.v[[0, -1]], 0.0, atol=1e-12)
    assert program.peak_joint_speed_time("shoulder_pan_joint") > 0


def test_shipped_program_is_made_by_its_recipe():
    """toppra's result is deterministic here; 1e-7 covers the file's 10 significant digits and
    solver differences between toppra versions far below anything a stop study resolves."""
    made = make_ur10_pick_place()
    shipped = read_program(SHIPPED, robot("ur10"))
    assert len(shipped.t) == len(made.t)
    np.testing.assert_allclose(shipped.t, made.t, rtol=0, atol=1e-7)
    np.testing.assert_allclose(shipped.q, made.q, rtol=0, atol=1e-7)
    np.testing.assert_allclose(shipped.v, made.v, rtol=0, atol=1e-7)
    comment = [line[2:] for line in SHIPPED.read_text().splitlines() if line.startswith("# ")]
    assert comment == _comment().splitlines()


def test_find_program_takes_a_path_or_a_shipped_name(tmp_path):
    assert find_program("ur10_pick_place") == SHIPPED
    assert find_program("ur10_pick_place.csv") == SHIPPED
    mine = tmp_path / "mine.csv"
    assert find_program(mine) == mine  # not there: reading it will say so
    with pytest.raises(InputError) as info:
        find_program("ur10_pick")
    assert str(info.value) == (
        "ur10_pick: no such file, and not the name of a shipped program (ur10_pick_place)"
    )


def test_init_copies_the_shipped_program(tmp_path, capsys):
    assert main(["init", "program", "ur10_pick_place", "--to", str(tmp_path)]) == 0
    copy = tmp_path / "ur10_pick_place.csv"
    assert capsys.readouterr().out == f"wrote {copy}\n"
    assert copy.read_bytes() == SHIPPED.read_bytes()
    assert len(read_program(copy, robot("ur10")).t) > 2
    assert main(["init", "program", "ur10_pick_place.csv", "--to", str(tmp_path)]) == 1
    assert "exists; nothing copied" in capsys.readouterr().err
