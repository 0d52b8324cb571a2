"""Running a study: its cases on all cores or on a Dask cluster, stored as they finish.

Every case is a simulation of the case's scenario and its stopping report, by the batched
engine (:mod:`vtm_pin.core.batch`: a worker advances a batch of cases together; cases it cannot
take run on the scalar engine) or the scalar one. A case that fails is recorded with its
one-line message and the study goes on. Each finished case is written at once, atomically,
with the cases finished together, into ``DIR/cases`` (:mod:`vtm_pin.study.store`);
``DIR/study.json`` holds the study's fingerprint. Run again after an interruption (Ctrl-C, or
the process killed outright), the same command computes only the cases missing there; a
changed study is refused rather than mixed with old results. The results table, its summary
and the report are written once, by the driver process only, when every case is done
(:func:`run_study`).

Executors: one worker runs the cases in the driver process; more use a process pool, and a
scheduler address sends them to a Dask cluster (:mod:`vtm_pin.study.executors`). A worker loads each
robot model once (a :class:`~vtm_pin.physics.robot.RobotCache`), not once per case.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import math
import platform
import re
import statistics
import sys
import time
import warnings
from collections import Counter
from collections.abc import Callable, Generator, Mapping, Sequence
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.batch import ENGINES, PARTS
from ..exceptions import OutputError, StudyError, VtmError, VtmWarning
from ..files.staging import output_lock, write_staged
from ..outputs.figures import DEFINITIONS as FIGURE_DEFINITIONS
from ..outputs.figures import METRICS
from ..outputs.flags import KINDS as FLAG_KINDS
from ..physics.robot import RobotCache, example_models, keep_example_models
from .cases import Case, Study
from .executors import (
    close,
    connect,
    dask_workers,
    default_workers,
    in_background,
    on_dask,
    on_pool,
    start_fork_server,
)
from .store import CaseStore, seal, write_lines

if TYPE_CHECKING:
    import pandas as pd


#: Most flagged cases whose messages summary.json lists (the table flags every case).
MAX_FLAGGED_SUMMARY = 100
#: What each column of the results table means besides the figures of
#: :data:`vtm_pin.outputs.figures.DEFINITIONS` (summary.json and report.html quote these).
DEFINITIONS = {
    "case": "Stable id of the case: a hash of its axis values (and of its index in sampled "
    "studies).",
    "status": "ok: every joint came to rest; not_stopped: some joint was still moving at the "
    "end of the run (lengthen duration); error: <message>: the case failed.",
    "holds": "true: every brake's static torque holds its joint's gravity load throughout the "
    "stop, and its sliding torque stops it; false: some brake cannot (see flags).",
    "flags": f"Broken assumptions behind the case's figures ({', '.join(FLAG_KINDS)}), ; "
    "separated; each case's record (in cases/*.jsonl) has the messages.",
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
        study: The study's fingerprint, carried by the case's record.
    """

    base: Mapping[str, Any]
    base_dir: str
    source: str
    name: str
    case: Case
    study: str = ""


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


