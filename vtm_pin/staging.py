"""Output folders written all at once: files go to a staging folder, then move in together."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

from .exceptions import OutputError


def write_staged(out: str | Path, write: Callable[[Path], None]) -> list[str]:
    """Let ``write`` fill a staging folder beside ``out``, then move its files into ``out``.

    Files of the same name already in ``out`` are replaced, others are kept. If ``write``
    fails, nothing is moved into ``out``.

    Returns:
        The names of the files written, sorted.

    Raises:
        OutputError: A file could not be written or moved; ``out`` is as it was.
    """
    out = Path(out)
    staging: Path | None = None
    try:
        parent = out.resolve().parent
        parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=".vtm-pin-", dir=parent))
        write(staging)
        out.mkdir(parents=True, exist_ok=True)
        written = sorted(item.name for item in staging.iterdir())
        for name in written:
            os.replace(staging / name, out / name)
    except OSError as exc:
        raise OutputError(str(out), f"cannot write '{out}' ({exc.strerror or exc})") from exc
    finally:
        if staging is not None:
            shutil.rmtree(staging, ignore_errors=True)
    return written
