"""A study's case store: ``DIR/study.json`` and the records of its finished cases.

The records are JSON Lines files in ``DIR/cases``: each file holds the cases a worker
finished together (up to :data:`vtm_pin.study.runner.REPORT_CASES`, one with the scalar
engine), one sealed record a line (:func:`seal`). A file is written once, through a temporary
file and a rename (:func:`~vtm_pin.files.staging.write_atomic`): a killed process leaves
whole files only. Its name is its first case's id and a random token
(``<id>-<token>.jsonl``), so no file ever replaces another. One file for many cases, not one
a case: creating a file costs ~0.1-0.5 ms on this project's machines, more than a case's
record takes to encode.

On resume (:meth:`CaseStore.open`) every line is checked (:func:`check_record`); a line that is
not a record of this study's case is not kept (its case is computed again), and its file is
rewritten without it, so that it is reported once.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import secrets
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..exceptions import OutputError, StudyError, excerpt
from ..files.inputs import read_text
from ..files.staging import write_atomic
from .cases import Case, Study

#: Files of a study's output folder.
CASES_FOLDER, STATE_FILE = "cases", "study.json"
#: The ending of a case-records file.
RECORDS_SUFFIX = ".jsonl"

#: Keys every stored case record has, and the JSON types of their values.
RECORD_KEYS: dict[str, type | tuple[type, ...]] = {
    "case": str,
    "study": str,
    "index": int,
    "values": dict,
    "status": str,
    "metrics": dict,
    "timing": dict,
    "wall_time": (int, float),
    "checksum": str,
}


def seal(record: dict[str, Any]) -> str:
    """The record as the line of JSON stored, with ``checksum``: a hash of everything else.

    The line is the record's other keys, in their order, as compact JSON, with the checksum
    last: one encoding gives both the text hashed and the text stored (a record read back
    has its keys in the same order, and encodes to the same text).

    Raises:
        ValueError: The record holds NaN or an infinity (a record must not).
    """
    text = _body_text(record)
    record["checksum"] = hashlib.sha256(text.encode()).hexdigest()
    return f'{text[:-1]}{"," if len(text) > 2 else ""}"checksum":"{record["checksum"]}"}}\n'


def _body_text(record: Mapping[str, Any]) -> str:
    """The compact JSON of the record without its checksum (what the checksum hashes)."""
    body = {k: v for k, v in record.items() if k != "checksum"}
    return json.dumps(body, separators=(",", ":"), allow_nan=False)


def check_record(record: Any, case: Case, study: str) -> str | None:
    """Why a stored record cannot be kept for ``case`` of the study ``study`` (None if it can).

    It must have the shape of :data:`RECORD_KEYS`, the case's id and axis values, the study's
    fingerprint, finite metrics, and a checksum that matches its content.
    """
    if not isinstance(record, dict):
        return "not a record (a mapping)"
    for key, kind in RECORD_KEYS.items():
        if not isinstance(record.get(key), kind) or isinstance(record.get(key), bool):
            return f"'{key}' is missing or of the wrong type"
    if record["case"] != case.id:
        return f"it holds case {excerpt(record['case'])}"
    if record["study"] != study:
        return "it was computed for another study (or before it changed)"
    try:
        if record["checksum"] != hashlib.sha256(_body_text(record).encode()).hexdigest():
            return "its checksum does not match its content (edited or damaged)"
    except ValueError:
        return "it holds NaN or an infinity"
    if _hash_values(record["values"]) != _hash_values(case.values):
        return "its axis values are not the case's"
    bad = [k for k, v in record["metrics"].items() if not _finite_or_none(v)]
    if bad:
        return f"metric {excerpt(bad[0])} is not a finite number"
    return None


def _hash_values(values: Mapping[str, Any]) -> str:
    return json.dumps(values, sort_keys=True, default=str)


def _finite_or_none(value: Any) -> bool:
    if value is None:
        return True
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def write_lines(folder: Path, first: str, lines: Sequence[str]) -> Path:
    """Store sealed records (:func:`seal`) as one new file of ``folder/cases``, atomically.

    Args:
        folder: The study's output folder.
        first: The first record's case id (the file's name begins with it).
        lines: The records' lines.

    Returns:
        The file written.

    Raises:
        OutputError: It cannot be written (naming the file and why).
    """
    path = folder / CASES_FOLDER / f"{first}-{secrets.token_hex(4)}{RECORDS_SUFFIX}"
    try:
        write_atomic(path, "".join(lines))
    except OSError as exc:
        raise OutputError(
            str(folder), f"cannot write the case records '{path}' ({exc.strerror or exc})"
        ) from exc
    return path


def record_files(cases_folder: Path) -> list[Path]:
    """The case-records files in ``cases_folder`` (none if it does not exist), by name."""
    return sorted(cases_folder.glob(f"*{RECORDS_SUFFIX}"))


def count_stored(folder: Path) -> int:
    """How many records the case files of the output folder ``folder`` hold (lines)."""
    count = 0
    for path in record_files(folder / CASES_FOLDER):
        with contextlib.suppress(OSError):
            count += path.read_bytes().count(b"\n")
    return count


@dataclass
class CaseStore:
    """The records of a study's finished cases in ``DIR/cases`` (see the module's notes).

    Attributes:
        folder: The study's output folder.
        study: The study.
        records: Case id -> record, of the cases stored so far.
        rejected: Stored lines that were not kept (``file:line`` -> why); their cases are run
            again.
        fresh: Whether :meth:`open` started the folder (it held no study before).
    """

    folder: Path
    study: Study
    records: dict[str, dict[str, Any]] = field(default_factory=dict)
    rejected: dict[str, str] = field(default_factory=dict)
    fresh: bool = False

    @property
    def cases_folder(self) -> Path:
        """Where the case records are."""
        return self.folder / CASES_FOLDER

    def open(self, cases: Sequence[Case]) -> None:
        """Create the folder, or reopen it: refuse another study's results, check the records.

        A line that is not a record of one of ``cases`` (see :func:`check_record`) is not
        kept: its case, if it names one, is computed again (:attr:`rejected` says which and
        why), and its file is rewritten without it.

        Args:
            cases: The study's cases; only their records are loaded.

        Raises:
            StudyError: The folder holds the results of another study, or of this study
                before its file or its base scenario changed, or case records without a
                ``study.json``; or ``study.json`` cannot be read.
            OutputError: The folder cannot be created or written.
        """
        state_path = self.folder / STATE_FILE
        self._check_state(state_path)
        target = self.cases_folder
        try:
            self.cases_folder.mkdir(parents=True, exist_ok=True)
            if not state_path.is_file():
                target = state_path
                state = {"study": self.study.source, "fingerprint": self.study.fingerprint}
                write_atomic(state_path, json.dumps(state, indent=2) + "\n")
                self.fresh = True
            for partial in self.cases_folder.glob(f".*{RECORDS_SUFFIX}.*"):  # killed writers'
                target = partial
                partial.unlink(missing_ok=True)
            by_id = {case.id: case for case in cases}
            for path in record_files(self.cases_folder):
                target = path
                self._load(path, by_id)
        except OSError as exc:
            raise OutputError(
                str(self.folder), f"cannot write '{target}' ({exc.strerror or exc})"
            ) from exc

    def _load(self, path: Path, by_id: Mapping[str, Case]) -> None:
        """Keep the records of ``path`` that pass; rewrite it without those that do not."""
        try:
            lines = path.read_bytes().decode().splitlines(keepends=True)
        except UnicodeDecodeError as exc:
            self.rejected[path.name] = f"cannot be read (not UTF-8 text at byte {exc.start})"
            path.unlink()
            return
        kept: list[str] = []
        for number, line in enumerate(lines, 1):
            reason = self._take(line, by_id)
            if reason is None:
                kept.append(line)
            else:
                self.rejected[f"{path.name}:{number}"] = reason
        if len(kept) == len(lines):
            return
        if kept:
            write_atomic(path, "".join(kept))
        else:
            path.unlink()

    def _take(self, line: str, by_id: Mapping[str, Case]) -> str | None:
        """Keep the record of one stored line; why not, if it cannot be kept."""
        try:
            record = json.loads(line)
        except ValueError as exc:
            return f"cannot be read ({' '.join(str(exc).split())[:120]})"
        if not isinstance(record, dict):
            return "not a record (a mapping)"
        name = record.get("case")
        if not isinstance(name, str):
            return "'case' is missing or of the wrong type"
        if name not in by_id:
            return f"it holds case {excerpt(name)}, not one of this study's"
        reason = check_record(record, by_id[name], self.study.fingerprint)
        if reason is None:
            self.records[name] = record
        return reason

    def _check_state(self, state_path: Path) -> None:
        """Refuse a folder that holds another study's results, or a damaged ``study.json``."""
        if not os.path.lexists(state_path):
            if record_files(self.cases_folder):
                raise StudyError(
                    self.study.source,
                    "",
                    f"'{self.cases_folder}' holds case records but '{state_path}' is missing, "
                    "so which study they belong to is unknown; to start over, delete that "
                    "folder or choose another --out",
                )
            return
        try:
            state = json.loads(read_text(state_path, StudyError))
        except (StudyError, ValueError) as exc:
            reason = exc.problem if isinstance(exc, StudyError) else f"not JSON: {exc}"
            raise StudyError(
                str(state_path),
                "",
                f"cannot read this study's state file ({' '.join(reason.split())[:160]}); "
                "delete the folder to start over, or choose another --out",
            ) from exc
        if not isinstance(state, dict) or not isinstance(state.get("fingerprint"), str):
            raise StudyError(
                str(state_path),
                "fingerprint",
                "the state file has no fingerprint (it is damaged); delete the folder to start "
                "over, or choose another --out",
            )
        if state["fingerprint"] != self.study.fingerprint:
            raise StudyError(
                self.study.source,
                "",
                f"'{self.folder}' holds results of a different study (this study file or its "
                "base scenario changed since they were computed); to start over, delete that "
                "folder or choose another --out",
            )

    def discard(self) -> None:
        """Remove what this run wrote into a folder it started (a study that cannot run)."""
        if not self.fresh:
            return
        for path in record_files(self.cases_folder):
            path.unlink(missing_ok=True)
        with contextlib.suppress(OSError):
            self.cases_folder.rmdir()
        (self.folder / STATE_FILE).unlink(missing_ok=True)
