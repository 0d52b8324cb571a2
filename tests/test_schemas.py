"""The shipped JSON Schemas: standard files, the rules the project checks, and the editor line.

``vtm_pin/schemas/scenario.schema.json`` and ``study.schema.json`` are the rules of scenario and
study files. A standard validator (``jsonschema.Draft202012Validator`` on the file as shipped,
``$ref`` and all, without the project's finite-number type) must give the project's own schema
verdict (:func:`vtm_pin.files.inputs.check_schema`) on every shipped file and on generated bad
input: the scenarios of ``tests/test_bad_input.py`` and every one-value mutation of the shipped
studies.

Compared: schema-level verdicts only, on documents JSON can hold. Left out, and counted:

* documents the reader refuses before any schema (not YAML, alias bombs, deep nesting, keys
  given twice): no schema sees them;
* documents holding a value JSON has not: YAML's ``.nan`` and ``.inf`` (a standard validator
  refuses ``inf`` by every number's bounds but passes ``nan``, which no bound catches; the
  project refuses both as not finite) and keys that are not strings (the project refuses them
  by name; JSON keys are strings).

Rules checked in code beyond the schema (joints and frames of the robot, events within the
duration, ...) are not schema verdicts: inputs that pass both validators and are refused by
``vtm-pin`` for such a rule are counted, not compared.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import jsonschema
import pytest
import yaml
from conftest import ROOT, SCENARIOS
from test_bad_input import replaced

from vtm_pin.exceptions import InputError, ScenarioError, StudyError
from vtm_pin.files.inputs import check_schema, read_yaml
from vtm_pin.numerics.integrators import INTEGRATORS
from vtm_pin.numerics.transitions import TRANSITIONS
from vtm_pin.scene.scenario import SCENARIOS_DIR, SCHEMA
from vtm_pin.schemas import raw_schema, schema_file
from vtm_pin.study.cases import STUDIES_DIR, STUDY_SCHEMA

STUDIES = ROOT / "studies"
STANDARD = {
    "scenario": jsonschema.Draft202012Validator(raw_schema("scenario")),
    "study": jsonschema.Draft202012Validator(raw_schema("study")),
}
PROJECT = {"scenario": (SCHEMA, ScenarioError), "study": (STUDY_SCHEMA, StudyError)}
#: The first line of each shipped file, for editors (VS Code's YAML extension and others).
EDITOR_LINE = "# yaml-language-server: $schema=../vtm_pin/schemas/{}.schema.json"


def shipped(kind: str) -> list[Path]:
    """The shipped files of ``kind``: in the clone and in the package (once each)."""
    folders = (SCENARIOS, SCENARIOS_DIR) if kind == "scenario" else (STUDIES, STUDIES_DIR)
    found = {p.resolve(): p for folder in folders for p in folder.glob("*.yaml")}
    return sorted(found.values())


def project_passes(kind: str, raw: Any) -> bool:
    schema, error = PROJECT[kind]
    try:
        check_schema(raw, schema, "s.yaml", error)
    except InputError:
        return False
    return True


def json_like(value: Any) -> bool:
    """Whether JSON can hold ``value``: no NaN or infinity, string keys, JSON types only."""
    if isinstance(value, dict):
        return all(isinstance(k, str) and json_like(v) for k, v in value.items())
    if isinstance(value, list):
        return all(json_like(v) for v in value)
    if isinstance(value, float):
        return math.isfinite(value)
    return value is None or isinstance(value, (str, int, bool))


def bounded(schema: Any) -> list[str]:
    """Where a ``number`` or ``integer`` of a schema file lacks a lower or an upper bound."""
    out = []
    if isinstance(schema, dict):
        if schema.get("type") in ("number", "integer"):
            lows = ("minimum", "exclusiveMinimum")
            if not any(k in schema for k in lows) or "maximum" not in schema:
                out.append(str(schema))
        for value in schema.values():
            out += bounded(value)
    elif isinstance(schema, list):
        for value in schema:
            out += bounded(value)
    return out


@pytest.mark.parametrize("kind", ["scenario", "study"])
def test_schema_files_are_standard_draft_2020_12_with_bounded_numbers(kind):
    raw = raw_schema(kind)
    jsonschema.Draft202012Validator.check_schema(raw)  # raises on a malformed schema
    assert raw["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert raw["$id"].endswith(f"{kind}.schema.json") and raw["title"].startswith("vtm-pin")
    # every number is bounded on both sides, so a standard validator refuses ±inf too
    assert bounded(raw) == []
    if kind == "scenario":  # the units live in the descriptions
        assert "duration" in raw["properties"] and "[s]" in schema_file(kind).read_text()


def test_the_names_the_schema_lists_are_the_codes_own():
    """The schema file lists integrators and transition rules: they must be the code's."""
    assert SCHEMA["properties"]["integrator"]["properties"]["method"]["enum"] == sorted(INTEGRATORS)
    assert SCHEMA["properties"]["transition"]["enum"] == sorted(TRANSITIONS)


