"""The published stopping-table format: reading, one-line refusals, joints, round trip."""

import csv
import math
from pathlib import Path

import pytest
from conftest import UR_JOINTS
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vtm_pin.calibration.table import (
    COLUMNS,
    MOTIONS,
    UNITS,
    StoppingRow,
    StoppingTable,
    TableError,
    check_joints,
    read_stopping_table,
)
from vtm_pin.exceptions import InputError
from vtm_pin.files.inputs import MAX_FILE_BYTES

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
UR5_TABLE = DATA / "ur5_cb3_stopping_cat0.csv"
UR5_JOINTS = UR_JOINTS
#: Conversions are a multiplication or a division: a few ulps [-, relative].
CONVERSION_RTOL = 1e-15
#: The notes round 183 deg/s to 3.194 rad/s: half a unit of their last digit [rad/s].
NOTES_SPEED_ATOL = 5e-4

HEADER = ",".join(COLUMNS)
ROW = "UR5,0,elbow_joint,J2 elbow,183,5,100,down,164,0.22,manual p. 53"
ROW_B = "UR5,0,shoulder_lift_joint,J1,183,5,100,down,530,0.70,manual p. 53"


def table(*lines: str) -> str:
    return "\n".join(lines) + "\n"


def with_cell(column: str, value: str, row: str = ROW) -> str:
    """ROW with one cell replaced (the value is written as it is: quote it yourself)."""
    cells = row.split(",")
    cells[COLUMNS.index(column)] = value
    return ",".join(cells)


def refused(path: Path) -> TableError:
    with pytest.raises(TableError) as info:
        read_stopping_table(path)
    error = info.value
    message = str(error)
    assert isinstance(error, InputError)
    assert "\n" not in message and "Traceback" not in message
    assert error.source == str(path) and message.startswith(f"{path}: ")
    return error


# -- the published UR5 table ----------------------------------------------------------------


@pytest.mark.skipif(not DATA.is_dir(), reason=f"shared data folder {DATA} is absent")
def test_reads_the_published_ur5_table_in_si_units():
    t = read_stopping_table(UR5_TABLE)
    assert isinstance(t, StoppingTable) and t.path == str(UR5_TABLE)
    assert len(t.rows) == 3
    assert t.joints == ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint")
    assert t.sources == ("UR5/CB3 User Manual v3.4.5 Appendix A.1 p. I-53",)
    assert t.robot == "UR5/CB3"
    assert [r.line for r in t.rows] == [2, 3, 4]
    assert [r.motion for r in t.rows] == ["horizontal", "down", "down"]
    assert [r.joint_label for r in t.rows] == ["J0 base", "J1 shoulder", "J2 elbow"]
    for r in t.rows:
        assert r.category == 0
        assert r.speed == pytest.approx(183 * math.pi / 180, rel=CONVERSION_RTOL)
        assert r.speed == pytest.approx(3.194, abs=NOTES_SPEED_ATOL)
        assert r.payload == 5.0 and r.extension == 1.0
    expected = [(0.244, 0.31), (0.530, 0.70), (0.164, 0.22)]  # [s], [rad]
    for r, (time, distance) in zip(t.rows, expected, strict=True):
        assert r.stop_time == pytest.approx(time, rel=CONVERSION_RTOL)
        assert r.stop_distance == distance
    check_joints(t, UR5_JOINTS)


def test_units_name_every_column():
    assert tuple(UNITS) == COLUMNS
    assert UNITS["speed_deg_s"] == "deg/s" and UNITS["stop_time_ms"] == "ms"
    assert MOTIONS == ("horizontal", "down", "up")


# -- what is tolerated ---------------------------------------------------------------------


def test_bom_spaces_crlf_comments_blank_and_empty_lines_are_tolerated(tmp_path):
    path = tmp_path / "table.csv"
    text = (
        "\ufeff# UR5 stopping data, copied from the manual\r\n"
        + " , ".join(COLUMNS)
        + "\r\n"
        + "\r\n"
        + "  # a comment between rows\r\n"
        + " UR5 , 0 , elbow_joint ,  , 183.0 , 5 , 100 , down , 164 , 0.22 , manual \r\n"
        + ",,,,,,,,,,\r\n"
        + 'UR5,1,elbow_joint, "J2, elbow" ,1.83e2,0,50,up,1e2,.5,"the ""manual"", p. 1"\r\n'
        + "\r\n\r\n"
    )
    path.write_bytes(text.encode("utf-8"))
    t = read_stopping_table(path)
    assert [r.line for r in t.rows] == [5, 7]
    first, second = t.rows
    assert first.robot == "UR5" and first.joint_label == "" and first.source == "manual"
    assert second.joint_label == "J2, elbow" and second.source == 'the "manual", p. 1'
    assert second.category == 1 and second.motion == "up" and second.payload == 0.0
    assert second.extension == 0.5 and second.stop_distance == 0.5
    assert second.stop_time == pytest.approx(0.1, rel=CONVERSION_RTOL)
    assert second.speed == pytest.approx(first.speed, rel=CONVERSION_RTOL)
    assert t.joints == ("elbow_joint",)
    assert t.sources == ("manual", 'the "manual", p. 1')


