import copy
import math
import time

import pytest
from conftest import SCENARIOS
from hypothesis import example, given, settings
from hypothesis import strategies as st

from vtm_pin.exceptions import ScenarioError, excerpt
from vtm_pin.files.inputs import (
    MAX_DEPTH,
    MAX_FILE_BYTES,
    MAX_NODES,
    _walk,
    check_schema,
    read_yaml,
)

SCHEMA = {
    "type": "object",
    "additionalProperties": False,
    "properties": {
        "duration": {"type": "number", "exclusiveMinimum": 0, "maximum": 10, "description": "[s]"},
        "q": {
            "oneOf": [
                {"type": "array", "items": {"type": "number"}},
                {"type": "object", "additionalProperties": {"type": "number"}},
            ]
        },
        "nested": {"type": "object"},
    },
}


def read(tmp_path, content: bytes):
    path = tmp_path / "s.yaml"
    path.write_bytes(content)
    return read_yaml(path, ScenarioError)


def refused(tmp_path, content: bytes) -> str:
    with pytest.raises(ScenarioError) as info:
        read(tmp_path, content)
    message = str(info.value)
    assert message.startswith(str(tmp_path / "s.yaml")) and "\n" not in message
    return message


def test_alias_bomb_is_refused_at_once_with_a_short_message(tmp_path):
    # "Billion laughs": 9 levels of 10 aliases expand to 10^9 values. The composer counts
    # values as expanded and stops past MAX_NODES, having read a few lines: measured ~3 ms,
    # the bound leaves room for a slow machine.
    lines = ["a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, 10)]
    start = time.perf_counter()
    message = refused(tmp_path, "\n".join(lines).encode())
    assert time.perf_counter() - start < 1.0
    assert f"more than {MAX_NODES} values (an alias counts as the values it repeats)" in message
    assert len(message) < 200 + len(str(tmp_path))


def test_a_few_aliases_are_fine(tmp_path):
    doc = read(tmp_path, b"a: &b {gear_ratio: 100}\nc: *b\nd: *b\n")
    assert doc["c"] == doc["d"] == {"gear_ratio": 100}


def test_alias_inside_the_collection_it_names_is_refused(tmp_path):
    assert "refers to a collection that contains it" in refused(tmp_path, b"a: &x [1, *x]\n")


@pytest.mark.parametrize("depth", [MAX_DEPTH + 1, 1000, 100_000])
def test_deep_nesting_is_refused(tmp_path, depth):
    message = refused(tmp_path, b"a: " + b"[" * depth + b"]" * depth)
    assert f"nested deeper than {MAX_DEPTH} levels" in message and "line 1" in message


def test_nesting_within_the_limit_reads(tmp_path):
    depth = MAX_DEPTH - 2  # the mapping and its value take the other two levels
    doc = read(tmp_path, b"a: " + b"[" * depth + b"]" * depth)
    assert isinstance(doc["a"], list)


def test_large_file_is_refused(tmp_path):
    message = refused(tmp_path, b"description: " + b"a" * MAX_FILE_BYTES)
    assert f"larger than {MAX_FILE_BYTES} bytes" in message


@pytest.mark.parametrize(
    "content, words",
    [
        ("description: Stäubli\n".encode("latin-1"), "is not UTF-8 text: byte 0xe4 at offset 15"),
        ("description: Stäubli\n".encode("utf-16"), "(it starts like UTF-16)"),
        (bytes(range(256)), "is not UTF-8 text"),
        (b"robot: x\x00\n", "contains the character U+0000"),
        (b"robot: x\x07\n", "contains the character U+0007"),
        (b"duration: " + b"9" * 5000 + b"\n", "'duration': an integer of 5000 digits at line 1"),
        (b"robot: [x\nduration: 1\n", "not valid YAML at line 2: expected ',' or ']'"),
        (b"a: !!python/object:os.system x\n", "not valid YAML at line 1"),
    ],
)
def test_bytes_that_are_not_a_yaml_text_give_one_line(tmp_path, content, words):
    assert words in refused(tmp_path, content)


def test_utf8_with_a_byte_order_mark_reads(tmp_path):
    assert read(tmp_path, "\ufeffdescription: Stäubli\n".encode())["description"] == "Stäubli"


def check(raw):
    with pytest.raises(ScenarioError) as info:
        check_schema(raw, SCHEMA, "s.yaml", ScenarioError)
    return str(info.value)


@pytest.mark.parametrize(
    "value, words",
    [
        (math.nan, "'duration': nan is not a finite number"),
        (math.inf, "'duration': inf is not a finite number"),
        (10**400, "'duration': <an integer of 400 digits> is not a finite number"),
        (1e308, "'duration': 1e+308 must be <= 10 s"),
        (0, "'duration': 0 must be > 0 s"),
        ("1.5", "'duration': '1.5' is not a number (a number in quotes is text: drop the quotes)"),
    ],
)
def test_numbers_must_be_finite_and_in_range(value, words):
    assert words in check({"duration": value})


def test_a_list_item_is_named_by_its_index():
    assert "'q[1]': nan is not a finite number" in check({"q": [0.0, math.nan]})
    assert "'q.joint1': 'x' is not a number" in check({"q": {"joint1": "x"}})
    assert "'q': 'x' must be a list of numbers or a mapping" in check({"q": "x"})


def test_keys_of_mixed_types_are_refused_without_sorting_them():
    assert check({1: "a", "foo": "b"}) == "s.yaml: key 1 (int) is not a name: quote it ('1')"
    assert "'nested': key None (NoneType) is not a name" in check({"nested": {None: 1, "a": 2}})


def test_echoed_values_are_short_excerpts():
    long = "x" * 10_000 + "\n"
    message = check({long: 1})
    assert "'" + "x" * 59 + "…': unknown key; allowed keys here: duration, nested, q" in message
    assert len(check({"q": [long]})) < 200
    assert excerpt("a\nb") == "a\\nb" and len(excerpt("y" * 1000)) == 60


def test_too_many_values_built_in_python_are_refused():
    message = check({"nested": {"a": list(range(MAX_NODES))}})
    assert f"has more than {MAX_NODES} values" in message


@pytest.mark.parametrize("text", ["1e-4", "1.0e-4", "1e+3", "1E3", ".5e1", "-2.5e-3"])
def test_exponents_read_as_numbers_as_in_yaml_1_2(tmp_path, text):
    assert read(tmp_path, f"x: {text}\n".encode())["x"] == float(text)


# A study's cases are checked against their base: only the top-level values that differ are
# validated again. That must raise exactly when, and with exactly the message that, the whole
# check does.

_VALUES = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-3, 3),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=4),
    st.lists(st.floats(-2.0, 2.0), max_size=7),
    st.dictionaries(
        st.sampled_from(["joint", "speed", "mass", "t", "category", "zz"]),
        st.one_of(st.floats(-2.0, 2.0), st.text(max_size=3)),
        max_size=3,
    ),
)


