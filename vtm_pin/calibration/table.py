"""Published stopping data (ISO 10218-1 Annex B) read from a CSV table.

Robot makers publish, for each joint and stop category, how long a joint moving at a given
speed takes to stop and how far it travels, with a payload and an arm extension. vtm_pin
reads these figures from a CSV file (UTF-8, comma separated) whose first line (comments aside)
is the header, with exactly these 11 columns in this order; each further line is a measurement:

=====================  =============================================================
column                 content
=====================  =============================================================
``robot``              the robot, as the maker names it (text, not empty)
``category``           stop category: ``0`` or ``1``
``joint``              the tested joint's name in the URDF (text, not empty)
``joint_label``        the maker's name for the joint (text, may be empty)
``speed_deg_s``        joint speed at the stop signal [deg/s], > 0 and <= 3600
``payload_kg``         payload at the tool [kg], >= 0 and <= 10000
``extension_pct``      arm extension [%] of the maximum reach, > 0 and <= 100
``motion``             ``horizontal``, ``down`` or ``up``: how the tested joint moved
``stop_time_ms``       stopping time [ms], > 0 and <= 1000000
``stop_distance_rad``  stopping distance of the joint [rad], > 0 and <= 100
``source``             where the figures come from: document, version, page (not empty)
=====================  =============================================================

For example::

    robot,category,joint,joint_label,speed_deg_s,payload_kg,extension_pct,motion,stop_time_ms,stop_distance_rad,source
    UR5/CB3,0,shoulder_pan_joint,J0 base,183,5,100,horizontal,244,0.31,UR5 manual v3.4.5 p. I-53

Rules:

* Numbers are decimal with a point (``0.31``, ``1e3``); NaN and infinities are refused.
* Spaces around a cell are ignored; a cell that holds a comma or a quote is quoted the CSV
  way (``"J0, base"``, ``"the ""base"" joint"``); a cell cannot span lines.
* Blank lines (and lines of empty cells only, as spreadsheets export them) are skipped, and so
  are comment lines: lines whose first character other than a space is ``#``.
* A table holds one robot's data: every row has the same ``robot``.
* No two rows have the same joint, category, speed, payload, extension and motion.
* At most :data:`MAX_ROWS` rows (1000: a maker's table has tens; the full ISO 10218-1 grid of
  3 speeds x 3 payloads x 3 extensions for 6 joints in both categories has 324); files
  larger than :data:`~vtm_pin.files.inputs.MAX_FILE_BYTES` are refused; a UTF-8 byte order mark is
  allowed.

Two more rules are checked before a calibration (``vtm-pin calibrate``) fits anything:

* Units (:func:`check_units`): a joint that stops from the speed v0 within the time t travels
  about v0 t / 2 (a constant deceleration) to v0 t (a delay, then a hard stop); one that falls
  under gravity during the brake delay may speed up first. A row whose ``stop_distance_rad``
  exceeds :data:`MAX_MEAN_SPEED_RATIO` (2) x v0 t is impossible as read: a unit is wrong. The
  message names the column that would explain it: ``stop_time_ms`` when every time of the
  table is below :data:`SECONDS_LIKE_MS` (10 ms: times in seconds) and the row is possible
  read in seconds; ``speed_deg_s`` when the row is possible with the speed read in rad/s
  (or ``stop_distance_rad`` read in degrees, which the same factor 57.3 explains).
* Robot (:func:`check_robot`): the ``robot`` column must name the robot the table is fitted
  to. Names are compared by their runs of letters and digits, ignoring case: they match when
  the runs of one, joined, equal some consecutive runs of the other's, joined (``UR5/CB3``
  matches ``ur5_cb3`` and ``ur5``, not ``ur10`` nor ``ur5e``; ``KUKA KR 16`` matches
  ``kr16``). The robot is named by ``--robot``; a URDF path by its file name or its
  ``<robot name>``. ``--robot-differs`` fits another robot's table on purpose:
  every source then says so, in ``calibration.json`` and ``calibrated.yaml``.

A table that breaks a rule is refused with :class:`TableError`: one line naming the file, the
row and column, and what is allowed, e.g. ``table.csv: 'row 3, column speed_deg_s': 'fast' is
not a number (deg/s, > 0 and <= 3600)``. Rows are numbered by the file's lines, as a
spreadsheet numbers them: the header is row 1 (unless comment lines precede it) and blank and
comment lines count. :func:`check_joints` checks the joints against a robot's. Errors found
later about a row (its scenario refused, its simulation failed during a fit) name the file
and row the same way (:func:`row_message`).

Read values are in SI units: speeds in rad/s, times in s, extensions as fractions.
"""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

