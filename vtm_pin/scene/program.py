"""Robot programs: the joint trajectory q(t), v(t) a robot runs, read from a file or generated.

A program is a table with one row per sample: ``time`` [s], one column per joint of the
robot, named as the robot names it, holding its position [rad] (or [m] for a prismatic
joint), and optionally ``v_<joint>`` columns with its velocity [rad/s] (or [m/s]), given for
every joint or for none. :func:`read_program` reads it from CSV or Parquet and refuses, in one
line naming the row and the column, what is not a motion the robot can run:

* missing, unknown or duplicate columns (other columns are refused, not ignored, so that a
  misspelt joint is not silently dropped; the message lists the allowed names);
* cells that are not finite numbers, time that does not increase strictly (it may start
  anywhere; :meth:`Program.scaled` keeps the start), fewer than 2 rows,
  more than :data:`MAX_ROWS` rows, files larger than :data:`MAX_PROGRAM_BYTES`;
* positions outside the joint limits, velocities above the velocity limits of the robot's
  model (URDF ``<limit velocity>``), accelerations above ``acceleration_limit`` (default
  :data:`ACCELERATION_LIMIT`: robot data files give no acceleration limits), and ``v_``
  columns that are not the derivative of the positions (see :func:`read_program`).

Without ``v_`` columns the velocities are differentiated from the positions: they are the
derivative of the not-a-knot cubic spline through the samples (scipy ``CubicSpline``), exact
for cubic motion and O(h^3) accurate for smooth motion sampled every h seconds.

:func:`generate_program` makes a program through joint waypoints, time-optimal under velocity
and acceleration limits (toppra, the optional extra ``vtm_pin[program]``); the shipped
``ur10_pick_place`` program was made with it (see ``tests/test_program.py``, which makes it
again and compares it to the shipped file).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import pandas as pd

from ..exceptions import InputError, excerpt
from ..files.inputs import find_shipped, open_regular
from ..physics.robot import Robot

#: Most rows a program may have (a 10-minute program sampled at 4 ms has 150,000).
MAX_ROWS = 200_000
#: Largest program file read [bytes] (200,000 rows of 13 columns in CSV are about 30 MB).
MAX_PROGRAM_BYTES = 100_000_000
#: Default bound on joint accelerations [rad/s^2] (or [m/s^2]) when reading or generating a
#: program. Robot data files give no acceleration limits; this generous bound (an industrial
#: arm's joints reach a few to a few tens of rad/s^2) refuses noisy or corrupt data, not
#: brisk motion. Give ``acceleration_limit`` for a tighter one.
ACCELERATION_LIMIT = 50.0
#: Relative slack on the position, velocity and acceleration limits: values written with 10
#: significant digits, and toppra's own tolerance, may exceed a limit by rounding.
LIMIT_RTOL = 1.0e-6
#: Absolute slack [rad] (or [m]) of the check that ``v_`` columns are the derivative of the
#: positions: rounding of positions and times written with 10 significant digits.
CONSISTENCY_ATOL = 1.0e-6
#: A limit per joint: one value for all joints, one per joint, or None for the default.
Limit = float | Sequence[float] | np.ndarray | None
#: Suffixes read as Parquet; any other file is read as CSV.
PARQUET_SUFFIXES = (".parquet", ".pq")
#: Extra to install for :func:`generate_program`.
PROGRAM_EXTRA = "pip install 'vtm_pin[program]'"

_SPLINE_METHOD = (
    "differentiated from the positions: derivative of the not-a-knot cubic spline through "
    "them (scipy CubicSpline)"
)
_FILE_METHOD = "from the file's columns v_<joint>"


#: Folder of the shipped programs (``ur10_pick_place.csv``).
PROGRAMS_DIR = Path(str(resources.files("vtm_pin.programs")))


def find_program(spec: str | Path) -> Path:
    """The program file ``spec`` names: an existing path, else a shipped program's name.

    A bare name (``ur10_pick_place``, or with ``.csv``) that is not a file names a program in
    :data:`PROGRAMS_DIR`; any other path is returned as it is (reading it says what is wrong).

    Raises:
        InputError: ``spec`` is a bare name that is neither a file nor a shipped program; the
            message lists the shipped ones.
    """
    return find_shipped(spec, PROGRAMS_DIR, "program", InputError, ".csv")


@dataclass(frozen=True, eq=False)
class Program:
    """A joint trajectory sampled at increasing times, with its velocities.

    Between samples the motion is the piecewise cubic Hermite interpolant of the positions and
    velocities (scipy ``CubicHermiteSpline``): it passes through every sample with its
    velocity. Where the velocities were differentiated with the cubic spline through the
    positions, it is that spline itself.

    Attributes:
        joint_names: The robot's joints, in the order of the columns of ``q`` and ``v``.
        t: Sample times [s], shape (m,), strictly increasing, m >= 2.
        q: Joint positions [rad] (or [m]), shape (m, n).
        v: Joint velocities [rad/s] (or [m/s]), shape (m, n).
        source: Where the program came from (its file, or how it was made).
        velocity_method: A sentence saying where ``v`` came from.
    """

    joint_names: tuple[str, ...]
    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    source: str
    velocity_method: str

    def __post_init__(self) -> None:
        m, n = len(self.t), len(self.joint_names)
        for name in ("t", "q", "v"):
            array = np.array(getattr(self, name), dtype=float)
            array.setflags(write=False)
            object.__setattr__(self, name, array)
        if self.t.shape != (m,) or m < 2 or not np.all(np.diff(self.t) > 0):
            raise ValueError("t must be a strictly increasing 1-D array of at least 2 times")
        if self.q.shape != (m, n) or self.v.shape != (m, n):
            shapes = f"{self.q.shape}, {self.v.shape}"
            raise ValueError(f"q and v must have shape {(m, n)}, not {shapes}")

    @property
    def duration(self) -> float:
        """Time from the first sample to the last [s]."""
        return float(self.t[-1] - self.t[0])

    @cached_property
    def _spline(self) -> Any:
        from scipy.interpolate import CubicHermiteSpline

        return CubicHermiteSpline(self.t, self.q, self.v, axis=0)

    def state_at(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities at time(s) ``t``, by piecewise cubic Hermite interpolation.

        Args:
            t: A time, or an array of k times [s], within ``[t[0], t[-1]]``.

        Returns:
            ``(q, v)``: shape (n,) each for one time, (k, n) for k times; [rad], [rad/s].

        Raises:
            ValueError: A time is outside the program.
        """
        times = np.asarray(t, dtype=float)
        slack = 1e-12 * max(1.0, abs(float(self.t[-1])))
        if np.any(~np.isfinite(times)) or np.any(times < self.t[0] - slack):
            raise ValueError(f"t must be within [{self.t[0]:g}, {self.t[-1]:g}] s")
        if np.any(times > self.t[-1] + slack):
            raise ValueError(f"t must be within [{self.t[0]:g}, {self.t[-1]:g}] s")
        times = np.clip(times, self.t[0], self.t[-1])
        return self._spline(times), self._spline(times, 1)

    def scaled(self, override: float) -> Program:
        """The same motion run at speed override ``override`` (as a robot's speed slider).

        Times after the first are stretched by 1/``override`` (``t[0]`` stays), velocities are
        multiplied by ``override`` (accelerations by its square); positions are unchanged.

        Args:
            override: Speed override F in (0, 1].

        Raises:
            ValueError: ``override`` is not in (0, 1].
        """
        if not 0.0 < override <= 1.0:
            raise ValueError(f"the speed override must be in (0, 1], not {override!r}")
        return replace(
            self,
            t=self.t[0] + (self.t - self.t[0]) / override,
            v=self.v * override,
            velocity_method=f"{self.velocity_method}; run at speed override {override:g} "
            "(times / override, velocities x override)",
        )

    def peak_joint_speed_time(self, joint: str | None = None) -> float:
        """Time [s] of the sample where a joint moves fastest (the earliest if several).

        Args:
            joint: The joint whose speed |v| counts; by default the fastest of all joints at
                each sample (their speeds compared as they are, rad/s).

        Raises:
            ValueError: ``joint`` is not a joint of the program.
        """
        if joint is None:
            speed = np.abs(self.v).max(axis=1)
        elif joint in self.joint_names:
            speed = np.abs(self.v[:, self.joint_names.index(joint)])
        else:
            raise ValueError(f"'{joint}' is not one of {', '.join(self.joint_names)}")
        return float(self.t[int(np.argmax(speed))])


