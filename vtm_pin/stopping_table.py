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
* Files larger than :data:`~vtm_pin.inputs.MAX_FILE_BYTES` are refused; a UTF-8 byte order
  mark is allowed.

A table that breaks a rule is refused with :class:`TableError`: one line naming the file, the
row and column, and what is allowed, e.g. ``table.csv: 'row 3, column speed_deg_s': 'fast' is
not a number (deg/s, > 0 and <= 3600)``. Rows are numbered by the file's lines, as a
spreadsheet numbers them: the header is row 1 (unless comment lines precede it) and blank and
comment lines count. :func:`check_joints` checks the joints against a robot's.

Read values are in SI units: speeds in rad/s, times in s, extensions as fractions.
"""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from .exceptions import InputError, excerpt
from .inputs import read_text

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
            :data:`~vtm_pin.inputs.MAX_FILE_BYTES`, is not UTF-8, has no header or no rows,
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


def _read_text(path: Path) -> str:
    """The text of a file: at most :data:`~vtm_pin.inputs.MAX_FILE_BYTES`, strict UTF-8."""
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