@pytest.mark.parametrize("kind", ["scenario", "study"])
def test_every_shipped_file_passes_both_validators(kind):
    files = shipped(kind)
    assert len(files) >= (10 if kind == "scenario" else 4)
    for path in files:
        raw = read_yaml(path, PROJECT[kind][1])
        assert project_passes(kind, raw), path
        assert STANDARD[kind].is_valid(raw), path


@pytest.mark.parametrize("kind", ["scenario", "study"])
def test_shipped_files_name_their_schema_for_editors(kind):
    """The first line points editors at the schema by a path that works in a clone."""
    folder = SCENARIOS if kind == "scenario" else STUDIES
    for path in sorted(folder.glob("*.yaml")):
        first, rest = path.read_text().split("\n", 1)
        assert first == EDITOR_LINE.format(kind), path
        target = (path.parent / first.split("$schema=", 1)[1]).resolve()
        assert target.read_bytes() == schema_file(kind).read_bytes(), path
        # a comment to the reader: the document is the same without the line
        assert yaml.safe_load(rest) == read_yaml(path, InputError), path


def test_standard_validator_agrees_on_the_bad_scenario_corpus(tmp_path):
    """Same verdicts on ~400 generated scenarios; the rest counted (3 s, and 10 s more to
    generate the corpus when tests/test_bad_input.py has not been collected)."""
    from test_bad_input import CASES

    counts = dict.fromkeys(["compared", "refused", "unread", "not json", "code rules"], 0)
    for case in CASES:
        text = case.files.get("s.yaml")
        if text is None or case.name.split("-")[1] == "deep":  # deep: refused by the reader,
            continue  # and reading 5000 levels takes 0.2 s each
        path = tmp_path / "s.yaml"
        path.write_bytes(text)
        try:
            raw = read_yaml(path, ScenarioError)
        except ScenarioError:
            counts["unread"] += 1
            continue
        verdict = project_passes("scenario", raw)
        if not json_like(raw):
            counts["not json"] += 1
            assert not verdict, case.name  # NaN, inf and non-string keys: all refused
            continue
        assert STANDARD["scenario"].is_valid(raw) == verdict, case.name
        counts["compared"] += 1
        counts["refused"] += not verdict
        counts["code rules"] += verdict
    print(counts)
    assert counts["compared"] >= 250 and counts["refused"] >= 100, counts
    assert counts["not json"] >= 20, counts


BAD_VALUES: list[Any] = ["abc", 1.5, -1, 10**400, 1e12, None, True, [], ["a"], {"a": 1}, {}]


def leaves(doc: Any, path: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Paths of every value of a parsed document (mappings and lists too)."""
    children: Any = doc.items() if isinstance(doc, dict) else []
    if isinstance(doc, list):
        children = enumerate(doc)
    return [path] + [p for k, v in children for p in leaves(v, (*path, k))]


def test_standard_validator_agrees_on_every_one_value_change_of_the_shipped_studies():
    compared = refused = 0
    docs = {repr(d): d for d in (read_yaml(p, StudyError) for p in shipped("study"))}
    for doc in docs.values():  # the clone's and the package's copies are the same files
        for where in leaves(doc):
            node = doc
            for part in where:
                node = node[part]
            changes = [replaced(doc, where, value) for value in BAD_VALUES]
            if isinstance(node, dict):
                changes.append(replaced(doc, where, {**node, "zz_unknown": 1}))
            for raw in changes:
                verdict = project_passes("study", raw)
                assert STANDARD["study"].is_valid(raw) == verdict, (where, raw)
                compared += 1
                refused += not verdict
    assert compared >= 500 and refused >= 200, (compared, refused)
