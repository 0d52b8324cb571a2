"""The JSON Schemas of scenario and study files, shipped as package data and read once.

``scenario.schema.json`` and ``study.schema.json`` (JSON Schema draft 2020-12) are the single
source of the rules of those files: :mod:`vtm_pin.scene.scenario` and :mod:`vtm_pin.study.cases`
validate with them, and editors read them through a file's ``# yaml-language-server: $schema=...``
comment. Parts used more than once (a drive, a brake, a constraint, a calibration) are
``$defs`` of the scenario schema, referred to with ``$ref``; :func:`load_schema` returns the
schema with every ``$ref`` replaced by its definition, so that the code can walk and cut it
(``SCHEMA["properties"]["integrator"]``) as a plain dict.

A standard validator agrees with the project's check (``tests/test_schemas.py``) on every
document JSON can hold. The project adds one rule a schema cannot state: a ``number`` is
finite, so YAML's ``.nan`` (which passes every ``minimum`` and ``maximum``) is refused.
"""

from __future__ import annotations

import json
from functools import cache
from importlib import resources
from typing import Any

#: Keys of a schema file's top level that annotate the file and are not rules of a document.
_ANNOTATIONS = ("$schema", "$id", "title", "description", "$comment", "$defs")


def schema_file(name: str) -> Any:
    """The shipped file of schema ``name`` (``scenario`` or ``study``), as a resource."""
    return resources.files(__name__) / f"{name}.schema.json"


@cache
def raw_schema(name: str) -> dict[str, Any]:
    """Schema ``name`` as its file gives it (with ``$defs`` and ``$ref``), read once."""
    data: dict[str, Any] = json.loads(schema_file(name).read_text(encoding="utf-8"))
    return data


def load_schema(name: str) -> dict[str, Any]:
    """Schema ``name`` with every ``$ref`` inlined and without the file's annotations.

    A fresh copy on each call: callers may keep or extend it. Within it, each plain
    ``{"$ref": ...}`` of one definition is the same dict (``constraints[]`` and
    ``events[].activate[]`` share theirs), so a walk can tell a reused part.
    """
    raw = raw_schema(name)
    rules = {k: v for k, v in raw.items() if k not in _ANNOTATIONS}
    return _inline(rules, raw.get("$defs", {}), {})


def definition(name: str, key: str) -> dict[str, Any]:
    """The definition ``$defs/<key>`` of schema ``name``, its own ``$ref`` inlined."""
    defs = raw_schema(name)["$defs"]
    return _inline(defs[key], defs, {})


def _inline(node: Any, defs: dict[str, Any], done: dict[str, Any]) -> Any:
    """``node`` with each ``{"$ref": "#/$defs/x", ...}`` replaced by ``x``'s keys in its place.

    ``done`` holds the definitions inlined so far, by name, each built once.
    """
    if isinstance(node, list):
        return [_inline(item, defs, done) for item in node]
    if not isinstance(node, dict):
        return node
    if "$ref" in node:
        ref = node["$ref"].removeprefix("#/$defs/")
        if ref not in done:
            done[ref] = _inline(defs[ref], defs, done)
        if len(node) == 1:
            return done[ref]
    out: dict[str, Any] = {}
    for key, value in node.items():
        if key == "$ref":
            out.update({k: v for k, v in done[ref].items() if k not in node})
        else:
            out[key] = _inline(value, defs, done)
    return out
