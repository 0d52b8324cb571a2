"""Running a study: its cases on all cores or on a Dask cluster, stored as they finish.

Every case is a simulation of the case's scenario and its stopping report, by the batched
engine (:mod:`vtm_pin.batch`: a worker advances a batch of cases together; cases it cannot
take run on the scalar engine) or the scalar one. A case that fails is recorded with its
one-line message and the study goes on. Each finished case is written at
once, atomically, to ``DIR/cases/<id>.json``; ``DIR/study.json`` holds the study's
fingerprint. Run again after an interruption (Ctrl-C, or the process killed outright), the
same command computes only the cases missing there; a changed study is refused rather than
mixed with old results. The results table, its summary and the report are written once, by
the driver process only, when every case is done (:func:`run_study`).

Executors: one worker runs the cases in the driver process; more use a process pool, and a
scheduler address sends them to a Dask cluster (:mod:`vtm_pin.executors`). A worker loads each
robot model once (a :class:`~vtm_pin.robot.RobotCache`), not once per case.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import platform
import re
import statistics
import sys
import tempfile
import time
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .batch import ENGINES, PARTS
from .exceptions import OutputError, StudyError, VtmError, VtmWarning
from .executors import connect, dask_workers, on_dask, on_pool
from .figures import DEFINITIONS as FIGURE_DEFINITIONS
from .figures import METRICS
from .flags import KINDS as FLAG_KINDS
from .robot import RobotCache
from .staging import write_staged
from .study import Case, Study

if TYPE_CHECKING:
    import pandas as pd


#: Files of a study's output folder.
CASES_FOLDER, STATE_FILE = "cases", "study.json"
#: Most flagged cases whose messages summary.json lists (the table flags every case).
MAX_FLAGGED_SUMMARY = 100
#: What each column of the results table means besides the figures of
#: :data:`vtm_pin.figures.DEFINITIONS` (summary.json and report.html quote these).
DEFINITIONS = {
    "case": "Stable id of the case: a hash of its axis values (and of its index in sampled "
    "studies).",
    "status": "ok: every joint came to rest; not_stopped: some joint was still moving at the "
    "end of the run (lengthen duration); error: <message>: the case failed.",
    "holds": "true: every brake's static torque holds its joint's gravity load throughout the "
    "stop, and its sliding torque stops it; false: some brake cannot (see flags).",
    "flags": f"Broken assumptions behind the case's figures ({', '.join(FLAG_KINDS)}), ; "
    "separated; each case record (cases/<case>.json) has the messages.",
    **FIGURE_DEFINITIONS,
    "stop_time.<joint>": "That joint's stopping time [s].",
    "stop_angle.<joint>": "That joint's travel after the signal, |q(end) - q(signal)| [rad].",
    "wall_time": "Time this case took to build, simulate and report [s].",
}


@dataclass(frozen=True)
class CaseTask:
    """What a worker needs to run one case (picklable: sent to processes and clusters).

    Attributes:
        base: The base scenario, parsed.
        base_dir: Folder the base scenario's relative paths are resolved against.
        source: The base scenario file, for messages.
        name: The base scenario's name.
        case: The case.
    """

    base: Mapping[str, Any]
    base_dir: str
    source: str
    name: str
    case: Case


@dataclass(frozen=True)
class StudyOutput:
    """What :func:`run_study` produced.

    Attributes:
        study: The study.
        table: The results table, one row per case in study order.
        summary: The JSON-ready summary written to ``summary.json``.
        files: Names of the files written into the output folder, sorted.
        computed: Cases computed by this call (the others were stored by an earlier one).
        phases: Wall time of this call's phases [s]: ``cases`` (running and storing them),
            ``outputs`` (table, summary, graphs and report).
    """

    study: Study
    table: pd.DataFrame
    summary: Mapping[str, Any]
    files: tuple[str, ...]
    computed: int
    phases: Mapping[str, float] = field(default_factory=dict)


#: This process's robots: a worker loads each robot model once, not once per case.
_ROBOTS = RobotCache()


def run_cases(tasks: Sequence[CaseTask], engine: str = "batched") -> list[dict[str, Any]]:
    """Run cases; returns their records (JSON-ready), in order. Never raises for a case.

    A record holds the case id, index and values, ``status``, the metrics of
    :data:`METRICS` and per joint (None where undefined), the scenario's assumptions, the
    engine that ran it (and why not the batched one, if it was asked for), and the timing
    split: ``build`` (scenario and model), ``simulate`` (with the batched engine, the case's
    share of its batch), ``report`` [s].

    Args:
        tasks: The cases.
        engine: ``batched`` (cases of one robot advance together, see
            :mod:`vtm_pin.batch`) or ``scalar``.
    """
    from .batch import run_many
    from .figures import bound_variants
    from .scenario import build_scenario
    from .study import resolve_case

    records: list[dict[str, Any]] = []
    built: list[tuple[dict[str, Any], Any, list[Any]]] = []  # record, scenario, bound variants
    for task in tasks:
        case = task.case
        record: dict[str, Any] = {"case": case.id, "index": case.index, "values": dict(case.values)}
        records.append(record)
        start = time.perf_counter()
        try:
            raw = resolve_case(task.base, case.values)
            source = f"{task.source} (case {case.id})"
            scenario = build_scenario(
                raw,
                source=source,
                base_dir=Path(task.base_dir),
                name=task.name,
                loader=_ROBOTS,
                valid=_valid_base(task.base),
            )
            extra = bound_variants(scenario, _ROBOTS) if scenario.bounds is not None else []
            built.append((record, scenario, extra))
        except Exception as exc:
            _record_error(record, exc)
        record["timing"] = {"build": time.perf_counter() - start}
    groups: dict[str, list[tuple[dict[str, Any], Any, list[Any]]]] = {}
    for item in built:
        groups.setdefault(item[1].transition, []).append(item)
    for transition, items in groups.items():
        # Every case's scenario and its bounds' variants run in one batch.
        runs = [(k, s) for k, (_, scenario, extra) in enumerate(items) for s in (scenario, *extra)]
        try:
            outcome = run_many(
                [s.problem for _, s in runs],
                [s.integrator for _, s in runs],
                transition=transition,
                engine=engine,
            )
        except Exception as exc:
            for record, _, _ in items:
                _record_error(record, exc)
                record["timing"]["report"] = 0.0
            continue
        done: dict[int, list[tuple[Any, Any, str, str | None, Any]]] = {}
        for (k, s), *rest in zip(
            runs, outcome.results, outcome.engines, outcome.fallbacks, outcome.shares, strict=True
        ):
            done.setdefault(k, []).append((s, *rest))
        for k, (record, scenario, _) in enumerate(items):
            (_, result, used, reason, share), *variants = done[k]
            record["engine"] = used
            record["fallback"] = reason if engine == "batched" else None
            if share is not None:
                record["engine_split"] = share
            _record_result(record, scenario, result, [(v[0], v[1]) for v in variants])
    for record in records:
        timing = record["timing"]
        record["wall_time"] = sum(timing.values())
    return records


#: This process's study bases that pass the scenario schema (by their repr), and those that do
#: not: a base is checked once, not once per case (a scalar study sends one case at a time).
_BASES: dict[str, bool] = {}


def _valid_base(base: Mapping[str, Any]) -> Mapping[str, Any] | None:
    """``base`` if it passes the scenario schema (its cases are then checked against it)."""
    from .scenario import passes_schema

    key = repr(base)  # exact for parsed YAML: equal reprs, equal documents
    ok = _BASES.get(key)
    if ok is None:
        ok = passes_schema(base)
        if len(_BASES) >= 16:
            _BASES.clear()
        _BASES[key] = ok
    return base if ok else None


def _record_result(
    record: dict[str, Any], scenario: Any, result: Any, variants: Sequence[tuple[Any, Any]] = ()
) -> None:
    """Fill a case's record from its simulation (or the error that ended it).

    ``variants``: the runs its bounds need (scenario, result or error), if it asks for bounds.
    """
    from .figures import bounded, describe_flags, stop_figures
    from .scenario import scenario_failure
    from .stopping import compute_stopping_report

    begin = time.perf_counter()
    try:
        if isinstance(result, Exception):
            raise scenario_failure(scenario, result)
        if scenario.stop is None:
            raise StudyError(scenario.source, "stop", "a study case needs a stop to measure")
        report = compute_stopping_report(
            scenario.robot, result, scenario.brakes, scenario.tool_frame
        )
        figures = stop_figures(scenario, result, report)
        if variants:
            failed = next((r for _, r in variants if isinstance(r, Exception)), None)
            if failed is not None:
                raise scenario_failure(scenario, failed)
            figures = bounded(scenario, figures, variants)
            record["bounds"] = dict(figures.bounds)
        record.update(
            status=figures.status,
            metrics={**figures.metrics, **figures.upper},
            holds=figures.holds,
            flags=describe_flags(figures.flags),
            chain={k: v for k, v in figures.chain.items() if k in ("safeguard", "definition")},
        )
        record["assumptions"] = list(scenario.robot.assumptions) + list(scenario.assumptions)
        record["tool_frame"] = scenario.tool_frame
        record["timing"]["simulate"] = float(result.wall_time)
        record["rhs_evals"] = int(result.rhs_evals)
    except Exception as exc:
        _record_error(record, exc)
    record["timing"]["report"] = time.perf_counter() - begin


def _record_error(record: dict[str, Any], exc: Exception) -> None:
    """A failed case: its one-line message (an internal error says so)."""
    if isinstance(exc, VtmError):
        message = str(exc)
    else:  # a bug: recorded like a failure, so the study goes on
        message = f"internal error ({type(exc).__name__}: {exc})"
    record.update(status=f"error: {_one_line(message)}", metrics={})


def _one_line(text: str) -> str:
    return " ".join(text.split())


@dataclass
class CaseStore:
    """The records of a study's finished cases in ``DIR/cases``, one JSON file per case.

    Attributes:
        folder: The study's output folder.
        study: The study.
        records: Case id -> record, of the cases stored so far.
    """

    folder: Path
    study: Study
    records: dict[str, dict[str, Any]] = field(default_factory=dict)

    @property
    def cases_folder(self) -> Path:
        """Where the case records are."""
        return self.folder / CASES_FOLDER

    def open(self, wanted: set[str]) -> None:
        """Create the folder, or reopen it: refuse another study's results, load the records.

        Args:
            wanted: Ids of the study's cases; only their records are loaded.

        Raises:
            StudyError: The folder holds the results of another study, or of this study
                before its file or its base scenario changed.
            OutputError: The folder cannot be created or written.
        """
        state_path = self.folder / STATE_FILE
        try:
            if state_path.is_file():
                state = json.loads(state_path.read_text())
                if state.get("fingerprint") != self.study.fingerprint:
                    raise StudyError(
                        self.study.source,
                        "",
                        f"'{self.folder}' holds results of a different study (this study file "
                        "or its base scenario changed since they were computed); to start "
                        "over, delete that folder or choose another --out",
                    )
            self.cases_folder.mkdir(parents=True, exist_ok=True)
            if not state_path.is_file():
                state = {"study": self.study.source, "fingerprint": self.study.fingerprint}
                _write_atomic(state_path, json.dumps(state, indent=2) + "\n")
            for path in self.cases_folder.glob("*.json"):
                if path.stem in wanted:
                    self.records[path.stem] = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            raise OutputError(str(self.folder), f"cannot use '{self.folder}' ({reason})") from exc

    def save(self, record: dict[str, Any]) -> None:
        """Store one finished case, atomically (a killed process leaves no partial file)."""
        text = json.dumps(record, indent=1, allow_nan=False) + "\n"
        try:
            _write_atomic(self.cases_folder / f"{record['case']}.json", text)
        except OSError as exc:
            raise OutputError(str(self.folder), f"cannot write a case ({exc.strerror})") from exc
        self.records[record["case"]] = record


def _write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file in the same folder and a rename.

    A killed process leaves the old file or the new one, never a part. There is no fsync:
    the page cache outlives the process, and a case lost to a power cut is run again.
    """
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes it private; follow the umask instead
        with os.fdopen(fd, "w") as file:
            file.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _umask()


