"""The README and the documentation stay true.

The README's commands are the ones CI runs, its picture is what the first one draws, its links
reach the pages; the generated key reference matches the schema; every page's Python blocks run.
"""

import importlib.util
import re

import pytest
from conftest import ROOT

from vtm_pin.scene.scenario import SCHEMA

README = (ROOT / "README.md").read_text()
DOCS = ROOT / "docs"
PAGES = sorted(DOCS.glob("*.md"))


def _generator():
    """docs/gen_scenario_keys.py, the MkDocs hook that writes the key reference."""
    path = DOCS / "gen_scenario_keys.py"
    spec = importlib.util.spec_from_file_location("gen_scenario_keys", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


GENERATED = _generator().key_table(SCHEMA)


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


def reference_rows():
    """Key -> (type, unit, default, allowed) of the generated scenario-key table."""
    rows = {}
    for line in GENERATED.splitlines():
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


def test_key_reference_lists_every_schema_key():
    assert set(reference_rows()) == set(schema_keys(SCHEMA))


def test_the_key_reference_page_is_generated_by_the_build():
    """The page holds the marker the hook replaces, and mkdocs.yml runs that hook."""
    generator = _generator()
    page = (DOCS / "scenario-files.md").read_text()
    assert page.count(generator.MARKER) == 1
    assert "docs/gen_scenario_keys.py" in (ROOT / "mkdocs.yml").read_text()
    built = generator.on_page_markdown(page, page=None, config=None, files=None)
    assert generator.MARKER not in built and "| `brakes.<joint>.delay` |" in built


def test_readme_is_a_short_front_page_whose_links_reach_the_pages():
    assert len(README.splitlines()) < 200
    links = re.findall(r"\]\((docs/[^)#]+)(?:#[^)]*)?\)", README)
    assert {link for link in links if link.endswith(".md")} == {
        f"docs/{page.name}" for page in PAGES
    }
    for link in links:
        assert (ROOT / link).is_file(), link


@pytest.mark.parametrize("key", sorted(schema_keys(SCHEMA)))
def test_key_reference_row_agrees_with_schema(key):
    """Type, unit, default and allowed values of each documented key follow the schema."""
    kind, unit, default, allowed = reference_rows()[key]
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
        assert default == "required", f"{key}: required in the schema, not '{default}'"
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


#: RMS pixel difference (0-255) allowed between the pictures of the docs and a fresh run: 0 on
#: one machine; room for font anti-aliasing of another matplotlib build. Measured: halving
#: dt moves lines by sub-pixels (RMS 0.04); the naive run replaced by another rule gives 18.
PICTURE_RMS = 2.0


def test_pictures_are_what_the_first_command_draws(tmp_path):
    from matplotlib.testing.compare import compare_images

    from vtm_pin.cli import main

    command = re.findall(r"```bash\n(.+?)\n```", README)[0]
    assert "](docs/pendulum3r_poses.png)" in README
    arguments = command.split("vtm-pin ", 1)[1].split()
    out = tmp_path / "results"
    arguments[arguments.index("--out") + 1] = str(out)
    arguments[1] = str(ROOT / arguments[1])
    assert main([*arguments, "--quiet"]) == 0
    for produced, shown in [
        ("poses.png", "pendulum3r_poses.png"),
        ("momenta.png", "pendulum3r_momenta.png"),
    ]:
        assert f"]({shown})" in (DOCS / "getting-started.md").read_text()
        difference = compare_images(str(ROOT / "docs" / shown), str(out / produced), PICTURE_RMS)
        assert difference is None, (
            f"{difference}\nIf the change is intended, copy results/pendulum3r/{produced} to "
            f"docs/{shown} after running the README's first command."
        )


def python_blocks(path):
    return re.findall(r"```python\n(.+?)\n```", path.read_text(), flags=re.DOTALL)


#: Files written by a page's blocks, checked once they have run.
WRITTEN = {"python.md": ["results/pendulum3r/summary.json", "pendulum3r.png"]}


def test_the_pages_with_python_blocks_are_the_expected_ones():
    with_blocks = {path.name for path in [ROOT / "README.md", *PAGES] if python_blocks(path)}
    assert {"python.md", "tutorial.md"} <= with_blocks


@pytest.mark.parametrize(
    "path",
    [path for path in [ROOT / "README.md", *PAGES] if python_blocks(path)],
    ids=lambda path: path.name,
)
def test_python_blocks_run_in_order(path, tmp_path, monkeypatch):
    """Every ```python block of a page, top to bottom, in one namespace, from an empty folder."""
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {"__name__": "docs"}
    for number, block in enumerate(python_blocks(path), 1):
        exec(compile(block, f"{path.name} python block {number}", "exec"), namespace)
    for written in WRITTEN.get(path.name, []):
        assert (tmp_path / written).is_file(), written