from ..exceptions import InputError, excerpt
from ..files.inputs import read_text

#: How the tested joint moved at the stop signal.
MOTIONS = ("horizontal", "down", "up")
#: Stop categories of Annex-B stopping data.
CATEGORIES = (0, 1)
#: The columns of a stopping table, in order.
COLUMNS: tuple[str, ...] = (
    "robot",
    "category",
    "joint",
    "joint_label",
    "speed_deg_s",
    "payload_kg",
    "extension_pct",
    "motion",
    "stop_time_ms",
    "stop_distance_rad",
    "source",
)
#: Units of each column, for messages and docs ("" for text and categories).
UNITS: dict[str, str] = {
    "robot": "",
    "category": "",
    "joint": "",
    "joint_label": "",
    "speed_deg_s": "deg/s",
    "payload_kg": "kg",
    "extension_pct": "%",
    "motion": "",
    "stop_time_ms": "ms",
    "stop_distance_rad": "rad",
    "source": "",
}
#: Allowed range of each numeric column: (low, whether low itself is allowed, high).
BOUNDS: dict[str, tuple[float, bool, float]] = {
    "speed_deg_s": (0.0, False, 3600.0),
    "payload_kg": (0.0, True, 1e4),
    "extension_pct": (0.0, False, 100.0),
    "stop_time_ms": (0.0, False, 1e6),
    "stop_distance_rad": (0.0, False, 100.0),
}
#: Most rows of stopping data read from a table. A maker's table has tens of rows (UR's has
#: 3 per category); the full ISO 10218-1 Annex-B grid (3 speeds x 3 payloads x 3 extensions)
#: for 6 joints in both categories has 324. Every row is simulated at each step of a fit, so
#: 1000 rows already take hours; a larger file is not a stopping table.
MAX_ROWS = 1000
#: Largest stopping distance accepted, as a multiple of speed x time [-]. A joint that only
#: decelerates travels between v0 t / 2 (constant deceleration) and v0 t (a delay, then a hard
#: stop); one that falls under gravity during the brake delay may speed up first, hence the
#: margin. The unit mistakes it catches are far beyond: x1000 for seconds in ``stop_time_ms``,
#: x57.3 for rad/s in ``speed_deg_s`` (or degrees in ``stop_distance_rad``).
MAX_MEAN_SPEED_RATIO = 2.0
#: A table whose every ``stop_time_ms`` is below this [ms] looks like it holds seconds: no arm
#: stops from a tested speed in 10 ms (its brakes alone take longer to engage), none takes 10 s.
SECONDS_LIKE_MS = 10.0
#: What a text column must hold, said when it is empty (``joint_label`` may be empty).
_REQUIRED_TEXT = {
    "robot": "give the robot's name",
    "joint": "give the joint's name in the URDF",
    "source": "say where the figures come from (document, version, page)",
}
_NUMBER = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_NON_FINITE = re.compile(r"[+-]?(?:nan|inf|infinity)", re.IGNORECASE)
_DECIMAL_COMMA = re.compile(r"[+-]?[0-9]+,[0-9]+")
_SPACE_AFTER_QUOTE = re.compile(r'"[ \t]+,')


class TableError(InputError):
    """A stopping table is malformed: names the file, the row and column, and what is allowed.

    ``key`` is ``row N, column name`` for a cell, ``row N`` for a whole row, ``header`` for
    the header and "" for the whole file; N is the line number in the file.
    """


