"""Output folders: one run at a time, and their files written all at once.

:func:`output_lock` makes an output folder belong to one run: a second run into the same
folder is refused in one line while the first holds it (``flock``: on one machine, and on
network file systems that carry it). :func:`write_staged` writes a run's files into a staging
folder beside the output folder and then moves them in together; a staging folder left by a
run killed outright is removed by the next run into the same folder. :func:`write_atomic`
writes one file whole (a study's case records, the models kept between runs).
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import os
import shutil
import tempfile
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from ..exceptions import OutputError, VtmWarning

#: Output folders this process holds (a run's own nested writes do not lock again).
_HELD: set[str] = set()


@contextmanager
def output_lock(out: str | Path) -> Iterator[None]:
    """Hold ``out`` (created if missing) for this run; refuse if another run holds it.

    The lock is an exclusive ``flock`` on the folder itself, so it leaves no file behind and
    ends with the process however it ends. Where there is no ``flock`` (Windows) the folder is
    used without a lock; where the file system refuses it, too, with a warning line.

    Raises:
        OutputError: Another run holds the folder, or it cannot be created.
    """
    out = Path(out)
    created = False
    try:
        key = str(out.resolve())
        out.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.mkdir(out)
            created = True  # by this run: removed again if it writes nothing
        except FileExistsError:
            pass
        fd = os.open(out, os.O_RDONLY)
    except (OSError, RuntimeError) as exc:
        where = getattr(exc, "filename", None) or out
        reason = getattr(exc, "strerror", None) or exc
        raise OutputError(str(out), f"cannot write into '{where}' ({reason})") from exc
    if key in _HELD:  # this run's own nested write
        os.close(fd)
        yield
        return
    try:
        _lock(fd, out)
    except BaseException:
        os.close(fd)
        raise
    _HELD.add(key)
    try:
        yield
    finally:
        _HELD.discard(key)
        if created:  # nothing written: leave nothing (while still holding the folder)
            with contextlib.suppress(OSError):
                out.rmdir()
        os.close(fd)  # releases the lock


def _lock(fd: int, out: Path) -> None:
    """Take the exclusive lock on the folder ``fd`` without waiting."""
    try:
        import fcntl
    except ImportError:  # Windows: no flock
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError as exc:
        raise OutputError(
            str(out),
            f"'{out}' is being written by another vtm-pin run; wait for it to end, or choose "
            "another --out",
        ) from exc
    except OSError as exc:  # a file system without flock: go on, but say so
        warnings.warn(
            f"'{out}' cannot be locked ({exc.strerror or exc}): another run writing into it at "
            "the same time would not be refused",
            VtmWarning,
            stacklevel=4,
        )


def _staging_prefix(out: Path) -> str:
    """Name prefix of ``out``'s staging folders (beside it): one per output folder."""
    digest = hashlib.sha256(str(out.resolve()).encode()).hexdigest()[:12]
    return f".vtm-pin-staging-{digest}-"


def write_staged(out: str | Path, write: Callable[[Path], None]) -> list[str]:
    """Let ``write`` fill a staging folder beside ``out``, then move its files into ``out``.

    Files of the same name already in ``out`` are replaced, others are kept. If ``write``
    fails, nothing is moved into ``out``. The folder is held (:func:`output_lock`) meanwhile,
    and staging folders that killed runs left for ``out`` are removed first.

    Returns:
        The names of the files written, sorted.

    Raises:
        OutputError: Another run holds ``out``, or a file could not be written or moved
            (naming it); ``out`` is as it was.
    """
    out = Path(out)
    staging: Path | None = None
    with output_lock(out):
        try:
            parent = out.resolve().parent
            prefix = _staging_prefix(out)
            for stale in parent.glob(f"{prefix}*"):
                shutil.rmtree(stale, ignore_errors=True)
            staging = Path(tempfile.mkdtemp(prefix=prefix, dir=parent))
            write(staging)
            written = sorted(item.name for item in staging.iterdir())
            for name in written:
                os.replace(staging / name, out / name)
        except OSError as exc:
            where = exc.filename or out
            raise OutputError(str(out), f"cannot write '{where}' ({exc.strerror or exc})") from exc
        finally:
            if staging is not None:
                shutil.rmtree(staging, ignore_errors=True)
    return written


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file in the same folder and a rename.

    A killed process leaves the old file or the new one, never a part (and perhaps a
    temporary ``.NAME.<pid>.<n>`` file, which is never read). There is no fsync: the page
    cache outlives the process, and a case lost to a power cut is run again. The temporary
    file is created with mode 0o666 less the umask, as any new file (``os.open``, exclusive:
    a name left by a killed process of the same id is skipped).
    """
    data = text.encode()
    while True:
        tmp = path.with_name(f".{path.name}.{os.getpid()}.{next(_TEMPORARY)}")
        try:
            fd = _create(tmp)
            break
        except FileExistsError:
            continue
    try:
        with open(fd, "wb") as file:
            file.write(data)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _create(path: Path) -> int:
    """A new file's descriptor, for writing (mode 0o666 less the umask; it must not exist)."""
    return os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)


#: Numbers of this process's temporary files (:func:`write_atomic`).
_TEMPORARY = itertools.count()