def run_cases(
    tasks: Sequence[CaseTask], engine: str = "batched", store: str | None = None
) -> list[dict[str, Any]]:
    """Run cases; returns their records (JSON-ready), in order. Never raises for a case.

    A record holds the case id, index and values, ``status``, the metrics of
    :data:`METRICS` and per joint (None where undefined), the scenario's assumptions, the
    engine that ran it (and why not the batched one, if it was asked for), and the timing
    split: ``build`` (scenario and model), ``simulate`` (with the batched engine, the case's
    share of its batch: the batch's time since its previous case ended, the reports of the
    cases that ended meanwhile left out), ``report`` [s].

    Args:
        tasks: The cases.
        engine: ``batched`` (cases of one robot advance together, see
            :mod:`vtm_pin.core.batch`) or ``scalar``.
        store: A study's output folder: each record is written into its ``cases`` folder as
            soon as its case's report is made, with up to :data:`REPORT_CASES` others (the
            cases done are kept if it is interrupted).
            A batched case's ``simulate`` time is then the batch's time since its previous
            case ended: these add up to the batch's time.

    Raises:
        OutputError: A record cannot be written into ``store``.
    """
    from ..outputs.figures import bound_variants
    from ..scene.scenario import build_scenario
    from . import cases

    keep = functools.partial(_keep, None if store is None else Path(store))
    records: list[dict[str, Any]] = []
    built: list[tuple[dict[str, Any], Any, list[Any]]] = []  # record, scenario, bound variants
    raws = [_case_raw(task) for task in tasks]
    poses = _Poses()
    for i, task in enumerate(tasks):
        case = task.case
        record: dict[str, Any] = {
            "case": case.id,
            "study": task.study,
            "index": case.index,
            "values": dict(case.values),
        }
        records.append(record)
        start, spent = time.perf_counter(), 0.0
        try:
            raw = raws[i]
            if isinstance(raw, Exception):
                raise raw
            source = f"{task.source} (case {case.id})"
            scenario = build_scenario(
                raw,
                source=source,
                base_dir=Path(task.base_dir),
                name=task.name,
                loader=_ROBOTS,
                valid=_valid_base(task.base) if cases.FAST_CASES else None,
            )
            spent = poses.solve(i, scenario, raw, tasks, raws)
            extra = bound_variants(scenario, _ROBOTS) if scenario.bounds is not None else []
            built.append((record, scenario, extra))
        except Exception as exc:
            _record_error(record, exc)
        record["timing"] = {"build": time.perf_counter() - start - spent + poses.share(i)}
    failed = [r for r in records if str(r.get("status", "")).startswith("error")]
    for record in failed:  # it could not be built
        record["wall_time"] = sum(record["timing"].values())
    keep(failed)
    groups: dict[str, list[tuple[dict[str, Any], Any, list[Any]]]] = {}
    for item in built:
        groups.setdefault(item[1].transition, []).append(item)
    for transition, items in groups.items():
        _run_group(transition, items, engine, keep)
    return records


def _case_raw(task: CaseTask) -> Mapping[str, Any] | Exception:
    """The case's scenario (parsed YAML), or the exception that resolving it raised."""
    from . import cases

    try:
        return cases.case_scenario(task.base, task.case)
    except Exception as exc:  # reported by the case's record, as a build error
        return exc


class _Poses:
    """The Annex-B poses of a run's cases, solved at once after its first Annex-B case's build.

    Case by case, each build solves its own pose (~1.2 ms a UR10 case, over half of its
    build). After the first case that computed one, the poses of the later cases of the same
    study are solved together (:func:`vtm_pin.scene.scenario.solve_variant_poses`, Newton over
    the lanes); their builds then find them in the pose cache. The time this takes is shared
    out among those cases' build times, not counted in the first case's.
    """

    def __init__(self) -> None:
        self.done = False
        self.cases: set[int] = set()
        self.seconds = 0.0

    def solve(
        self,
        first: int,
        scenario: Any,
        raw: Mapping[str, Any],
        tasks: Sequence[CaseTask],
        raws: Sequence[Mapping[str, Any] | Exception],
    ) -> float:
        """Solve once the poses of the cases after ``first``; returns the time it took [s].

        Only once a run, and only if case ``first``'s ``scenario`` is an Annex-B case.
        """
        from ..scene.scenario import solve_variant_poses

        if self.done or scenario.test_state is None:
            return 0.0
        self.done = True
        start = time.perf_counter()
        base = tasks[first].base
        variants = {
            j: r
            for j in range(first + 1, len(tasks))
            if tasks[j].base is base and not isinstance(r := raws[j], Exception)
        }
        self.cases = set(variants)
        solve_variant_poses(scenario, raw, variants.values())
        self.seconds = time.perf_counter() - start
        return self.seconds

    def share(self, case: int) -> float:
        """Case ``case``'s share of the time the poses took [s] (0 if not among them)."""
        return self.seconds / len(self.cases) if case in self.cases else 0.0


#: Finished cases whose reports are made together (:func:`_run_group`): their runs' tool
#: motions in one pass (:func:`vtm_pin.outputs.stopping.tool_motions`); at most this many
#: finished cases wait for their records.
REPORT_CASES = 32