def read_program(
    path: str | Path,
    robot: Robot,
    acceleration_limit: Limit = None,
) -> Program:
    """Read and check a program (CSV, or Parquet for ``.parquet``/``.pq``) for ``robot``.

    Rows are counted from 1 after the header: row N is the N-th data row (in a CSV file,
    blank lines and lines starting with ``#`` are skipped and not counted). CSV files are
    UTF-8, comma-separated, with a header line of column names (spaces around names ignored).

    Velocities come from the ``v_<joint>`` columns if there are any (see the module's
    docstring otherwise). Given velocities must be the derivative of the positions: between
    rows i and i+1, ``|dq - (v_i + v_i+1) dt / 2|`` must be at most ``a dt^2 / 4`` (plus
    :data:`CONSISTENCY_ATOL`), the trapezoid rule's error bound for a velocity whose rate of
    change is at most ``a`` = the acceleration limit; velocities in deg/s, or shifted by a
    row, fail it. Accelerations are the velocity differences over the time steps (given
    velocities), or the spline's second derivative at the samples (differentiated ones).

    A speed or acceleration above its limit is reported at the row where it is largest (a
    glitch, not the ringing a spline makes around it); other values at the first bad row.

    Args:
        path: The program file.
        robot: The robot that runs it: its joint names, position and velocity limits.
        acceleration_limit: Largest joint acceleration [rad/s^2], one for all joints or one
            per joint; default :data:`ACCELERATION_LIMIT`.

    Raises:
        InputError: The file cannot be read or breaks a rule; one line naming the file, the
            row and column (``row 12, column elbow_joint``) and what is allowed.
    """
    source = excerpt(str(path), 200)
    with open_regular(Path(path), InputError) as file:
        size = _file_size(file)
        if size > MAX_PROGRAM_BYTES:
            raise InputError(source, "", f"is {size} bytes; at most {MAX_PROGRAM_BYTES} are read")
        if Path(path).suffix.lower() in PARQUET_SUFFIXES:
            header, cells = _read_parquet(file, source)
        else:
            header, cells = _read_csv(file, source)
    velocities = _check_columns(header, robot, source)
    if len(cells[0]) > MAX_ROWS:
        raise InputError(source, "", f"has more than {MAX_ROWS} rows; a program has at most that")
    if len(cells[0]) < 2:
        rows = f"{len(cells[0])} row{'' if len(cells[0]) == 1 else 's'}"
        raise InputError(source, "", f"has {rows}; a program needs at least 2 (a start and an end)")
    data = {name: _numbers(cells[i], name, source) for i, name in enumerate(header)}
    t = data["time"]
    _check_time(t, source)
    q = np.column_stack([data[joint] for joint in robot.joints])
    if velocities:
        v = np.column_stack([data[f"v_{joint}"] for joint in robot.joints])
        method = _FILE_METHOD
    else:
        v, method = _spline_velocities(t, q), _SPLINE_METHOD
    program = Program(robot.joints, t, q, v, source, method)
    check_program(program, robot, acceleration_limit)
    return program


