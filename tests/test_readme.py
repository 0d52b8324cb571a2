"""The README stays true: its commands are the ones CI runs, its key table matches the schema."""

import re

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


def test_readme_key_table_matches_schema():
    section = README.split("## Scenario files", 1)[1].split("\n## ", 1)[0]
    documented = set(re.findall(r"^\| `([^`]+)` \|", section, flags=re.M))
    assert documented == set(schema_keys(SCHEMA))


def test_ci_runs_the_readme_test_command():
    commands = re.findall(r"```bash\n(.+?)\n```", README)
    assert len(commands) == 2
    assert commands[1] in (ROOT / ".ci" / "run").read_text()
    assert "vtm-pin run scenarios/pendulum3r.yaml" in commands[0]