def _run_group(
    transition: str,
    items: Sequence[tuple[dict[str, Any], Any, list[Any]]],
    engine: str,
    keep: Callable[[list[dict[str, Any]]], None],
) -> None:
    """Run cases of one transition rule, each with its bounds' variants, in one batch.

    A case's record is completed and kept once its runs have ended, with the next finished
    cases' up to :data:`REPORT_CASES` of them (or when the batch ends or is interrupted).
    """
    from ..core.batch import MIN_LANES, run_many

    runs = [(k, s) for k, (_, scenario, extra) in enumerate(items) for s in (scenario, *extra)]
    ended: list[list[Any]] = [[] for _ in items]  # per case: (run, scenario, result, reason, share)
    sizes = [1 + len(extra) for _, _, extra in items]
    waiting: list[int] = []  # finished cases, their records not yet made

    def flush() -> None:
        done = [(k, sorted(ended[k], key=lambda e: e[0])) for k in waiting]
        waiting.clear()
        _complete_many(items, done, engine, keep)

    def on_done(i: int, result: Any, reason: str | None, share: Any) -> None:
        k, scenario = runs[i]
        ended[k].append((i, scenario, result, reason, share))
        if len(ended[k]) == sizes[k]:
            waiting.append(k)
            if len(waiting) >= REPORT_CASES:
                flush()

    try:
        run_many(
            [s.problem for _, s in runs],
            [s.integrator for _, s in runs],
            transition=transition,
            engine=engine,
            on_done=on_done,
            min_lanes=MIN_LANES,
            holding=False,  # a record holds no holding torque: not computed at the samples
        )
    except OutputError:
        raise
    except Exception as exc:  # a bug: every case not yet done fails with it
        flush()
        failed = [record for k, (record, _, _) in enumerate(items) if len(ended[k]) < sizes[k]]
        for record in failed:
            _record_error(record, exc)
            record["timing"]["report"] = 0.0
            record["wall_time"] = sum(record["timing"].values())
        keep(failed)
        return
    except BaseException:  # interrupted: the finished cases are kept
        flush()
        raise
    flush()


def _complete_many(
    items: Sequence[tuple[dict[str, Any], Any, list[Any]]],
    done: Sequence[tuple[int, Sequence[tuple[Any, ...]]]],
    engine: str,
    keep: Callable[[list[dict[str, Any]]], None],
) -> None:
    """Fill and keep the records of finished cases ``(k, its ended runs)``.

    Their runs' tool motions are computed in one pass; its time is shared out equally over
    the cases' ``report`` times. Should that pass fail, each report computes its own (and
    records the error, if it is the case's).
    """
    from ..core.results import SimulationResult
    from ..outputs.stopping import tool_motions

    runs = [e for _, ended in done for e in ended if isinstance(e[2], SimulationResult)]
    begin = time.perf_counter()
    try:
        found = tool_motions([(e[1].robot, e[2], e[1].tool_frame) for e in runs])
        motions = {e[0]: m for e, m in zip(runs, found, strict=True)}
    except Exception:  # each report computes its own
        motions = {}
    share = (time.perf_counter() - begin) / max(1, len(done))
    for k, ended in done:
        _complete(items[k][0], items[k][1], ended, engine, motions, share)
    keep([items[k][0] for k, _ in done])


def _complete(
    record: dict[str, Any],
    scenario: Any,
    ended: Sequence[tuple[Any, ...]],
    engine: str,
    motions: Mapping[int, Any] | None = None,
    share: float = 0.0,
) -> None:
    """Fill a case's record from its runs (the case's own first, then its bounds' variants).

    ``motions``: tool motions by run (:func:`vtm_pin.outputs.stopping.tool_motions`), if
    computed with other cases'; ``share``: this case's part of their time [s].
    """
    motions = motions or {}
    (_, _, result, reason, share_of_batch), *variants = ended
    record["engine"] = "scalar" if reason is not None else "batched"
    record["fallback"] = reason if engine == "batched" else None
    if share_of_batch is not None:
        record["engine_split"] = share_of_batch
    _record_result(
        record,
        scenario,
        result,
        [(v[1], v[2]) for v in variants],
        [motions.get(e[0]) for e in ended],
    )
    record["timing"]["report"] += share
    record["wall_time"] = sum(record["timing"].values())


