"""The README stays true: its commands are the ones CI runs, its key table matches the schema."""

import re

import pytest
from conftest import ROOT

from vtm_pin.scenario import SCHEMA

README = (ROOT / "README.md").read_text()


#: The constraint spec is documented once, under `constraints[]`; `events[].activate` reuses it.
SHARED = SCHEMA["properties"]["constraints"]["items"]


def schema_keys(schema, prefix=""):
    for key, sub in schema.get("properties", {}).items():
        path = f"{prefix}{key}"
        yield path
        if sub.get("items") is SHARED and path != "constraints":
            continue
        if sub.get("type") == "object" and "properties" in sub:
            yield from schema_keys(sub, f"{path}.")
        if sub.get("type") == "object" and isinstance(sub.get("additionalProperties"), dict):
            yield from schema_keys(sub["additionalProperties"], f"{path}.<joint>.")
        if sub.get("type") == "array" and isinstance(sub.get("items"), dict):
            yield from schema_keys(sub["items"], f"{path}[].")


def readme_rows():
    """Key -> (type, unit, default, allowed) of the README's scenario-key table."""
    section = README.split("## Scenario files", 1)[1].split("\n## ", 1)[0]
    rows = {}
    for line in section.splitlines():
        match = re.match(r"^\| `([^`]+)` \|(.*)\|$", line)
        if match:
            cells = [c.strip() for c in re.split(r"(?<!\\)\|", match.group(2))]
            assert len(cells) == 4, line
            rows[match.group(1)] = cells
    return rows


def schema_at(path):
    """The schema of a key path such as ``brakes.<joint>.delay`` or ``events[].t``."""
    sub = SCHEMA
    for part in re.split(r"\.(?![^<]*>)", path):
        name = part.removesuffix("[]")
        sub = sub["additionalProperties"] if name == "<joint>" else sub["properties"][name]
        if part.endswith("[]"):
            sub = sub["items"]
    return sub


def required_keys(schema, prefix=""):
    for key, sub in schema.get("properties", {}).items():
        path = f"{prefix}{key}"
        if key in schema.get("required", []):
            yield path
        if sub.get("type") == "object":
            yield from required_keys(sub, f"{path}.")
        if sub.get("type") == "array" and sub.get("items", {}).get("type") == "object":
            yield from required_keys(sub["items"], f"{path}[].")


TYPE_WORDS = {"number": "number", "string": "string", "boolean": "boolean", "array": "list"}
TYPE_WORDS["object"] = "mapping"


def type_words(schema):
    if "oneOf" in schema:
        return {w for alt in schema["oneOf"] for w in type_words(alt)}
    if "enum" in schema:
        return {"integer" if isinstance(schema["enum"][0], int) else "string"}
    return {TYPE_WORDS[schema["type"]]}


def test_readme_key_table_matches_schema():
    assert set(readme_rows()) == set(schema_keys(SCHEMA))


@pytest.mark.parametrize("key", sorted(schema_keys(SCHEMA)))
def test_readme_key_row_agrees_with_schema(key):
    """Type, unit, default and allowed values of each documented key follow the schema."""
    kind, unit, default, allowed = readme_rows()[key]
    schema = schema_at(key)
    for word in type_words(schema):
        assert word in kind, f"{key}: type column '{kind}' lacks '{word}'"
    for value in schema.get("enum", []):
        assert f"`{value}`" in allowed, f"{key}: allowed values lack `{value}`"
    if schema.get("exclusiveMinimum") == 0:
        assert "> 0" in allowed, f"{key}: allowed values lack '> 0'"
    if schema.get("minimum") == 0:
        assert "≥ 0" in allowed, f"{key}: allowed values lack '≥ 0'"
    if key in set(required_keys(SCHEMA)):
        assert default == "required", f"{key}: required in the schema, README says '{default}'"
    else:
        assert not default == "required", f"{key}: optional in the schema"
    description = schema.get("description", "")
    stated = re.search(r"Default: (.+)\.$", description)
    if stated:
        assert default.replace("`", "") == stated.group(1), f"{key}: default differs"
    leaf = schema.get("type") not in ("object", "array") or "items" not in schema
    leaf = leaf and "properties" not in schema and "additionalProperties" not in schema
    units = re.findall(r"\[([^\]]+)\]", description)
    if leaf:
        assert bool(units) == bool(unit), f"{key}: unit '{unit}' vs schema {units}"
        if units:
            assert unit.startswith(units[0]), f"{key}: unit '{unit}' vs schema [{units[0]}]"


def test_ci_runs_the_readme_test_command():
    commands = re.findall(r"```bash\n(.+?)\n```", README)
    assert len(commands) == 2
    assert commands[1] in (ROOT / ".ci" / "run").read_text()
    assert "vtm-pin run scenarios/pendulum3r.yaml" in commands[0]


#: RMS pixel difference (0-255) allowed between the README's pictures and a fresh run: 0 on
#: one machine; room for font anti-aliasing of another matplotlib build. Measured: halving
#: dt moves lines by sub-pixels (RMS 0.04); the naive run replaced by another rule gives 18.
PICTURE_RMS = 2.0


def test_readme_pictures_are_what_the_first_command_draws(tmp_path):
    from matplotlib.testing.compare import compare_images

    from vtm_pin.cli import main

    command = re.findall(r"```bash\n(.+?)\n```", README)[0]
    arguments = command.split("vtm-pin ", 1)[1].split()
    out = tmp_path / "results"
    arguments[arguments.index("--out") + 1] = str(out)
    arguments[1] = str(ROOT / arguments[1])
    assert main([*arguments, "--quiet"]) == 0
    for produced, shown in [
        ("poses.png", "pendulum3r_poses.png"),
        ("momenta.png", "pendulum3r_momenta.png"),
    ]:
        assert f"](docs/{shown})" in README
        difference = compare_images(str(ROOT / "docs" / shown), str(out / produced), PICTURE_RMS)
        assert difference is None, (
            f"{difference}\nIf the change is intended, copy results/pendulum3r/{produced} to "
            f"docs/{shown} after running the README's first command."
        )


def test_readme_python_blocks_run_in_order(tmp_path, monkeypatch):
    """Every ```python block, top to bottom, in one namespace, from an empty folder."""
    blocks = re.findall(r"```python\n(.+?)\n```", README, flags=re.DOTALL)
    assert len(blocks) >= 2
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {"__name__": "readme"}
    for number, block in enumerate(blocks, 1):
        exec(compile(block, f"README.md python block {number}", "exec"), namespace)
    assert (tmp_path / "results" / "pendulum3r" / "summary.json").is_file()
    assert (tmp_path / "pendulum3r.png").is_file()