# -- what is refused -----------------------------------------------------------------------

TOO_LARGE = "too large"
_NUMBERS = "(deg/s, > 0 and <= 3600)"

BAD_TABLES = [
    # (id, file content (None: no file), key, phrase of the message)
    ("no file", None, "", "cannot read the file (No such file or directory)"),
    (
        "not utf-8",
        table(HEADER, with_cell("robot", "UR \udce9")),  # a Latin-1 é: byte 0xe9
        "",
        f"not UTF-8 text: byte 0xe9 at offset {len(HEADER) + len(chr(10) + 'UR ')} (line 2)",
    ),
    ("utf-16", "UTF-16", "", "it starts like UTF-16"),
    ("too large", TOO_LARGE, "", f"is larger than {MAX_FILE_BYTES} bytes"),
    ("empty", "", "", "is empty: a stopping table starts with the header robot,category,"),
    ("blank and comments only", "\n# nothing\n  \n", "", "is empty"),
    ("header only", table(HEADER), "", "has a header but no rows"),
    ("no header", table(ROW), "header", "line 1 is not the header"),
    (
        "missing column",
        table(HEADER.replace(",source", ""), ROW.rsplit(",", 1)[0]),
        "header",
        "missing columns: source; the header must be robot,category,",
    ),
    (
        "renamed column",
        table(HEADER.replace("speed_deg_s", "speed"), ROW),
        "header",
        "missing columns: speed_deg_s; unexpected columns: speed;",
    ),
    (
        "out of order",
        table(HEADER.replace("robot,category", "category,robot"), ROW),
        "header",
        "columns out of order; the header must be",
    ),
    (
        "repeated column",
        table(HEADER.replace("joint_label", "joint"), ROW),
        "header",
        "missing columns: joint_label; repeated columns: joint",
    ),
    ("unclosed quote in header", table('robot,"category', ROW), "header", "cannot split"),
    ("too few cells", table(HEADER, ROW.rsplit(",", 1)[0]), "row 2", "has 10 cells, the header"),
    ("too many cells", table(HEADER, ROW + ",x"), "row 2", "has 12 cells, the header has 11"),
    (
        "unclosed quote",
        table(HEADER, with_cell("source", '"manual')),
        "row 2",
        "cannot split the line into cells",
    ),
    ("text after a quote", table(HEADER, with_cell("robot", '"a"b')), "row 2", "cannot split"),
    ("empty robot", table(HEADER, with_cell("robot", " ")), "row 2, column robot", "is empty"),
    ("empty joint", table(HEADER, with_cell("joint", "")), "row 2, column joint", "is empty"),
    ("empty source", table(HEADER, with_cell("source", "")), "row 2, column source", "is empty"),
    (
        "empty number",
        table(HEADER, with_cell("payload_kg", "")),
        "row 2, column payload_kg",
        "is empty; give a number (kg, >= 0 and <= 10000)",
    ),
    (
        "not a number",
        table(HEADER, with_cell("speed_deg_s", "fast")),
        "row 2, column speed_deg_s",
        f"'fast' is not a number {_NUMBERS}",
    ),
    (
        "a unit in the cell",
        table(HEADER, with_cell("speed_deg_s", "183 deg/s")),
        "row 2, column speed_deg_s",
        "'183 deg/s' is not a number",
    ),
    (
        "hexadecimal",
        table(HEADER, with_cell("stop_time_ms", "0x10")),
        "row 2, column stop_time_ms",
        "'0x10' is not a number (ms, > 0 and <= 1000000)",
    ),
    (
        "underscores",
        table(HEADER, with_cell("stop_time_ms", "1_000")),
        "row 2, column stop_time_ms",
        "is not a number",
    ),
    (
        "decimal comma",
        table(HEADER, with_cell("stop_distance_rad", '"0,22"')),
        "row 2, column stop_distance_rad",
        "'0,22' is not a number (rad, > 0 and <= 100); write decimals with a point",
    ),
    (
        "nan",
        table(HEADER, with_cell("speed_deg_s", "NaN")),
        "row 2, column speed_deg_s",
        f"'NaN' is not a finite number {_NUMBERS}",
    ),
    (
        "inf",
        table(HEADER, with_cell("payload_kg", "inf")),
        "row 2, column payload_kg",
        "is not a finite number",
    ),
    (
        "-infinity",
        table(HEADER, with_cell("stop_time_ms", "-Infinity")),
        "row 2, column stop_time_ms",
        "is not a finite number",
    ),
    (
        "overflow",
        table(HEADER, with_cell("stop_distance_rad", "1e999")),
        "row 2, column stop_distance_rad",
        "'1e999' is not a finite number",
    ),
    (
        "zero speed",
        table(HEADER, with_cell("speed_deg_s", "0")),
        "row 2, column speed_deg_s",
        f"'0' is out of range {_NUMBERS}",
    ),
    (
        "speed too high",
        table(HEADER, with_cell("speed_deg_s", "3600.5")),
        "row 2, column speed_deg_s",
        "'3600.5' is out of range",
    ),
    (
        "negative payload",
        table(HEADER, with_cell("payload_kg", "-1")),
        "row 2, column payload_kg",
        "'-1' is out of range (kg, >= 0 and <= 10000)",
    ),
    (
        "payload too high",
        table(HEADER, with_cell("payload_kg", "1e5")),
        "row 2, column payload_kg",
        "is out of range",
    ),
    (
        "zero extension",
        table(HEADER, with_cell("extension_pct", "0")),
        "row 2, column extension_pct",
        "'0' is out of range (%, > 0 and <= 100)",
    ),
    (
        "extension as a fraction above 100 %",
        table(HEADER, with_cell("extension_pct", "101")),
        "row 2, column extension_pct",
        "is out of range",
    ),
    (
        "zero time",
        table(HEADER, with_cell("stop_time_ms", "0")),
        "row 2, column stop_time_ms",
        "is out of range",
    ),
    (
        "time too long",
        table(HEADER, with_cell("stop_time_ms", "2e6")),
        "row 2, column stop_time_ms",
        "is out of range",
    ),
    (
        "negative distance",
        table(HEADER, with_cell("stop_distance_rad", "-0.22")),
        "row 2, column stop_distance_rad",
        "is out of range (rad, > 0 and <= 100)",
    ),
    (
        "distance too long",
        table(HEADER, with_cell("stop_distance_rad", "101")),
        "row 2, column stop_distance_rad",
        "is out of range",
    ),
    (
        "category 2",
        table(HEADER, with_cell("category", "2")),
        "row 2, column category",
        "'2' is not a stop category; allowed: 0 or 1",
    ),
    (
        "category as a float",
        table(HEADER, with_cell("category", "0.0")),
        "row 2, column category",
        "'0.0' is not a stop category",
    ),
    (
        "empty category",
        table(HEADER, with_cell("category", "")),
        "row 2, column category",
        "is empty",
    ),
    (
        "unknown motion",
        table(HEADER, with_cell("motion", "sideways")),
        "row 2, column motion",
        "'sideways' is not a motion; allowed: horizontal, down, up",
    ),
    (
        "motion in capitals",
        table(HEADER, with_cell("motion", "Down")),
        "row 2, column motion",
        "'Down' is not a motion",
    ),
    ("empty motion", table(HEADER, with_cell("motion", "")), "row 2, column motion", "is empty"),
    (
        "duplicate",
        table(HEADER, ROW, ROW_B, with_cell("stop_time_ms", "170")),
        "row 4",
        "repeats row 2: same joint, category, speed, payload, extension and motion",
    ),
    (
        "duplicate written differently",
        table(HEADER, ROW, with_cell("speed_deg_s", "1.83e2")),
        "row 3",
        "repeats row 2",
    ),
    (
        "two robots",
        table(HEADER, ROW, with_cell("robot", "UR10", ROW_B)),
        "row 3, column robot",
        "'UR10' differs from 'UR5' of row 2; a table holds one robot's data",
    ),
    (
        "rows numbered by file lines",
        table("# comment", HEADER, "", ROW, "# another", with_cell("motion", "left")),
        "row 6, column motion",
        "'left' is not a motion",
    ),
]