def check_program(program: Program, robot: Robot, acceleration_limit: Limit = None) -> None:
    """Check a program's positions, velocities and accelerations against ``robot``'s limits.

    The checks of :func:`read_program` after the file is parsed (see there). Velocities
    differentiated by the spline (``velocity_method`` starting as :func:`read_program` states
    it) are named by their joint's column and their accelerations are the spline's; any
    other velocities (a file's, toppra's, scaled ones) are checked as given ``v_`` columns.

    Raises:
        InputError: A sample breaks a limit; names ``program.source``, the row and column.
    """
    source, t, q, v = program.source, program.t, program.q, program.v
    _check_time(t, source)
    model = robot.model
    units = _units(robot)
    given = not program.velocity_method.startswith(_SPLINE_METHOD)
    for j, joint in enumerate(robot.joints):
        low, high = float(model.lowerPositionLimit[j]), float(model.upperPositionLimit[j])
        slack = LIMIT_RTOL * max(1.0, abs(low), abs(high))
        bad = np.flatnonzero((q[:, j] < low - slack) | (q[:, j] > high + slack))
        if bad.size:
            raise InputError(
                source,
                _key(bad[0], joint),
                f"{q[bad[0], j]:.6g} {units[j]} is outside the joint's limits "
                f"[{low:.6g}, {high:.6g}] {units[j]}",
            )
        column = f"v_{joint}" if given else joint
        _check_speed(v[:, j], float(model.velocityLimit[j]), column, units[j], given, source)
    alimit = _acceleration_limits(acceleration_limit, len(robot.joints))
    if given:
        _check_given_velocities(program, alimit, units)
    else:
        _check_spline_accelerations(program, alimit, units)