@dataclass(frozen=True)
class StoppingRow:
    """One published measurement, in SI units.

    Attributes:
        line: Line number in the file (the header is line 1), for messages.
        robot: The robot, as the maker names it.
        category: Stop category, 0 or 1.
        joint: The tested joint's name in the URDF.
        joint_label: The maker's name for the joint ("" when not given).
        speed: Joint speed at the stop signal [rad/s] (from ``speed_deg_s``).
        payload: Payload at the tool [kg].
        extension: Arm extension [-], a fraction of the maximum reach (``extension_pct`` / 100).
        motion: ``horizontal``, ``down`` or ``up``.
        stop_time: Stopping time [s] (from ``stop_time_ms``).
        stop_distance: Stopping distance of the joint [rad].
        source: Where the figures come from.
        path: The file the row was read from, for messages ("" if not read from a file).
    """

    line: int
    robot: str
    category: int
    joint: str
    joint_label: str
    speed: float
    payload: float
    extension: float
    motion: str
    stop_time: float
    stop_distance: float
    source: str
    path: str = field(default="", compare=False)


@dataclass(frozen=True)
class StoppingTable:
    """A stopping table as read: its file and its rows, in file order (at least one).

    Attributes:
        path: The file it was read from.
        rows: Its rows, in file order.
    """

    path: str
    rows: tuple[StoppingRow, ...]

    @property
    def robot(self) -> str:
        """The robot of every row ("" for a table without rows)."""
        return self.rows[0].robot if self.rows else ""

    @property
    def sources(self) -> tuple[str, ...]:
        """The distinct sources, in order of first appearance."""
        return tuple(dict.fromkeys(row.source for row in self.rows))

    @property
    def joints(self) -> tuple[str, ...]:
        """The distinct joints, in order of first appearance."""
        return tuple(dict.fromkeys(row.joint for row in self.rows))


def read_stopping_table(path: str | Path) -> StoppingTable:
    """Read and check a stopping table (the format is in the module's docstring).

    Args:
        path: The CSV file.

    Returns:
        The table, with its values converted to SI units (rad/s, s, fractions).

    Raises:
        TableError: The file cannot be read, is larger than
            :data:`~vtm_pin.files.inputs.MAX_FILE_BYTES`, is not UTF-8, has no header or no rows,
            or a header, row or cell breaks a rule; one line naming the file, the row and the
            column.
    """
    source = str(path)
    lines = _records(source, _read_text(Path(path)))
    if not lines:
        raise TableError(
            source, "", f"is empty: a stopping table starts with the header {','.join(COLUMNS)}"
        )
    _check_header(source, *lines[0])
    if len(lines) == 1:
        raise TableError(source, "", "has a header but no rows of stopping data")
    if len(lines) - 1 > MAX_ROWS:
        raise TableError(
            source,
            "",
            f"has {len(lines) - 1} rows of stopping data; at most {MAX_ROWS} are read (a "
            "maker's table has tens; each row is simulated at every step of a fit): is it "
            "the right file?",
        )
    rows: list[StoppingRow] = []
    seen: dict[tuple[object, ...], int] = {}
    for line, cells in lines[1:]:
        row = _parse_row(source, line, cells)
        if rows and row.robot != rows[0].robot:
            raise TableError(
                source,
                _cell_key(line, "robot"),
                f"'{excerpt(row.robot)}' differs from '{excerpt(rows[0].robot)}' of row "
                f"{rows[0].line}; a table holds one robot's data",
            )
        same = _identity(row)
        if same in seen:
            raise TableError(
                source,
                f"row {line}",
                f"repeats row {seen[same]}: same joint, category, speed, payload, extension and "
                "motion",
            )
        seen[same] = line
        rows.append(row)
    return StoppingTable(source, tuple(rows))