@pytest.mark.parametrize(
    ("content", "key", "phrase"),
    [case[1:] for case in BAD_TABLES],
    ids=[case[0] for case in BAD_TABLES],
)
def test_bad_tables_are_refused_in_one_line_naming_row_and_column(tmp_path, content, key, phrase):
    path = tmp_path / "table.csv"
    if content == TOO_LARGE:
        path.write_bytes(table(HEADER, ROW).encode() + b"#" * MAX_FILE_BYTES)
    elif content == "UTF-16":
        path.write_bytes(table(HEADER, ROW).encode("utf-16"))
    elif content is not None:
        path.write_bytes(content.encode("utf-8", errors="surrogateescape"))
    error = refused(path)
    assert error.key == key
    assert phrase in error.problem
    assert str(error).startswith(f"{path}: '{key}': " if key else f"{path}: ")


def test_a_folder_is_refused(tmp_path):
    error = refused(tmp_path)
    assert error.key == "" and "is a folder, not a regular file" in error.problem


def test_a_long_cell_is_cut_in_the_message(tmp_path):
    path = tmp_path / "table.csv"
    path.write_text(table(HEADER, with_cell("speed_deg_s", "x" * 10_000)), encoding="utf-8")
    error = refused(path)
    assert error.key == "row 2, column speed_deg_s" and len(str(error)) < 300


