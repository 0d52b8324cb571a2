"""The README stays true: its commands are the ones CI runs, its key table matches the schema."""

import re

from conftest import ROOT

from vtm_pin.scenario import SCHEMA

README = (ROOT / "README.md").read_text()


def schema_keys(schema, prefix=""):
    for key, sub in schema.get("properties", {}).items():
        path = f"{prefix}{key}"
        yield path
        if sub.get("type") == "object" and "properties" in sub:
            yield from schema_keys(sub, f"{path}.")
        if sub.get("type") == "object" and isinstance(sub.get("additionalProperties"), dict):
            yield from schema_keys(sub["additionalProperties"], f"{path}.<joint>.")
        if sub.get("type") == "array" and isinstance(sub.get("items"), dict):
            yield from schema_keys(sub["items"], f"{path}[].")


def test_readme_key_table_matches_schema():
    documented = set(re.findall(r"^\| `([^`]+)` \|", README, flags=re.M))
    keys = set(schema_keys(SCHEMA))
    assert keys - documented == set(), "schema keys missing from the README"
    assert {k for k in documented if k[0].islower() and "." not in k} - keys <= {
        "kkt",
        "projected",
        "minimal",
        "naive",
        "planar_3r",
        "joints",
        "events[]",
        "final",
        "energy",
        "stats",
        "also",
    }


def test_ci_runs_the_readme_test_command():
    commands = re.findall(r"```bash\n(.+?)\n```", README)
    assert len(commands) == 2
    assert commands[1] in (ROOT / ".ci" / "run").read_text()
    assert "vtm-pin run scenarios/pendulum3r.yaml" in commands[0]