def check_joints(table: StoppingTable, joints: Sequence[str]) -> None:
    """Check that every row's joint is one of a robot's joints.

    Args:
        table: The stopping table.
        joints: The robot's joint names (``Robot.joints``).

    Raises:
        TableError: Naming the first row whose joint is not one of ``joints``, and listing them.
    """
    known = set(joints)
    for row in table.rows:
        if row.joint not in known:
            raise TableError(
                table.path,
                _cell_key(row.line, "joint"),
                f"'{excerpt(row.joint)}' is not a joint of the robot; its joints are: "
                f"{', '.join(joints)}",
            )


def row_message(row: StoppingRow, problem: str, column: str = "") -> str:
    """``problem`` about ``row`` (and its ``column``), as :class:`TableError` says it.

    For errors found after reading (a row's scenario refused, its simulation failed): one line
    naming the file, the row (its line number) and the column, e.g. ``table.csv: 'row 3,
    column motion': ...``.
    """
    key = _cell_key(row.line, column) if column else f"row {row.line}"
    return str(TableError(row.path, key, problem))


def check_units(table: StoppingTable) -> None:
    """Refuse a row whose distance no stop from its speed within its time can travel.

    A row is impossible as read when ``stop_distance_rad`` exceeds
    :data:`MAX_MEAN_SPEED_RATIO` x speed x time (see the module's docstring); the message
    names the unit mistake that would explain it.

    Raises:
        TableError: Naming the file, the first impossible row, the column of the likely
            mistake, and the mistake.
    """
    seconds = all(row.stop_time * 1e3 < SECONDS_LIKE_MS for row in table.rows)
    for row in table.rows:
        if row.stop_distance <= MAX_MEAN_SPEED_RATIO * row.speed * row.stop_time:
            continue
        column, hint = _unit_mistake(row, seconds)
        raise TableError(
            table.path,
            _cell_key(row.line, column),
            f"stop_distance_rad {row.stop_distance:g} rad is more than {MAX_MEAN_SPEED_RATIO:g} "
            f"x speed x time ({row.speed:.4g} rad/s x {row.stop_time:.4g} s = "
            f"{row.speed * row.stop_time:.3g} rad): no stop travels that far, so a unit is "
            f"wrong; {hint}",
        )


def _unit_mistake(row: StoppingRow, seconds: bool) -> tuple[str, str]:
    """The column of the unit mistake that makes ``row`` possible, and what to do.

    Args:
        row: A row whose distance is beyond :data:`MAX_MEAN_SPEED_RATIO` x speed x time.
        seconds: Whether every time of the table is below :data:`SECONDS_LIKE_MS`.
    """
    reach = MAX_MEAN_SPEED_RATIO * row.speed * row.stop_time  # [rad]
    if seconds and row.stop_distance <= 1e3 * reach:
        return "stop_time_ms", (
            f"the times look like seconds: every stop_time_ms is below {SECONDS_LIKE_MS:g} ms, "
            "and read as seconds the row is possible; write milliseconds"
        )
    if row.stop_distance <= math.degrees(reach):
        return "speed_deg_s", (
            f"the speed looks like rad/s: read as {math.degrees(row.speed):.4g} rad/s the row "
            "is possible; write deg/s (or, if stop_distance_rad is in degrees, write radians)"
        )
    return "stop_distance_rad", (
        "check the units: speed_deg_s in deg/s, stop_time_ms in ms, stop_distance_rad in rad"
    )


def robot_matches(table_robot: str, names: Sequence[str]) -> bool:
    """Whether the table's ``robot`` names the same robot as one of ``names``.

    Names are compared by their runs of letters and digits, ignoring case: two names match
    when the runs of one, joined, equal some consecutive runs of the other's, joined
    (``UR5/CB3`` matches ``ur5_cb3`` and ``ur5``, not ``ur10`` nor ``ur5e``).
    """
    ours = _runs(table_robot)
    for name in names:
        theirs = _runs(name)
        if ours and theirs and (_within(ours, theirs) or _within(theirs, ours)):
            return True
    return False