def test_the_message_reads_as_documented(tmp_path):
    path = tmp_path / "table.csv"
    path.write_text(table(HEADER, ROW_B, with_cell("speed_deg_s", "fast")), encoding="utf-8")
    assert str(refused(path)) == (
        f"{path}: 'row 3, column speed_deg_s': 'fast' is not a number (deg/s, > 0 and <= 3600)"
    )


# -- joints --------------------------------------------------------------------------------


def test_check_joints_accepts_the_robots_joints_and_names_a_foreign_one(tmp_path):
    path = tmp_path / "table.csv"
    path.write_text(table(HEADER, ROW_B, ROW), encoding="utf-8")
    t = read_stopping_table(path)
    check_joints(t, UR5_JOINTS)
    check_joints(t, ["elbow_joint", "shoulder_lift_joint"])
    without_elbow = [j for j in UR5_JOINTS if j != "elbow_joint"]
    with pytest.raises(TableError) as info:
        check_joints(t, without_elbow)
    error = info.value
    assert error.source == str(path) and error.key == "row 3, column joint"
    assert error.problem == (
        "'elbow_joint' is not a joint of the robot; its joints are: " + ", ".join(without_elbow)
    )
    assert "\n" not in str(error)


# -- round trip ----------------------------------------------------------------------------

_TEXT = (
    st.text(st.characters(blacklist_categories=("Cs", "Cc", "Zl", "Zp")), max_size=20)
    .map(str.strip)
    .filter(bool)
)
_ROBOT = _TEXT.filter(lambda s: not s.startswith("#"))  # a line starting with # is a comment
_RAW_ROW = st.fixed_dictionaries(
    {
        "category": st.sampled_from([0, 1]),
        "joint": _TEXT,
        "joint_label": st.one_of(st.just(""), _TEXT),
        "speed_deg_s": st.floats(0.0, 3600.0, exclude_min=True),
        "payload_kg": st.floats(0.0, 1e4),
        "extension_pct": st.floats(0.0, 100.0, exclude_min=True),
        "motion": st.sampled_from(MOTIONS),
        "stop_time_ms": st.floats(0.0, 1e6, exclude_min=True),
        "stop_distance_rad": st.floats(0.0, 100.0, exclude_min=True),
        "source": _TEXT,
    }
)


def _expected(line: int, robot: str, raw: dict) -> StoppingRow:
    return StoppingRow(
        line=line,
        robot=robot,
        category=raw["category"],
        joint=raw["joint"],
        joint_label=raw["joint_label"],
        speed=math.radians(raw["speed_deg_s"]),
        payload=raw["payload_kg"],
        extension=raw["extension_pct"] / 100,
        motion=raw["motion"],
        stop_time=raw["stop_time_ms"] / 1000,
        stop_distance=raw["stop_distance_rad"],
        source=raw["source"],
    )


def _identity(raw: dict) -> tuple:
    row = _expected(0, "", raw)
    return (row.joint, row.category, row.speed, row.payload, row.extension, row.motion)


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(robot=_ROBOT, raws=st.lists(_RAW_ROW, min_size=1, max_size=6, unique_by=_identity))
def test_valid_rows_written_with_csv_read_back_equal(tmp_path, robot, raws):
    path = tmp_path / "round_trip.csv"
    with path.open("w", encoding="utf-8", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(COLUMNS)
        for raw in raws:
            cells = {"robot": robot, **raw}
            writer.writerow(
                repr(v) if isinstance(v, float) else v for v in (cells[c] for c in COLUMNS)
            )
    t = read_stopping_table(path)
    # repr of a float reads back as the same float, so the rows are equal, not merely close.
    assert t.rows == tuple(_expected(line, robot, raw) for line, raw in enumerate(raws, start=2))
    assert t.robot == robot
