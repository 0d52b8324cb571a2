"""Copies of the shipped scenarios, studies, robots and programs, to start from (``vtm-pin init``).

A copy must work from its new folder: a study's ``scenario: ../scenarios/x.yaml`` becomes the
shipped scenario's name (which :func:`vtm_pin.study.cases.load_study` accepts), a scenario's
``include`` fragments are copied beside it, and a robot comes with its URDF (the shipped one,
or example-robot-data's for an arm whose data file only is shipped) beside its data file. A
copy's ``# yaml-language-server: $schema=`` line names the installed schema file by its absolute
path, so that an editor checks the copy wherever it lives.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path

from .exceptions import InputError, OutputError, excerpt
from .files.inputs import read_text, read_yaml
from .physics.robot import ROBOTS_DIR, list_example_robots, load_robot
from .scene.program import PROGRAMS_DIR
from .scene.scenario import SCENARIOS_DIR
from .schemas import schema_file
from .study.cases import STUDIES_DIR

#: What ``vtm-pin init`` copies, and the folder each kind is shipped in.
KINDS: Mapping[str, Path] = {
    "scenario": SCENARIOS_DIR,
    "study": STUDIES_DIR,
    "robot": ROBOTS_DIR,
    "program": PROGRAMS_DIR,
}

#: The file suffixes of each kind's shipped files (``.yaml`` for kinds not listed).
_SUFFIXES: Mapping[str, tuple[str, ...]] = {"robot": (".urdf", ".yaml"), "program": (".csv",)}


def shipped_names(kind: str) -> list[str]:
    """The shipped names of ``kind`` (file stems; a robot's URDF and data file count once)."""
    folder = KINDS[kind]
    suffixes = _SUFFIXES.get(kind, (".yaml",))
    return sorted({p.stem for p in folder.iterdir() if p.suffix in suffixes})


def init_files(kind: str, name: str, folder: Path) -> list[Path]:
    """Copy the shipped ``kind`` named ``name`` into ``folder`` (made if missing).

    Returns:
        The files written, the one asked for first.

    Raises:
        InputError: ``kind`` or ``name`` is not shipped (the message lists the choices), or a
            file to write exists already (nothing is written then).
        OutputError: A file could not be written (those written before it are removed).
    """
    if kind not in KINDS:
        raise InputError(
            "command line", "KIND", f"'{excerpt(kind)}' is not one of {', '.join(KINDS)}"
        )
    names = shipped_names(kind)
    stem = name.removesuffix(".yaml").removesuffix(".urdf").removesuffix(".csv")
    if stem not in names:
        raise InputError(
            "command line",
            "NAME",
            f"'{excerpt(name)}' is not a shipped {kind}; the shipped ones are: {', '.join(names)}",
        )
    copies = {"scenario": _scenario, "study": _study, "robot": _robot, "program": _program}[kind](
        stem
    )
    targets = [folder / file for file in copies]
    for target in targets:
        if target.exists() or target.is_symlink():
            raise InputError(
                "command line",
                "--to",
                f"{target} exists; nothing copied (move it away, or give --to another folder)",
            )
    written: list[Path] = []
    try:
        folder.mkdir(parents=True, exist_ok=True)
        for target, text in zip(targets, copies.values(), strict=True):
            with target.open("x", encoding="utf-8") as file:
                written.append(target)
                file.write(text)
    except OSError as exc:
        for path in written:
            path.unlink(missing_ok=True)
        raise OutputError(str(folder), f"cannot write {target.name} ({exc.strerror})") from exc
    return targets


def _scenario(name: str) -> dict[str, str]:
    """The scenario's text, with its ``include`` fragments copied beside it (by file name)."""
    path = SCENARIOS_DIR / f"{name}.yaml"
    text = read_text(path, InputError)
    raw = read_yaml(path, InputError)
    fragments: dict[str, str] = {}
    for entry in raw.get("include", []):
        fragment = SCENARIOS_DIR / entry
        fragments[fragment.name] = read_text(fragment, InputError)
        text = text.replace(entry, fragment.name)
    return {path.name: _schema_line(text, "scenario"), **fragments}


def _study(name: str) -> dict[str, str]:
    """The study's text, its base scenario named by its shipped name if it is a shipped one."""
    path = STUDIES_DIR / f"{name}.yaml"
    text = read_text(path, InputError)
    base = SCENARIOS_DIR / Path(str(read_yaml(path, InputError)["scenario"])).name
    if base.is_file():
        line = f"scenario: {base.stem}   # shipped (vtm-pin init scenario {base.stem} copies it)"
        text = re.sub(r"^scenario:.*$", line, text, count=1, flags=re.MULTILINE)
    return {path.name: _schema_line(text, "study")}


def _schema_line(text: str, kind: str) -> str:
    """``text`` with its editor schema line naming the installed schema of ``kind``."""
    line = f"# yaml-language-server: $schema={Path(str(schema_file(kind))).resolve()}"
    return re.sub(r"^# yaml-language-server: \$schema=.*$", line, text, count=1, flags=re.MULTILINE)


def _robot(name: str) -> dict[str, str]:
    """The robot's URDF and data file; example-robot-data's URDF for a data file alone."""
    copies: dict[str, str] = {}
    urdf = ROBOTS_DIR / f"{name}.urdf"
    if not urdf.is_file() and name in list_example_robots():
        urdf = Path(load_robot(name).source)
    if urdf.is_file():
        copies[f"{name}.urdf"] = read_text(urdf, InputError)
    data = ROBOTS_DIR / f"{name}.yaml"
    if data.is_file():
        copies[data.name] = read_text(data, InputError)
    return copies


def _program(name: str) -> dict[str, str]:
    """The program's CSV file, as it is (it names no other file)."""
    path = PROGRAMS_DIR / f"{name}.csv"
    return {path.name: read_text(path, InputError)}