def check_robot(
    table: StoppingTable, robot: str, names: Sequence[str], differs: bool
) -> StoppingTable:
    """The table, checked to be ``robot``'s (see :func:`robot_matches`).

    Args:
        table: The stopping table.
        robot: The robot as ``--robot`` gives it, for messages.
        names: The names it goes by: ``--robot``; for a URDF path, its file name and its
            ``<robot name>``.
        differs: Fit another robot's table on purpose (``--robot-differs``): the table is
            returned with every row's source saying so, for the outputs.

    Raises:
        TableError: The names do not match and ``differs`` is not set; names the file, the
            table's robot and ``robot``, and ``--robot-differs``.
    """
    if robot_matches(table.robot, names):
        return table
    if differs:
        note = f" [measured on {table.robot}; fitted to {robot} by --robot-differs]"
        rows = tuple(replace(row, source=row.source + note) for row in table.rows)
        return replace(table, rows=rows)
    raise TableError(
        table.path,
        _cell_key(table.rows[0].line, "robot"),
        f"the table is for '{excerpt(table.robot)}', not --robot {excerpt(robot)} (names "
        "compared by their letters and digits); give the robot it was measured on, or "
        f"--robot-differs to fit it to {excerpt(robot)} on purpose (the outputs then say so)",
    )


def _runs(name: str) -> list[str]:
    """The runs of letters and digits of a name, in lower case: ``UR5/CB3`` -> ur5, cb3."""
    return re.findall(r"[^\W_]+", name.lower())


def _within(short: list[str], long: list[str]) -> bool:
    """Whether ``short``, joined, equals consecutive runs of ``long``, joined."""
    joined = "".join(short)
    return any(
        "".join(long[i:j]) == joined for i in range(len(long)) for j in range(i + 1, len(long) + 1)
    )


def _read_text(path: Path) -> str:
    """The text of a file: at most :data:`~vtm_pin.files.inputs.MAX_FILE_BYTES`, strict UTF-8."""
    return read_text(path, TableError)