def _keep(store: Path | None, records: list[dict[str, Any]]) -> None:
    """Write finished cases' records into one file of the store's folder (if there is one).

    A record holding NaN or an infinity is stored as the case's failure instead. The write's
    time is shared out equally among the records (``timing.write``; not in the stored text).
    """
    if store is None or not records:
        return
    begin = time.perf_counter()
    write_lines(store, records[0]["case"], [_sealed(record) for record in records])
    share = (time.perf_counter() - begin) / len(records)
    for record in records:
        record["timing"]["write"] = share


def _sealed(record: dict[str, Any]) -> str:
    """The record's stored line (:func:`vtm_pin.study.store.seal`); a failure if it cannot."""
    try:
        return seal(record)
    except ValueError:  # a figure that is NaN or infinite: the case failed, it is not a result
        kept = {k: record[k] for k in ("case", "study", "index", "values", "timing", "wall_time")}
        record.clear()
        record.update(kept)
        _record_error(record, StudyError("", "", "a figure came out NaN or infinite; not a result"))
        return seal(record)


#: This process's study bases that pass the scenario schema (by their repr), and those that do
#: not: a base is checked once, not once per case (a scalar study sends one case at a time).
_BASES: dict[str, bool] = {}


def _valid_base(base: Mapping[str, Any]) -> Mapping[str, Any] | None:
    """``base`` if it passes the scenario schema (its cases are then checked against it)."""
    from ..scene.scenario import passes_schema

    known = _LAST_BASE.get("base")
    if known is not None and known[0] is base:  # the cases of a task list share their base
        return base if known[1] else None
    key = repr(base)  # exact for parsed YAML: equal reprs, equal documents
    ok = _BASES.get(key)
    if ok is None:
        ok = passes_schema(base)
        if len(_BASES) >= 16:
            _BASES.clear()
        _BASES[key] = ok
    _LAST_BASE["base"] = (base, ok)
    return base if ok else None


#: The last base :func:`_valid_base` checked (the object itself) and whether it passed.
_LAST_BASE: dict[str, tuple[Mapping[str, Any], bool]] = {}


def _record_result(
    record: dict[str, Any],
    scenario: Any,
    result: Any,
    variants: Sequence[tuple[Any, Any]] = (),
    motions: Sequence[Any] = (),
) -> None:
    """Fill a case's record from its simulation (or the error that ended it).

    ``variants``: the runs its bounds need (scenario, result or error), if it asks for bounds.
    ``motions``: the tool motions of the case's run and then its variants' (None: computed
    here), if they were computed with other cases' (:func:`_complete_many`).
    """
    from ..outputs.figures import bounded, describe_flags, stop_figures
    from ..outputs.stopping import compute_stopping_report
    from ..scene.scenario import scenario_failure

    begin = time.perf_counter()
    try:
        if isinstance(result, Exception):
            raise scenario_failure(scenario, result)
        if scenario.stop is None:
            raise StudyError(scenario.source, "stop", "a study case needs a stop to measure")
        motion, *more = motions or [None] * (1 + len(variants))
        report = compute_stopping_report(
            scenario.robot, result, scenario.brakes, scenario.tool_frame, motion
        )
        figures = stop_figures(scenario, result, report)
        if variants:
            failed = next((r for _, r in variants if isinstance(r, Exception)), None)
            if failed is not None:
                raise scenario_failure(scenario, failed)
            figures = bounded(scenario, figures, variants, more)
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