@settings(max_examples=300, deadline=None)
@given(
    key=st.sampled_from(
        ["annex_b", "payload", "stop", "brakes", "duration", "robot", "initial", "typo"]
    ),
    inner=st.sampled_from([None, "joint", "speed", "mass", "category", "elbow_joint", "q"]),
    value=_VALUES,
)
@example(key="stop", inner="category", value=False)  # 0 == False, but False is no category
def test_checking_against_a_valid_base_raises_as_the_whole_check_does(key, inner, value):
    from vtm_pin.scene.scenario import SCHEMA as SCENARIO_SCHEMA

    base = read_yaml(SCENARIOS / "ur10_annex_b.yaml", ScenarioError)
    raw = copy.deepcopy(base)
    if inner is None or not isinstance(raw.get(key), dict):
        raw[key] = value
    else:
        raw[key][inner] = value

    def outcome(**valid):
        try:
            check_schema(raw, SCENARIO_SCHEMA, "case", ScenarioError, **valid)
        except ScenarioError as exc:
            return str(exc)
        return None

    assert outcome(valid=base) == outcome()


def test_checking_against_a_valid_base_counts_every_value_of_the_case():
    """A base at the value limit passes; a case that adds one value to it must not."""
    from vtm_pin.scene.scenario import SCHEMA as SCENARIO_SCHEMA

    base = dict(read_yaml(SCENARIOS / "ur10_annex_b.yaml", ScenarioError))
    base.pop("payload")
    size = sum(1 for _ in _walk(base, [], "", ScenarioError))
    base["assumptions"] = [*base["assumptions"], *["a"] * (MAX_NODES - size)]
    check_schema(base, SCENARIO_SCHEMA, "base", ScenarioError)  # at the limit: passes
    raw = {**base, "payload": {"mass": 5.0}}
    with pytest.raises(ScenarioError, match=f"has more than {MAX_NODES} values"):
        check_schema(raw, SCENARIO_SCHEMA, "case", ScenarioError, valid=base)