def _check_time(t: np.ndarray, source: str) -> None:
    step = np.diff(t)
    bad = np.flatnonzero(~(step > 0))
    if bad.size:
        i = int(bad[0]) + 1
        raise InputError(
            source,
            _key(i, "time"),
            f"{t[i]:.10g} s is not after the previous row's {t[i - 1]:.10g} s; "
            "time must increase strictly",
        )


def _check_speed(
    v: np.ndarray, limit: float, column: str, unit: str, given: bool, source: str
) -> None:
    """Refuse a speed above a positive finite velocity limit (others are not checked)."""
    if not (math.isfinite(limit) and limit > 0):
        return
    if np.max(np.abs(v)) > limit * (1 + LIMIT_RTOL):
        i = int(np.argmax(np.abs(v)))
        value = f"{v[i]:.6g} {unit}/s"
        what = value if given else f"the velocity differentiated from the positions, {value},"
        raise InputError(
            source,
            _key(i, column),
            f"{what} is above the joint's velocity limit {limit:.6g} {unit}/s",
        )


def _check_given_velocities(program: Program, alimit: np.ndarray, units: list[str]) -> None:
    """Accelerations from velocity differences; velocities that integrate to the positions."""
    dt = np.diff(program.t)[:, None]
    dv = np.diff(program.v, axis=0)
    accel = dv / dt
    excess = np.abs(accel) / alimit
    if np.max(excess) > 1 + LIMIT_RTOL:
        i, j = (int(x) for x in np.unravel_index(np.argmax(excess), excess.shape))
        raise InputError(
            program.source,
            _key(i + 1, f"v_{program.joint_names[j]}"),
            f"the velocity changes by {dv[i, j]:.6g} {units[j]}/s in {dt[i, 0]:.6g} s from "
            f"the previous row: {abs(accel[i, j]):.6g} {units[j]}/s^2, above the acceleration "
            f"limit {alimit[j]:.6g} {units[j]}/s^2",
        )
    moved = np.diff(program.q, axis=0)
    trapezoid = (program.v[:-1] + program.v[1:]) * dt / 2
    bound = alimit * dt**2 / 4 + CONSISTENCY_ATOL
    off = np.abs(moved - trapezoid) > bound
    if off.any():
        i, j = np.argwhere(off)[0]
        raise InputError(
            program.source,
            _key(i + 1, f"v_{program.joint_names[j]}"),
            f"the velocities of this row and the previous one move the joint "
            f"{trapezoid[i, j]:.6g} {units[j]} in {dt[i, 0]:.6g} s but its position changes by "
            f"{moved[i, j]:.6g} {units[j]}; v_ columns must be the positions' time derivative "
            f"[{units[j]}/s] (allowed difference {bound[i, j]:.3g} {units[j]})",
        )