def run_study(
    study: Study,
    out: str | Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    engine: str = "batched",
    outputs: bool = True,
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
            :data:`BATCH_CASES` at a time (:mod:`vtm_pin.core.batch`; cases it cannot take run
            on the scalar engine, counted in the summary); ``scalar``: one case at a time.
        outputs: False: store the cases only (``out/cases``), and return the table and summary
            without writing them, the graphs or the report (a program's override search).

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
    if client is None and (workers or default_workers()) > 1:
        start_fork_server()  # its imports meanwhile: drawing the cases, opening the store
    try:
        with output_lock(out):
            return _run_held(study, out, workers, (client, scheduler), progress, engine, outputs)
    finally:
        if client is not None:
            close(client)


def _run_held(
    study: Study,
    out: Path,
    workers: int | None,
    cluster: tuple[Any | None, str | None],
    progress: Callable[[int, int], None] | None,
    engine: str,
    outputs: bool = True,
) -> StudyOutput:
    """:func:`run_study` once it holds ``out`` (``cluster``: the Dask client and its address)."""
    client, where = cluster
    cases = study.cases()
    store = CaseStore(out, study)
    store.open(cases)
    _warn_rejected(store)
    todo = [case for case in cases if case.id not in store.records]
    if progress is not None:
        progress(len(cases) - len(todo), len(cases))
    base_dir = str(study.scenario.parent)
    tasks = [
        CaseTask(
            study.base, base_dir, str(study.scenario), study.scenario.stem, case, study.fingerprint
        )
        for case in todo
    ]
    begin_cases = time.perf_counter()
    local = client is None  # local workers store each case themselves, as it finishes
    # closing: an interruption ends the workers at once, before the stored cases are counted
    with contextlib.closing(
        _execute(tasks, workers or default_workers(), client, engine, out)
    ) as run:
        for record in run:
            if not local:  # stored here, one record a file
                _keep(out, [record])
            store.records[record["case"]] = record
            if progress is not None:
                progress(len(store.records), len(cases))
    records = [store.records[case.id] for case in cases]
    try:
        _refuse_all_failed(study, records)
    except StudyError:
        store.discard()  # a study that cannot run leaves nothing
        raise
    count = workers or default_workers()
    executor = f"dask {where}" if client is not None else f"{count} worker{'s' * (count > 1)}"
    if not outputs:
        summary = build_study_summary(study, records, f"{executor}, {engine} engine")
        return StudyOutput(study, results_table(study, records), summary, (), len(tasks))
    begin_outputs = time.perf_counter()
    background = min(count, IMAGE_PROCESSES) if client is None and count > 1 else 0
    output = _finish(study, out, records, f"{executor}, {engine} engine", len(tasks), background)
    phases = {"cases": begin_outputs - begin_cases, "outputs": time.perf_counter() - begin_outputs}
    _warn_flagged(records, out)
    return dataclasses.replace(output, phases=phases)


def _warn_rejected(store: CaseStore) -> None:
    """One warning line if stored records were not kept (they are computed again)."""
    if store.rejected:
        name, reason = next(iter(store.rejected.items()))
        more = len(store.rejected) - 1
        warnings.warn(
            f"{len(store.rejected)} stored case record(s) in '{store.cases_folder}' not kept, "
            f"computed again ({name}: {reason}{f'; and {more} more' if more else ''})",
            VtmWarning,
            stacklevel=4,
        )


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
            f"all {len(statuses)} cases failed; the first: {statuses[0].removeprefix('error: ')}",
        )


#: Most processes that draw a study's graphs together (each a share, with the local workers'
#: cores free by then): a 10,000-case UR10 study has three.
IMAGE_PROCESSES = 3

#: Most cases a worker advances together with the batched engine (a batch's traces are held
#: in memory until it ends).
BATCH_CASES = 2500


#: Fewest cases in a batch of a study's last round (:func:`_chunks`): smaller batches share
#: less of their lanes' work (312-case batches cost ~20 % more a UR10 case than 1,250-case
#: ones; 625-case ones the same within the noise).
TAIL_CASES = 500


def _chunks(tasks: Sequence[CaseTask], workers: int, engine: str) -> list[list[CaseTask]]:
    """The tasks in the pieces a worker runs at once: single cases, or batches.

    Batches are a quarter of a worker's share (at most :data:`BATCH_CASES`): the workers stay
    evenly loaded, and an interruption loses at most the batches under way. The last round
    (one batch a worker, and what is left over) is cut in halves of at least
    :data:`TAIL_CASES` (the last one may be less): a worker that runs
    faster than the others (the machine's cores are not alike) takes more of the end instead
    of waiting for them (a 10,000-case study on 2 workers: one had waited ~0.9 s of ~12 s).
    """
    size = 1 if engine == "scalar" else min(BATCH_CASES, math.ceil(len(tasks) / (4 * workers)))
    size = max(size, 1)
    half = math.ceil(size / 2)
    tail = workers * size if half >= TAIL_CASES and workers > 1 else 0
    split = max(len(tasks) - tail, 0) // size * size  # whole batches before the last round
    head = [list(tasks[i : i + size]) for i in range(0, split, size)]
    step = half if tail else size
    return head + [list(tasks[i : i + step]) for i in range(split, len(tasks), step)]


def _execute(
    tasks: Sequence[CaseTask], workers: int, client: Any | None, engine: str, out: Path
) -> Generator[dict, None, None]:
    """Run the tasks; yields each record as soon as its piece is done (in any order).

    Local workers (this process, or a pool on this machine) store each record in ``out`` as
    its case finishes; a cluster's records are stored by the caller. Closing the generator
    ends the workers at once.
    """
    if client is not None:
        chunks = _chunks(tasks, 4 * dask_workers(client), engine) if tasks else []
        yield from on_dask(chunks, functools.partial(run_cases, engine=engine), client)
        return
    work = functools.partial(run_cases, engine=engine, store=str(out))
    chunks = _chunks(tasks, workers, engine)
    if workers <= 1 or len(chunks) <= 1:
        for chunk in chunks:
            yield from work(chunk)
        return
    # the workers get the driver's robot models (the study's, loaded to check its base)
    models = functools.partial(keep_example_models, example_models())
    yield from on_pool(chunks, work, min(workers, len(chunks)), setup=models)


def _finish(
    study: Study,
    out: Path,
    records: list[dict[str, Any]],
    executor: str,
    computed: int,
    background: int = 0,
) -> StudyOutput:
    """Build the table and summary, and write them with the report into ``out``.

    ``background``: the number of processes (0: none) that draw the graphs meanwhile, each
    a share of them: ~1-1.3 s for a 10,000-case study's three in one process, the longest
    part of its ~2 s of outputs.
    """
    table = results_table(study, records)
    with _images(table, str(study.base.get("robot", "")), background) as images:
        summary = build_study_summary(study, records, executor)

        def write(staging: Path) -> None:
            from .report import write_study_report

            table.to_parquet(staging / "results.parquet", index=False)
            table.to_csv(staging / "results.csv", index=False)
            text = json.dumps(summary, indent=2, allow_nan=False) + "\n"
            (staging / "summary.json").write_text(text)
            write_study_report(staging, summary, table, images())

        files = write_staged(out, write)
    return StudyOutput(study, table, summary, tuple(files), computed)


@contextlib.contextmanager
def _images(
    table: pd.DataFrame, robot: str, background: int
) -> Generator[Callable[[], Mapping[str, bytes] | None], None, None]:
    """The study's graphs (:func:`vtm_pin.study.report.stopping_images`), when asked for.

    In background, ``background`` processes of their own draw them meanwhile, a share each
    (all drawn here after all if one dies); else the report draws them (the function gives
    None).
    """
    if not background:
        yield lambda: None
        return
    from concurrent.futures.process import BrokenProcessPool

    from .report import merge_shares, stopping_images

    with contextlib.ExitStack() as stack:
        futures = [
            stack.enter_context(in_background(stopping_images, table, robot, (k, background)))
            for k in range(background)
        ]

        def images() -> Mapping[str, bytes]:
            try:
                return merge_shares([future.result() for future in futures])
            except BrokenProcessPool:  # a process died (out of memory, killed)
                return stopping_images(table, robot)

        yield images


def results_table(study: Study, records: Sequence[Mapping[str, Any]]) -> pd.DataFrame:
    """The results table: one row per case, in study order (columns: :data:`DEFINITIONS`).

    Built column by column (a study's 10,000 records in ~0.2 s; row dicts took ~0.8 s).
    """
    import pandas as pd

    joints: dict[str, None] = {}
    uppers: set[str] = set()
    for keys in dict.fromkeys(tuple(r["metrics"]) for r in records):  # the distinct key sets
        uppers.update(k for k in keys if k.endswith("_upper"))
        dotted = (k for k in keys if "." in k and not k.endswith("_upper"))
        joints.update(dict.fromkeys(k.split(".", 1)[1] for k in dotted))
    columns = [c for m in METRICS for c in (m, f"{m}_upper") if c == m or c in uppers]
    columns += [f"stop_time.{j}" for j in joints] + [f"stop_angle.{j}" for j in joints]
    values = [r["values"] for r in records]
    data: dict[str, Any] = {"case": [r["case"] for r in records]}
    for name in study.axes:
        data[name] = [_axis_value(v, name) for v in values]
    data["status"] = [r["status"] for r in records]
    data["holds"] = [bool(r["holds"]) if "holds" in r else None for r in records]
    data["flags"] = [";".join(f["kind"] for f in r.get("flags", [])) for r in records]
    figures = np.array(  # record by record (each record's dict read once); None is NaN
        [[m.get(c) for c in columns] for m in (r["metrics"] for r in records)], dtype=float
    ).reshape(len(records), len(columns))
    data.update(zip(columns, figures.T, strict=True))
    data["wall_time"] = [r["wall_time"] for r in records]
    table = pd.DataFrame(data, columns=list(data))
    for name in study.axes:  # one type per column, as parquet needs
        kinds = {type(v) for v in table[name]}
        if len(kinds) > 1 and not kinds <= {int, float}:
            table[name] = table[name].astype(str)
    return table


def _axis_value(values: Mapping[str, Any], name: str) -> Any:
    """A case's value of axis ``name`` in the table: None as "none", missing as NaN."""
    value = values.get(name, math.nan)
    return "none" if value is None else value


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
    split, mean = (
        {
            part: average(t[part] for t in timing if part in t)
            if any(part in t for t in timing)
            else None
            for part in ("build", "simulate", "report", "write")
        }
        for average in (statistics.median, statistics.fmean)
    )
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
        "timing_mean": mean,
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
    from .cases import NAMED_AXES

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
    stated = Counter(line for lines in lists for line in set(lines))  # cases stating each
    common = [line for line in lists[0] if stated[line] == len(lists)]
    known = set(common)
    varying = dict.fromkeys(line for lines in lists for line in lines if line not in known)
    groups: dict[str, list[list[str]]] = {}  # template -> each statement's split
    for line in varying:
        parts = _NUMBER_SPLIT.split(line)  # text, number, text, …, text
        groups.setdefault("…".join(parts[::2]), []).append(parts)
    templates = [_template(split) for split in groups.values()]
    shown = templates[:MAX_TEMPLATES]
    common += [f"Per case: {template}" for template in shown]
    if len(templates) > len(shown):
        common.append(
            f"{len(templates) - len(shown)} further per-case statements are in each case's "
            "record, in cases/*.jsonl."
        )
    return common


def _template(split: Sequence[Sequence[str]]) -> str:
    """Statements that differ only in numbers, as one: the numbers that differ shown as "…".

    Args:
        split: Each statement as :data:`_NUMBER_SPLIT` splits it (text and numbers in turn).
    """
    first = split[0]
    out = [first[0]]
    for k in range(1, len(first), 2):
        same = all(parts[k] == first[k] for parts in split)
        out += [first[k] if same else "…", first[k + 1]]
    return "".join(out)


#: A number in a statement (for grouping the statements that differ only in their numbers).
_NUMBER = re.compile(r"(?<![\w.\-])[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?(?![\w\-])")
#: The same, as a group: ``split`` returns the text and the numbers in turn.
_NUMBER_SPLIT = re.compile(f"({_NUMBER.pattern})")
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