def _records(source: str, text: str) -> list[tuple[int, list[str]]]:
    """(line number, stripped cells) of each line that is not blank, empty cells or comment."""
    records: list[tuple[int, list[str]]] = []
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    for number, line in enumerate(lines, start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        try:
            cells = _split(line)
        except csv.Error as exc:
            where = "header" if not records else f"row {number}"
            raise TableError(
                source,
                where,
                f"cannot split the line into cells ({exc}); quote a cell that holds a comma "
                'or a quote ("a, b", "the ""b"" joint"), on one line',
            ) from exc
        if any(cells):
            records.append((number, cells))
    return records


def _split(line: str) -> list[str]:
    """The stripped cells of a line; spaces between a closing quote and a comma are allowed.

    Raises:
        csv.Error: A quote is not closed on the line, or text follows a closing quote.
    """
    line = line.strip()
    try:
        return _cells(line)
    except csv.Error as first:
        # Strict CSV refuses '"a" ,b'; try again without those spaces (a line that is fine as
        # it is never gets here, so a quoted '"" ,' inside a cell is left alone).
        retry = _SPACE_AFTER_QUOTE.sub('",', line)
        if retry == line:
            raise
        try:
            return _cells(retry)
        except csv.Error:
            raise first from None


def _cells(line: str) -> list[str]:
    """The stripped cells of one line of CSV, read strictly."""
    cells = next(csv.reader([line], skipinitialspace=True, strict=True))
    return [cell.strip() for cell in cells]


def _check_header(source: str, line: int, cells: list[str]) -> None:
    """Refuse a header that is not exactly :data:`COLUMNS`, saying what differs."""
    if tuple(cells) == COLUMNS:
        return
    expected = ",".join(COLUMNS)
    if not set(cells) & set(COLUMNS):
        problem = f"line {line} is not the header; a stopping table starts with {expected}"
    else:
        missing = [c for c in COLUMNS if c not in cells]
        unexpected = list(dict.fromkeys(c for c in cells if c not in COLUMNS))
        repeated = list(dict.fromkeys(c for c in cells if c in COLUMNS and cells.count(c) > 1))
        parts = [
            f"{what}: {', '.join(excerpt(c) for c in names)}"
            for what, names in (
                ("missing columns", missing),
                ("unexpected columns", unexpected),
                ("repeated columns", repeated),
            )
            if names
        ]
        if not parts:
            parts = ["columns out of order"]
        problem = f"{'; '.join(parts)}; the header must be {expected}"
    raise TableError(source, "header", problem)


def _parse_row(source: str, line: int, cells: list[str]) -> StoppingRow:
    """One row, checked cell by cell and converted to SI units."""
    if len(cells) != len(COLUMNS):
        hint = (
            " (a cell holding a comma must be quoted)"
            if len(cells) > len(COLUMNS)
            else " (is a comma missing?)"
        )
        raise TableError(
            source,
            f"row {line}",
            f"has {len(cells)} cells, the header has {len(COLUMNS)}{hint}",
        )
    value = dict(zip(COLUMNS, cells, strict=True))
    for column, what in _REQUIRED_TEXT.items():
        if not value[column]:
            raise TableError(source, _cell_key(line, column), f"is empty; {what}")
    number = {column: _number(source, line, column, value[column]) for column in BOUNDS}
    return StoppingRow(
        line=line,
        robot=value["robot"],
        category=_category(source, line, value["category"]),
        joint=value["joint"],
        joint_label=value["joint_label"],
        speed=math.radians(number["speed_deg_s"]),
        payload=number["payload_kg"],
        extension=number["extension_pct"] / 100.0,
        motion=_motion(source, line, value["motion"]),
        stop_time=number["stop_time_ms"] / 1000.0,
        stop_distance=number["stop_distance_rad"],
        source=value["source"],
        path=source,
    )


def _number(source: str, line: int, column: str, cell: str) -> float:
    """A numeric cell within its :data:`BOUNDS`, in the column's unit."""
    low, low_allowed, high = BOUNDS[column]
    allowed = f"({UNITS[column]}, {'>=' if low_allowed else '>'} {low:.15g} and <= {high:.15g})"
    key = _cell_key(line, column)
    if not cell:
        raise TableError(source, key, f"is empty; give a number {allowed}")
    shown = f"'{excerpt(cell)}'"
    if _NON_FINITE.fullmatch(cell):
        raise TableError(source, key, f"{shown} is not a finite number {allowed}")
    if not _NUMBER.fullmatch(cell):
        hint = "; write decimals with a point" if _DECIMAL_COMMA.fullmatch(cell) else ""
        raise TableError(source, key, f"{shown} is not a number {allowed}{hint}")
    number = float(cell)
    if not math.isfinite(number):  # 1e999
        raise TableError(source, key, f"{shown} is not a finite number {allowed}")
    if not (low <= number if low_allowed else low < number) or number > high:
        raise TableError(source, key, f"{shown} is out of range {allowed}")
    return number


def _category(source: str, line: int, cell: str) -> int:
    """The stop category of a cell: 0 or 1."""
    allowed = " or ".join(str(c) for c in CATEGORIES)
    if cell not in [str(c) for c in CATEGORIES]:
        problem = f"'{excerpt(cell)}' is not a stop category" if cell else "is empty"
        raise TableError(
            source,
            _cell_key(line, "category"),
            f"{problem}; allowed: {allowed} (Annex-B stopping data are for categories 0 and 1)",
        )
    return int(cell)


def _motion(source: str, line: int, cell: str) -> str:
    """The motion of a cell: one of :data:`MOTIONS`."""
    if cell not in MOTIONS:
        problem = f"'{excerpt(cell)}' is not a motion" if cell else "is empty"
        raise TableError(
            source, _cell_key(line, "motion"), f"{problem}; allowed: {', '.join(MOTIONS)}"
        )
    return cell


def _identity(row: StoppingRow) -> tuple[object, ...]:
    """What makes two rows the same measurement: joint, category, speed, payload, extension, motion.

    Numbers are compared as numbers: ``183`` is ``183.0``.
    """
    return (row.joint, row.category, row.speed, row.payload, row.extension, row.motion)


def _cell_key(line: int, column: str) -> str:
    """The key of a cell in messages: ``row 3, column speed_deg_s``."""
    return f"row {line}, column {column}"
