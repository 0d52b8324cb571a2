"""Pinocchio models kept on disk between runs, for the robots that are slow to build.

example-robot-data's loader builds a robot's meshes with its model (~0.45 s for the UR10),
though vtm_pin keeps the model only; a study's driver did that in every command. The model is
kept here instead, as one JSON file per robot: the model in Pinocchio's own text format
(``saveToString``, exact: every double is written with all its digits), the URDF it came
from with that file's modification time and size, and the versions of Pinocchio and of
the package that built it. A file is used only while all of these still hold, and a model is
kept only if it reads back equal (``==``) to the one built; so what a run gets from here is
what it would have built (~0.3 ms to read the UR10's).

The folder is ``$VTM_PIN_CACHE/models``, else ``$XDG_CACHE_HOME/vtm_pin/models``, else
``~/.cache/vtm_pin/models``; deleting it is always safe. Nothing here fails a run: a file
that cannot be read or written is rebuilt, or not kept.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import pinocchio as pin

from .staging import write_atomic

#: Version of this module's file layout (a file of another layout is not read).
FORMAT = 1


def folder() -> Path:
    """Where the models are kept (see the module docstring)."""
    root = os.environ.get("VTM_PIN_CACHE")
    if root:
        return Path(root) / "models"
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "vtm_pin" / "models"


def read(name: str, versions: dict[str, str]) -> tuple[pin.Model, str] | None:
    """The kept model of robot ``name`` and its URDF, if still valid; else None.

    Args:
        name: The robot's name (as its loader knows it).
        versions: The versions of the software that builds it; a file from others is stale.
    """
    try:
        entry = json.loads(_path(name, versions).read_text("utf-8"))
        if entry.get("format") != FORMAT or entry.get("versions") != versions:
            return None
        if entry.get("stat") != _stat(entry["source"]):
            return None
        model = pin.Model()
        model.loadFromString(entry["model"])
        return model, str(entry["source"])
    except Exception:  # absent, unreadable, damaged: built again
        return None


def write(name: str, versions: dict[str, str], model: pin.Model, source: str) -> bool:
    """Keep ``model`` (built from the URDF ``source``) for the next run; whether it was kept.

    Not kept if it does not read back equal to itself, if ``source`` is not a file, or if the
    folder cannot be written (:func:`~vtm_pin.files.staging.write_atomic`: a reader sees the
    whole file or none).
    """
    try:
        text = model.saveToString()
        again = pin.Model()
        again.loadFromString(text)
        stat = _stat(source)
        if not (again == model and stat is not None):
            return False
        entry = {
            "format": FORMAT,
            "name": name,
            "versions": versions,
            "source": source,
            "stat": stat,
            "model": text,
        }
        path = _path(name, versions)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, json.dumps(entry))
        return True
    except Exception:  # a read-only or full disk: built again next time
        return False


def _path(name: str, versions: dict[str, str]) -> Path:
    """The file of robot ``name`` built by these versions."""
    key = hashlib.sha256(json.dumps([name, versions], sort_keys=True).encode()).hexdigest()
    safe = "".join(c if c.isalnum() or c in "-_" else "_" for c in name)[:40]
    return folder() / f"{safe}-{key[:16]}.json"


def _stat(source: str) -> list[int] | None:
    """The file's modification time [ns] and size [bytes]; None if it is not a file."""
    try:
        info = os.stat(source)
    except (OSError, ValueError):
        return None
    return [info.st_mtime_ns, info.st_size]