def _check_spline_accelerations(program: Program, alimit: np.ndarray, units: list[str]) -> None:
    """The spline's second derivative at the samples (where a cubic spline's is largest)."""
    from scipy.interpolate import CubicSpline

    accel = CubicSpline(program.t, program.q, axis=0)(program.t, 2)
    excess = np.abs(accel) / alimit
    if np.max(excess) > 1 + LIMIT_RTOL:
        i, j = (int(x) for x in np.unravel_index(np.argmax(excess), excess.shape))
        raise InputError(
            program.source,
            _key(i, program.joint_names[j]),
            f"the acceleration differentiated from the positions (cubic spline), "
            f"{accel[i, j]:.6g} {units[j]}/s^2, is above the acceleration limit "
            f"{alimit[j]:.6g} {units[j]}/s^2 (noisy positions? give v_ columns)",
        )


def _spline_velocities(t: np.ndarray, q: np.ndarray) -> np.ndarray:
    from scipy.interpolate import CubicSpline

    velocities: np.ndarray = CubicSpline(t, q, axis=0)(t, 1)
    return velocities


def _acceleration_limits(limit: Limit, n: int) -> np.ndarray:
    values = np.broadcast_to(
        np.asarray(ACCELERATION_LIMIT if limit is None else limit, dtype=float), (n,)
    )
    if not np.all(np.isfinite(values) & (values > 0)):
        raise ValueError(f"acceleration_limit must be positive and finite, not {limit!r}")
    return values.copy()


def _units(robot: Robot) -> list[str]:
    """The position unit of each joint: ``m`` for prismatic joints, ``rad`` otherwise."""
    model = robot.model
    units = []
    for joint in robot.joints:
        kind = model.joints[model.getJointId(joint)].shortname()
        units.append("m" if "Prismatic" in kind else "rad")
    return units


def _key(row: int, column: str) -> str:
    """``row 12, column elbow_joint`` for the 0-based index ``row`` of a data row."""
    return f"row {int(row) + 1}, column {excerpt(column)}"


def _file_size(file: BinaryIO) -> int:
    import os

    return os.fstat(file.fileno()).st_size


def _first_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return excerpt(text or type(exc).__name__, 160)


def _read_csv(file: BinaryIO, source: str) -> tuple[list[str], list[np.ndarray]]:
    """Header names and raw column values (text) of a CSV file, at most MAX_ROWS + 1 rows."""
    try:
        frame = pd.read_csv(
            file,
            header=None,
            dtype=str,
            keep_default_na=False,
            comment="#",
            skip_blank_lines=True,
            nrows=MAX_ROWS + 2,
            encoding="utf-8-sig",
        )
    except pd.errors.EmptyDataError:
        raise InputError(source, "", "is empty; a program has a header line and rows") from None
    except (ValueError, OSError) as exc:  # ParserError and UnicodeDecodeError are ValueErrors
        raise InputError(source, "", f"is not a CSV table ({_first_line(exc)})") from exc
    header = [str(name).strip() for name in frame.iloc[0]]
    cells = [frame.iloc[1:, i].to_numpy(dtype=object) for i in range(frame.shape[1])]
    return header, cells