def default_workers() -> int:
    """The number of cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def run_study(
    study: Study,
    out: str | Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    engine: str = "batched",
) -> StudyOutput:
    """Run the cases of ``study`` not yet stored in ``out``, then write its results there.

    Args:
        study: The study.
        out: Output folder; created if missing, reused (resumed) if it holds this study.
        workers: Processes on this machine; all cores by default. Ignored with a scheduler.
        scheduler: Address of a Dask scheduler (``tcp://host:port``) to send the cases to.
        progress: Called with (cases done, cases in all) after each case, and once at the
            start with the cases already stored.
        engine: ``batched``: each worker advances its cases together, up to
            :data:`BATCH_CASES` at a time (:mod:`vtm_pin.batch`; cases it cannot take run
            on the scalar engine, counted in the summary); ``scalar``: one case at a time.

    Returns:
        The table, summary and files written.

    Raises:
        StudyError: ``out`` holds another study's results, the scheduler cannot be used,
            or the engine is unknown.
        OutputError: ``out`` cannot be written.
        KeyboardInterrupt: Interrupted; the cases finished so far are stored.
    """
    out = Path(out)
    if engine not in ENGINES:
        raise StudyError(
            "command line",
            "--engine",
            f"'{engine}' is not an engine; allowed: {', '.join(ENGINES)}",
        )
    client = connect(scheduler) if scheduler is not None else None  # before anything is written
    cases = study.cases()
    store = CaseStore(out, study)
    store.open({case.id for case in cases})
    todo = [case for case in cases if case.id not in store.records]
    if progress is not None:
        progress(len(cases) - len(todo), len(cases))
    base_dir = str(study.scenario.parent)
    tasks = [
        CaseTask(study.base, base_dir, str(study.scenario), study.scenario.stem, case)
        for case in todo
    ]
    begin_cases = time.perf_counter()
    for record in _execute(tasks, workers or default_workers(), client, engine):
        begin = time.perf_counter()
        store.save(record)
        record.setdefault("timing", {})["write"] = time.perf_counter() - begin  # this run's
        if progress is not None:
            progress(len(store.records), len(cases))
    records = [store.records[case.id] for case in cases]
    _refuse_all_failed(study, records)
    count = workers or default_workers()
    executor = f"dask {scheduler}" if scheduler else f"{count} worker{'s' if count > 1 else ''}"
    begin_outputs = time.perf_counter()
    output = _finish(study, out, records, f"{executor}, {engine} engine", len(tasks))
    phases = {"cases": begin_outputs - begin_cases, "outputs": time.perf_counter() - begin_outputs}
    _warn_flagged(records, out)
    return dataclasses.replace(output, phases=phases)


def _warn_flagged(records: Sequence[Mapping[str, Any]], out: Path) -> None:
    """One warning line if some cases' figures rest on broken assumptions (flags)."""
    kinds: dict[str, int] = {}
    flagged = 0
    for record in records:
        if record.get("flags"):
            flagged += 1
            for flag in record["flags"]:
                kinds[flag["kind"]] = kinds.get(flag["kind"], 0) + 1
    if flagged:
        counts = ", ".join(f"{n} {kind}" for kind, n in kinds.items())
        warnings.warn(
            f"{flagged} of {len(records)} cases are flagged ({counts}): their figures rest on "
            f"broken assumptions; see {out / 'report.html'}, section Flagged cases",
            VtmWarning,
            stacklevel=3,
        )


def _refuse_all_failed(study: Study, records: Sequence[Mapping[str, Any]]) -> None:
    """A study none of whose cases ran is a broken study, not a result: say why, in one line."""
    statuses = [str(r["status"]) for r in records]
    if statuses and all(s.startswith("error") for s in statuses):
        raise StudyError(
            study.source,
            "",
            f"all {len(statuses)} cases failed (nothing written but the case records); the "
            f"first: {statuses[0].removeprefix('error: ')}",
        )


#: Most cases a worker advances together with the batched engine (a batch's traces are held
#: in memory until it ends).
BATCH_CASES = 2500


def _chunks(tasks: Sequence[CaseTask], workers: int, engine: str) -> list[list[CaseTask]]:
    """The tasks in the pieces a worker runs at once: single cases, or batches.

    Batches are a quarter of a worker's share (at most :data:`BATCH_CASES`): the workers stay
    evenly loaded, and an interruption loses at most the batches under way.
    """
    size = 1 if engine == "scalar" else min(BATCH_CASES, math.ceil(len(tasks) / (4 * workers)))
    size = max(size, 1)
    return [list(tasks[i : i + size]) for i in range(0, len(tasks), size)]


def _execute(
    tasks: Sequence[CaseTask], workers: int, client: Any | None, engine: str
) -> Iterator[dict]:
    """Run the tasks; yields each record as soon as its piece is done (in any order)."""
    work = functools.partial(run_cases, engine=engine)
    if client is not None:
        chunks = _chunks(tasks, 4 * dask_workers(client), engine) if tasks else []
        return on_dask(chunks, work, client)
    chunks = _chunks(tasks, workers, engine)
    if workers <= 1 or len(chunks) <= 1:
        return (record for chunk in chunks for record in work(chunk))
    return on_pool(chunks, work, min(workers, len(chunks)))


def _finish(
    study: Study, out: Path, records: list[dict[str, Any]], executor: str, computed: int
) -> StudyOutput:
    """Build the table and summary, and write them with the report into ``out``."""
    from .study_report import write_study_report

    table = results_table(study, records)
    summary = build_study_summary(study, records, executor)

    def write(staging: Path) -> None:
        table.to_parquet(staging / "results.parquet", index=False)
        table.to_csv(staging / "results.csv", index=False)
        (staging / "summary.json").write_text(json.dumps(summary, indent=2, allow_nan=False) + "\n")
        write_study_report(staging, summary, table)

    files = write_staged(out, write)
    return StudyOutput(study, table, summary, tuple(files), computed)


def results_table(study: Study, records: Sequence[Mapping[str, Any]]) -> pd.DataFrame:
    """The results table: one row per case, in study order (columns: :data:`DEFINITIONS`)."""
    import pandas as pd

    joints: dict[str, None] = {}
    for record in records:
        joints.update(
            dict.fromkeys(
                k.split(".", 1)[1]
                for k in record["metrics"]
                if "." in k and not k.endswith("_upper")
            )
        )
    uppers = {k for r in records for k in r["metrics"] if k.endswith("_upper")}
    columns = [c for m in METRICS for c in (m, f"{m}_upper") if c == m or c in uppers]
    columns += [f"stop_time.{j}" for j in joints] + [f"stop_angle.{j}" for j in joints]
    rows = []
    for record in records:
        values = {k: ("none" if v is None else v) for k, v in record["values"].items()}
        metrics = record["metrics"]
        ran = "holds" in record
        rows.append(
            {
                "case": record["case"],
                **values,
                "status": record["status"],
                "holds": bool(record["holds"]) if ran else None,
                "flags": ";".join(f["kind"] for f in record.get("flags", [])),
                **{c: _float(metrics.get(c)) for c in columns},
                "wall_time": record["wall_time"],
            }
        )
    head = ["case", *study.axes, "status", "holds", "flags"]
    table = pd.DataFrame(rows, columns=[*head, *columns, "wall_time"])
    for name in study.axes:  # one type per column, as parquet needs
        kinds = {type(v) for v in table[name]}
        if len(kinds) > 1 and not kinds <= {int, float}:
            table[name] = table[name].astype(str)
    return table


def _float(value: Any) -> float:
    return float("nan") if value is None else float(value)


def build_study_summary(
    study: Study, records: Sequence[Mapping[str, Any]], executor: str
) -> dict[str, Any]:
    """The JSON-ready ``summary.json`` of a study (keys documented in the README)."""
    statuses = [str(r["status"]) for r in records]
    counts = {
        "cases": len(records),
        "ok": statuses.count("ok"),
        "not_stopped": statuses.count("not_stopped"),
        "error": sum(s.startswith("error") for s in statuses),
        "cannot_hold": sum(r.get("holds") is False for r in records),
        "flagged": sum(bool(r.get("flags")) for r in records),
    }
    timing = [r["timing"] for r in records if "timing" in r]
    split = {
        part: statistics.median(t[part] for t in timing if part in t)
        if any(part in t for t in timing)
        else None
        for part in ("build", "simulate", "report", "write")
    }
    flagged = [r for r in records if r.get("flags")]
    chains = [r["chain"] for r in records if r.get("chain")]
    return {
        "study": {
            "name": study.name,
            "file": study.source,
            "description": study.description,
            "scenario": str(study.scenario),
            "robot": str(study.base.get("robot", "")),
            "tool_frame": next((str(r["tool_frame"]) for r in records if "tool_frame" in r), ""),
            "mode": study.mode,
            "samples": study.samples,
            "seed": study.seed if study.samples is not None else None,
            "axes": study.describe_axes(),
            "fingerprint": study.fingerprint,
        },
        "counts": counts,
        "executor": executor,
        "engines": _engine_counts(records),
        "versions": _versions(),
        "assumptions": _common_assumptions(records),
        "axes": {name: _axis_text(name) for name in study.axes},
        "definitions": DEFINITIONS,
        "units": {**METRICS, "wall_time": "s"},
        "timing_median": split,
        "wall_time_total": sum(float(r["wall_time"]) for r in records),
        "stopping_chain": chains[0] if chains else {},
        "bounds": next((r["bounds"] for r in records if r.get("bounds")), {}),
        "flagged": [
            {"case": r["case"], "flags": r["flags"]} for r in flagged[:MAX_FLAGGED_SUMMARY]
        ],
    }


def _engine_counts(records: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """How many cases each engine ran, and why the batched engine left cases to the scalar."""
    engines = [str(r.get("engine", "")) for r in records if r.get("engine")]
    reasons: dict[str, int] = {}
    for record in records:
        if record.get("fallback"):
            reasons[str(record["fallback"])] = reasons.get(str(record["fallback"]), 0) + 1
    split = [r["engine_split"] for r in records if "engine_split" in r]
    return {
        "batched": engines.count("batched"),
        "scalar": engines.count("scalar"),
        "fallbacks": dict(sorted(reasons.items())),
        "batched_split_total": {part: sum(s.get(part, 0.0) for s in split) for part in PARTS},
        "rhs_evals_total": sum(int(r.get("rhs_evals", 0)) for r in records),
    }


def _axis_text(name: str) -> str:
    from .study import NAMED_AXES

    if name in NAMED_AXES:
        return NAMED_AXES[name][1]
    return f"scenario key {name} (units as in the scenario key table)"


def _common_assumptions(records: Sequence[Mapping[str, Any]]) -> list[str]:
    """The assumptions stated by every finished case, then those that vary between cases.

    A statement whose numbers differ between cases (the payload's mass, the Annex-B speed and
    pose) is listed once, its numbers shown as "…", after "Per case:".
    """
    lists = [r["assumptions"] for r in records if "assumptions" in r]
    if not lists:
        return []
    common = [line for line in lists[0] if all(line in other for other in lists[1:])]
    varying = dict.fromkeys(line for other in lists for line in other if line not in common)
    groups: dict[str, list[str]] = {}
    for line in varying:
        groups.setdefault(_NUMBER.sub("…", line), []).append(line)
    templates = [_template(lines) for lines in groups.values()]
    shown = templates[:MAX_TEMPLATES]
    common += [f"Per case: {template}" for template in shown]
    if len(templates) > len(shown):
        common.append(
            f"{len(templates) - len(shown)} further per-case statements are in each case's "
            "record, cases/<case>.json."
        )
    return common


def _template(lines: Sequence[str]) -> str:
    """Statements that differ only in numbers, as one: the numbers that differ shown as "…"."""
    numbers = [_NUMBER.findall(line) for line in lines]
    parts = _NUMBER.split(lines[0])
    out = [parts[0]]
    for k, part in enumerate(parts[1:]):
        values = {found[k] for found in numbers}
        out += [numbers[0][k] if len(values) == 1 else "…", part]
    return "".join(out)


#: A number in a statement (for grouping the statements that differ only in their numbers).
_NUMBER = re.compile(r"(?<![\w.\-])[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?(?![\w\-])")
#: Most per-case statement templates listed in a study's summary.
MAX_TEMPLATES = 30


def _versions() -> dict[str, str]:
    names = (
        "vtm_pin",
        "pin",
        "example-robot-data",
        "numpy",
        "scipy",
        "pandas",
        "pyarrow",
        "distributed",
    )
    found = {"python": platform.python_version(), "platform": sys.platform}
    for name in names:
        try:
            found[name] = version(name)
        except PackageNotFoundError:
            continue
    return found


def format_study(output: StudyOutput, elapsed: float) -> str:
    """A few lines on a finished study: counts, failures and time (for the command line)."""
    counts = output.summary["counts"]
    stored = counts["cases"] - output.computed
    lines = [
        f"study {output.study.name}: {counts['cases']} cases: {counts['ok']} ok, "
        f"{counts['not_stopped']} not stopped, {counts['error']} failed "
        f"({output.computed} computed now, {stored} stored before; {output.summary['executor']}; "
        f"{elapsed:.1f} s)"
    ]
    engines = output.summary.get("engines", {})
    for reason, count in engines.get("fallbacks", {}).items():
        lines.append(f"  {count} case{'s' if count > 1 else ''} on the scalar engine: {reason}")
    failed = output.table[output.table["status"] != "ok"]
    for _, row in failed.head(5).iterrows():
        lines.append(f"  case {row['case']}: {row['status']}")
    if len(failed) > 5:
        lines.append(f"  ... and {len(failed) - 5} more in results.csv")
    return "\n".join(lines)
