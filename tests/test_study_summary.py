"""A study's table and summary from its records, against their plain row-by-row definitions.

The table is built column by column and the common assumptions by counting, for speed on
10,000-case studies; these tests hold both to what they mean, on synthetic records (no
simulation): every case's row, NaN where a figure is undefined, and each statement either
common to all cases or listed once as a per-case template.
"""

from __future__ import annotations

import math
import re
from types import SimpleNamespace
from typing import Any

import numpy as np
import pandas as pd
from hypothesis import given, settings
from hypothesis import strategies as st

from vtm_pin.outputs.figures import METRICS
from vtm_pin.study.runner import MAX_TEMPLATES, _common_assumptions, results_table

_NUMBER = re.compile(r"(?<![\w.\-])[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?(?![\w\-])")


def reference_assumptions(lists: list[list[str]]) -> list[str]:
    """The definition: lines every list states, then each template of the others, once."""
    if not lists:
        return []
    common = [line for line in lists[0] if all(line in other for other in lists[1:])]
    varying = dict.fromkeys(line for other in lists for line in other if line not in common)
    groups: dict[str, list[str]] = {}
    for line in varying:
        groups.setdefault(_NUMBER.sub("…", line), []).append(line)
    templates = []
    for lines in groups.values():
        numbers = [_NUMBER.findall(line) for line in lines]
        parts = _NUMBER.split(lines[0])
        out = [parts[0]]
        for k, part in enumerate(parts[1:]):
            out += [numbers[0][k] if len({n[k] for n in numbers}) == 1 else "…", part]
        templates.append("".join(out))
    shown = templates[:MAX_TEMPLATES]
    common += [f"Per case: {t}" for t in shown]
    if len(templates) > len(shown):
        common.append(
            f"{len(templates) - len(shown)} further per-case statements are in each case's "
            "record, in cases/*.jsonl."
        )
    return common


_STATEMENTS = st.sampled_from(
    [
        "robot data ASSUMED",
        "payload {} kg at {} m",
        "Annex-B speed {} % of {} rad/s",
        "brake torque {} N m, delay {} s",
        "pose q = [{}, {}] rad",
        "no numbers here",
        "step 1e-{} s, tol {}",
    ]
)


@st.composite
def statement(draw: st.DrawFn) -> str:
    text = draw(_STATEMENTS)
    values = draw(st.lists(st.sampled_from(["0", "1.5", "-2", "10", "0.25", "3"]), min_size=2))
    return text.format(*values[: text.count("{}")])


@settings(max_examples=200, deadline=None)
@given(st.lists(st.lists(statement(), max_size=6), max_size=8))
def test_common_assumptions_are_the_lines_all_state_then_per_case_templates(
    lists: list[list[str]],
) -> None:
    records: list[dict[str, Any]] = [{"assumptions": lines} for lines in lists]
    records.insert(len(records) // 2, {"status": "error: not built"})  # states nothing
    assert _common_assumptions(records) == reference_assumptions(lists)


def test_more_templates_than_shown_are_counted() -> None:
    names = [chr(65 + k) for k in range(MAX_TEMPLATES + 3)]  # words, not numbers
    lists = [[f"statement {name} with {c} in it" for name in names] for c in (1, 2)]
    found = _common_assumptions([{"assumptions": lines} for lines in lists])
    assert found == reference_assumptions(lists)
    assert found[-1].startswith("3 further per-case statements")


def _record(case: int, rng: np.random.Generator) -> dict[str, Any]:
    metrics: dict[str, Any] = {m: float(rng.normal()) for m in METRICS if rng.random() < 0.8}
    for joint in ("a", "b"):
        if rng.random() < 0.7:
            metrics[f"stop_time.{joint}"] = float(rng.random())
            metrics[f"stop_angle.{joint}"] = None if rng.random() < 0.2 else float(rng.normal())
    first = next(iter(METRICS))
    if case % 3 == 0:
        metrics[f"{first}_upper"] = float(rng.random())
    record: dict[str, Any] = {
        "case": f"c{case}",
        "values": {"speed": [0.5, None, 1][case % 3], "payload": ["1", 2.0][case % 2]},
        "status": "ok",
        "metrics": metrics,
        "wall_time": float(case),
    }
    if case % 4 != 1:
        record["holds"] = bool(case % 2)
        record["flags"] = [{"kind": "joint_slips"}] * (case % 3)
    if case == 5:
        record.update(status="error: bad", metrics={})
        del record["values"]["payload"]
    return record


def test_the_table_is_each_record_row_by_row() -> None:
    rng = np.random.default_rng(3)
    records = [_record(case, rng) for case in range(40)]
    table = results_table(SimpleNamespace(axes=("speed", "payload")), records)  # type: ignore[arg-type]
    first = next(iter(METRICS))
    columns = [c for m in METRICS for c in (m, f"{m}_upper") if c == m or c == f"{first}_upper"]
    columns += ["stop_time.a", "stop_time.b", "stop_angle.a", "stop_angle.b"]
    assert list(table.columns) == [
        "case", "speed", "payload", "status", "holds", "flags", *columns, "wall_time"
    ]  # fmt: skip
    for record, (_, row) in zip(records, table.iterrows(), strict=True):
        assert row["case"] == record["case"] and row["status"] == record["status"]
        speed = record["values"]["speed"]
        assert row["speed"] == ("none" if speed is None else str(speed))  # mixed: text
        payload = record["values"].get("payload")
        assert pd.isna(row["payload"]) if payload is None else row["payload"] == str(payload)
        assert row["holds"] == record.get("holds")
        assert row["flags"] == ";".join(f["kind"] for f in record.get("flags", []))
        for c in columns:
            value = record["metrics"].get(c)
            assert math.isnan(row[c]) if value is None else row[c] == value, (record["case"], c)
        assert row["wall_time"] == record["wall_time"]
    assert all(table[c].dtype == np.float64 for c in columns)
    assert pd.api.types.is_object_dtype(table["holds"])