def _read_parquet(file: BinaryIO, source: str) -> tuple[list[str], list[np.ndarray]]:
    """Column names and values of a Parquet file (its row count checked before reading)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        parquet = pq.ParquetFile(file)
        if parquet.metadata.num_rows > MAX_ROWS:
            rows = parquet.metadata.num_rows
            raise InputError(source, "", f"has {rows} rows; a program has at most {MAX_ROWS}")
        table = parquet.read()
        cells = [table.column(i).to_numpy(zero_copy_only=False) for i in range(table.num_columns)]
    except (pa.ArrowException, OSError, ValueError, TypeError) as exc:
        raise InputError(source, "", f"is not a Parquet table ({_first_line(exc)})") from exc
    header = [str(name).strip() for name in table.column_names]
    if not cells:
        raise InputError(source, "", "has no columns; a program has time and joint columns")
    return header, cells


def _numbers(values: np.ndarray, column: str, source: str) -> np.ndarray:
    """A column as finite floats; the first cell that is not one is refused with its row."""
    if values.dtype.kind in "iuf":
        numbers = values.astype(float)
    else:
        cells = [
            (value.strip() if isinstance(value, str) else value)
            if _is_text_or_number(value)
            else None
            for value in values
        ]
        numbers = pd.to_numeric(pd.Series(cells, dtype=object), errors="coerce").to_numpy(
            dtype=float
        )
    bad = np.flatnonzero(~np.isfinite(numbers))
    if not bad.size:
        return numbers
    value = values[bad[0]]
    if isinstance(value, str):
        value = value.strip()
    if value is None or (isinstance(value, str) and not value):
        problem = "is empty; give a number"
    elif isinstance(value, (bool, np.bool_)) or not _is_number(value):
        problem = f"'{excerpt(str(value))}' is not a number"
    else:
        problem = f"{excerpt(str(value))} is not a finite number"
    raise InputError(source, _key(bad[0], column), problem)


def _is_text_or_number(value: object) -> bool:
    """Values :func:`pandas.to_numeric` may convert: text and numbers, not true/false."""
    return isinstance(value, str) or (
        isinstance(value, (int, float, np.integer, np.floating))
        and not isinstance(value, (bool, np.bool_))
    )


def _is_number(value: object) -> bool:
    try:
        float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False
    return True


def _check_columns(header: list[str], robot: Robot, source: str) -> bool:
    """Refuse missing, unknown and duplicate columns; True if the ``v_`` columns are given."""
    speeds = [f"v_{joint}" for joint in robot.joints]
    allowed = ["time", *robot.joints, *speeds]
    names = f"time, the joints ({', '.join(robot.joints)}) and optionally v_<joint> for every joint"
    for i, name in enumerate(header):
        if name not in allowed:
            raise InputError(
                source,
                f"column {excerpt(name)}",
                f"is not a column of a program for {excerpt(robot.name)}; the columns are {names}",
            )
        if name in header[:i]:
            raise InputError(
                source,
                f"column {excerpt(name)}",
                f"is given twice (columns {header.index(name) + 1} and {i + 1})",
            )
    for name in ["time", *robot.joints]:
        if name not in header:
            raise InputError(source, f"column {name}", f"is missing; the columns are {names}")
    given = [name in header for name in speeds]
    if any(given) and not all(given):
        missing = speeds[given.index(False)]
        raise InputError(
            source,
            f"column {missing}",
            "is missing: v_<joint> columns are given for some joints, so for every joint "
            "(or give none, and the velocities are differentiated from the positions)",
        )
    return all(given)


def write_program(program: Program, path: str | Path, comment: str = "") -> Path:
    """Write a program as CSV (or Parquet for a ``.parquet``/``.pq`` path) that reads back.

    Columns: ``time``, the joints, then ``v_<joint>``; values with 10 significant digits in CSV.

    Args:
        program: The program.
        path: The file to write (replaced if it exists).
        comment: CSV only: text written first, each line starting with ``# ``.

    Returns:
        The path written.
    """
    path = Path(path)
    columns = {"time": program.t}
    columns.update({joint: program.q[:, j] for j, joint in enumerate(program.joint_names)})
    columns.update({f"v_{joint}": program.v[:, j] for j, joint in enumerate(program.joint_names)})
    frame = pd.DataFrame(columns) + 0.0  # + 0.0: no -0 in the file
    if path.suffix.lower() in PARQUET_SUFFIXES:
        frame.to_parquet(path, index=False)
        return path
    with path.open("w", encoding="utf-8", newline="") as file:
        for line in comment.splitlines():
            file.write(f"# {line}".rstrip() + "\n")
        frame.to_csv(file, index=False, float_format="%.10g", lineterminator="\n")
    return path


def generate_program(
    robot: Robot,
    waypoints: np.ndarray | Sequence[Sequence[float]],
    velocity_limit: Limit = None,
    acceleration_limit: Limit = None,
    dt: float = 0.01,
    stops: bool = True,
    source: str = "generate_program",
) -> Program:
    """A time-optimal program through joint waypoints under velocity and acceleration limits.

    The path is parametrised in time by TOPP-RA (toppra, the extra ``vtm_pin[program]``),
    starting and ending at rest. With ``stops`` (a pick-and-place cycle: the robot halts at
    every waypoint, as a joint move without blending does), each move between two waypoints
    is a straight line in joint space, all joints arriving together; without, the path is
    toppra's cubic spline through all the waypoints, passed without stopping. The trajectory
    is sampled every ``dt``, and at its ends and (with ``stops``) at every waypoint, where it
    is at rest; the samples are checked as
    :func:`read_program` checks a file. toppra keeps the limits at its grid points only, so
    the time is stretched uniformly by the least factor (1 on straight moves, about 1.001 on
    splines) that brings every sampled velocity and acceleration within them.

    Args:
        robot: The robot; its joint limits bound the waypoints, its velocity limits the
            ``velocity_limit``.
        waypoints: Joint positions [rad] (or [m]), shape (k, n) with k >= 2, in the order of
            ``robot.joints``; consecutive waypoints must differ.
        velocity_limit: Largest joint speed [rad/s], one for all joints or one per joint, at
            most the robot's; default the robot's velocity limits.
        acceleration_limit: Largest joint acceleration [rad/s^2], one or one per joint;
            default :data:`ACCELERATION_LIMIT`.
        dt: Sample spacing [s].
        stops: Stop at every waypoint (True) or pass through them on one spline (False).
        source: What the program's ``source`` (and error messages) call it.

    Raises:
        InputError: toppra is not installed (one line naming the extra), the waypoints or
            limits are malformed, or the motion leaves the joint limits.
    """
    try:
        import toppra  # noqa: F401  (imported here so that a missing extra is one line)
    except ImportError:
        raise InputError(
            source, "", f"generating a program needs toppra, not installed: {PROGRAM_EXTRA}"
        ) from None
    points, vlimit, alimit = _generator_inputs(robot, waypoints, velocity_limit, acceleration_limit)
    if not (math.isfinite(dt) and dt > 0):
        raise InputError(source, "dt", f"{dt!r} must be a positive number of seconds")
    pieces = [points[i : i + 2] for i in range(len(points) - 1)] if stops else [points]
    trajectories = [_toppra(piece, vlimit, alimit, source) for piece in pieces]
    starts = np.cumsum([0.0] + [float(tr.duration) for tr in trajectories])
    if starts[-1] / dt > MAX_ROWS:
        raise InputError(source, "dt", f"{dt:g} s gives more than {MAX_ROWS} samples")
    stretch = 1.0
    for _ in range(10):
        t, q, v = _sample(trajectories, starts, stretch, dt)
        accel = np.abs(np.diff(v, axis=0)) / np.diff(t)[:, None]
        ratio = max(
            float(np.max(np.abs(v) / vlimit)), math.sqrt(float(np.max(accel / alimit))), 1.0
        )
        if ratio <= 1.0:
            break
        stretch *= ratio * (1 + 1e-9)
    method = "from toppra's time-optimal parametrisation (its trajectory's derivative)"
    program = Program(robot.joints, t, q, v, source, method)
    check_program(program, robot, alimit)
    return program


def _generator_inputs(
    robot: Robot,
    waypoints: np.ndarray | Sequence[Sequence[float]],
    velocity_limit: Limit,
    acceleration_limit: Limit,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Waypoints (k, n) within the joint limits, and the velocity and acceleration limits."""
    n, model = len(robot.joints), robot.model
    points = np.asarray(waypoints, dtype=float)
    if points.ndim != 2 or points.shape[1] != n or len(points) < 2:
        raise InputError(
            "", "waypoints", f"must be at least 2 rows of {n} joint positions, not {points.shape}"
        )
    low, high = np.asarray(model.lowerPositionLimit), np.asarray(model.upperPositionLimit)
    for i, point in enumerate(points):
        outside = ~np.isfinite(point) | (point < low) | (point > high)
        if outside.any():
            j = int(np.argmax(outside))
            raise InputError(
                "",
                f"waypoints[{i}][{j}]",
                f"{point[j]!r} is not within {robot.joints[j]}'s limits [{low[j]:g}, {high[j]:g}]",
            )
        if i and np.array_equal(point, points[i - 1]):
            raise InputError("", f"waypoints[{i}]", "is the previous waypoint again; drop it")
    robot_speed = np.asarray(model.velocityLimit, dtype=float)
    vlimit = np.broadcast_to(
        np.asarray(robot_speed if velocity_limit is None else velocity_limit, dtype=float), (n,)
    ).copy()
    if not np.all(np.isfinite(vlimit) & (vlimit > 0) & (vlimit <= robot_speed)):
        raise InputError(
            "",
            "velocity_limit",
            f"{excerpt(velocity_limit)} must be positive and at most the robot's velocity limits "
            f"({', '.join(f'{x:g}' for x in robot_speed)})",
        )
    try:
        alimit = _acceleration_limits(acceleration_limit, n)
    except ValueError as exc:
        raise InputError("", "acceleration_limit", str(exc)) from None
    return points, vlimit, alimit


