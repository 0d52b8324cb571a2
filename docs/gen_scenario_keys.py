"""The scenario key reference, generated from the scenario schema so that it cannot drift.

The schema is ``vtm_pin.scene.scenario.SCHEMA``.

MkDocs runs this file as a hook (``hooks:`` in ``mkdocs.yml``): the marker
``<!-- scenario-keys -->`` in a page is replaced by a table with one row per key path
(``brakes.<joint>.delay``, ``events[].t``), its type, unit, default and allowed values, all
read from the schema. ``tests/test_docs.py`` checks the table against the schema.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any

MARKER = "<!-- scenario-keys -->"

TYPE_WORDS = {
    "number": "number",
    "string": "string",
    "boolean": "boolean",
    "array": "list",
    "object": "mapping",
}


def schema_keys(schema: dict[str, Any], prefix: str = "") -> Iterator[tuple[str, dict, bool]]:
    """Each key path below ``schema``, with its sub-schema and whether it is required.

    The constraint spec is listed once, under ``constraints[]``; ``events[].activate`` reuses it.
    """
    shared = schema.get("properties", {}).get("constraints", {}).get("items")
    yield from _walk(schema, prefix, shared)


def _walk(schema: dict[str, Any], prefix: str, shared: Any) -> Iterator[tuple[str, dict, bool]]:
    for key, sub in schema.get("properties", {}).items():
        path = f"{prefix}{key}"
        yield path, sub, key in schema.get("required", [])
        if sub.get("items") is shared and path != "constraints":
            continue
        if sub.get("type") == "object" and "properties" in sub:
            yield from _walk(sub, f"{path}.", shared)
        if sub.get("type") == "object" and isinstance(sub.get("additionalProperties"), dict):
            yield from _walk(sub["additionalProperties"], f"{path}.<joint>.", shared)
        if sub.get("type") == "array" and isinstance(sub.get("items"), dict):
            yield from _walk(sub["items"], f"{path}[].", shared)


def type_text(schema: dict[str, Any]) -> str:
    """The type of a value in words: ``number``, ``list of strings``, ``list or mapping``."""
    if "oneOf" in schema:
        return " or ".join(dict.fromkeys(type_text(alt) for alt in schema["oneOf"]))
    if "enum" in schema:
        return "integer" if isinstance(schema["enum"][0], int) else "string"
    kind = schema.get("type", "")
    if kind == "number" and schema.get("multipleOf") == 1:
        return "whole number"
    if kind == "array" and isinstance(schema.get("items"), dict) and "type" in schema["items"]:
        return f"list of {TYPE_WORDS[schema['items']['type']]}s"
    if kind == "object" and isinstance(schema.get("additionalProperties"), dict):
        return "mapping {joint: value}"
    return TYPE_WORDS.get(kind, kind)


def _number(value: float) -> str:
    """``1e6`` rather than ``1e+06`` or ``1000000``; other values as Python writes them."""
    power = f"{value:.0e}".replace("e+0", "e").replace("e+", "e")
    return power if abs(value) >= 1e4 and float(power) == value else f"{value:g}"


def allowed_text(schema: dict[str, Any]) -> str:
    """Allowed values (enum, bounds) and the description without its default."""
    parts = [", ".join(f"`{value}`" for value in schema["enum"])] if "enum" in schema else []
    low = {
        "exclusiveMinimum": f"> {_number(schema.get('exclusiveMinimum', 0))}",
        "minimum": f"≥ {_number(schema.get('minimum', 0))}",
    }
    parts += [text for name, text in low.items() if name in schema]
    if "maximum" in schema:
        parts.append(f"≤ {_number(schema['maximum'])}")
    description = re.sub(r"\s*Default: .+\.$", "", schema.get("description", ""))
    text = "; ".join(part for part in (" and ".join(parts), description) if part)
    return text.replace("|", "\\|")


def key_rows(schema: dict[str, Any]) -> list[list[str]]:
    """Key, type, unit, default and allowed values of every key path, in schema order."""
    rows = []
    for path, sub, required in schema_keys(schema):
        description = sub.get("description", "")
        stated = re.search(r"Default: (.+)\.$", description)
        default = "required" if required else (stated.group(1) if stated else "")
        nested = "properties" in sub or "additionalProperties" in sub
        numbers = sub.get("type") == "array" and sub.get("items", {}).get("type") == "number"
        leaf = not nested and (sub.get("type") not in ("object", "array") or numbers)
        units = re.findall(r"\[([^\]]+)\]", description) if leaf else []
        unit = units[0] if units else ""
        cells = [type_text(sub), unit, default]
        rows.append([f"`{path}`", *(cell.replace("|", "\\|") for cell in cells)])
        rows[-1].append(allowed_text(sub))
    return rows


def key_table(schema: dict[str, Any]) -> str:
    """The reference table in Markdown."""
    lines = ["| key | type | unit | default | allowed / meaning |", "|---|---|---|---|---|"]
    lines += ["| " + " | ".join(row) + " |" for row in key_rows(schema)]
    return "\n".join(lines)


def on_page_markdown(markdown: str, **_: Any) -> str:
    """MkDocs hook: put the generated table where a page has the marker."""
    if MARKER not in markdown:
        return markdown
    from vtm_pin.scene.scenario import SCHEMA

    return markdown.replace(MARKER, key_table(SCHEMA))