def _toppra(points: np.ndarray, vlimit: np.ndarray, alimit: np.ndarray, source: str) -> Any:
    """The time-optimal trajectory (toppra) on the spline through ``points``, rest to rest."""
    import toppra
    import toppra.algorithm
    import toppra.constraint

    # Path parameter: cumulative joint-space distance (a straight line for two points).
    lengths = np.linalg.norm(np.diff(points, axis=0), axis=1)
    path = toppra.SplineInterpolator(np.concatenate([[0.0], np.cumsum(lengths)]), points)
    constraints = [
        toppra.constraint.JointVelocityConstraint(np.column_stack([-vlimit, vlimit])),
        toppra.constraint.JointAccelerationConstraint(np.column_stack([-alimit, alimit])),
    ]
    instance = toppra.algorithm.TOPPRA(constraints, path, parametrizer="ParametrizeConstAccel")
    trajectory = instance.compute_trajectory(0.0, 0.0)
    if trajectory is None:
        raise InputError(source, "waypoints", "toppra found no motion within the limits")
    return trajectory


def _sample(
    trajectories: Sequence[Any], starts: np.ndarray, stretch: float, dt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Samples of the moves one after the other, slowed down by ``stretch``.

    Times are multiplied by ``stretch``, velocities divided by it. Samples every ``dt``, and
    where each move starts and ends (at rest on its waypoints); grid times within dt / 4 of
    those are dropped.
    """
    marks = starts * stretch
    grid = np.arange(0.0, marks[-1], dt)
    after = np.clip(np.searchsorted(marks, grid), 1, len(marks) - 1)
    near = np.minimum(grid - marks[after - 1], marks[after] - grid) < dt / 4
    t = np.union1d(grid[~near], marks)
    nominal = np.clip(t / stretch, 0.0, starts[-1])
    segment = np.clip(np.searchsorted(starts, nominal, side="right") - 1, 0, len(trajectories) - 1)
    q = np.empty((len(t), trajectories[0].dof))
    v = np.empty_like(q)
    for k, trajectory in enumerate(trajectories):
        rows = segment == k
        local = np.clip(nominal[rows] - starts[k], 0.0, float(trajectory.duration))
        q[rows] = trajectory(local)
        v[rows] = trajectory(local, 1) / stretch
    return t, q, v
