"""The ``vtm-pin`` command and ``python -m vtm_pin``: the CLI, with Ctrl-C caught from the start.

The CLI imports Pinocchio, SciPy and Matplotlib, which takes a second or two; this module
imports nothing heavy itself, so that Ctrl-C during those imports exits with status 130 and
one line, as it does during a run.

A study on local workers starts the pools' fork server first
(:func:`~vtm_pin.study.executors.start_fork_server`), so that its imports (~1.7 s) run beside
the CLI's and its workers can start their cases as soon as the driver has drawn them.
"""

from __future__ import annotations

import argparse
import gc
import signal
import sys
from collections.abc import Sequence

from .files.interrupts import EXIT_INTERRUPTED, forget_interrupt
from .study.executors import default_workers, start_fork_server


class _Guess(argparse.ArgumentParser):
    """A parser that raises instead of printing: :func:`pooled_study` only guesses."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise ValueError(message)


def pooled_study(argv: Sequence[str]) -> bool:
    """Whether ``argv`` runs a study on more than one local worker (no ``--scheduler``).

    Read from ``study`` and its ``--workers`` and ``--scheduler`` only, before the CLI's
    parser is imported: anything this cannot read (``--help``, a bad value) is False, and the
    command itself starts the fork server when it needs one, as it always does.
    """
    if not argv or argv[0] != "study" or {"-h", "--help"} & set(argv):
        return False
    parser = _Guess(add_help=False)
    parser.add_argument("--workers", type=int)
    parser.add_argument("--scheduler")
    try:
        known, _ = parser.parse_known_args(argv[1:])
    except ValueError:
        return False
    workers = known.workers if known.workers is not None else default_workers()
    return known.scheduler is None and workers > 1


def entry_point() -> int:
    """Run ``vtm-pin`` on ``sys.argv``; returns the exit status.

    The process ends once the command returns: its objects are then frozen (``gc.freeze``),
    so that the interpreter's collections at exit do not walk them all again. After a
    10,000-case study (its records, table and summary) they took 0.2-0.25 s of the command,
    against ~0.05 s frozen (issue 27).
    """
    interrupted = []

    def interrupt(signum: int, frame: object) -> None:
        # Remembered as well as raised: Python drops an exception raised inside a weakref
        # callback ("Exception ignored in ..."), which the import machinery runs.
        interrupted.append(signum)
        raise KeyboardInterrupt

    def unraisable(report: sys.UnraisableHookArgs) -> None:
        if report.exc_type is not KeyboardInterrupt:  # that one is remembered: no traceback
            sys.__unraisablehook__(report)

    try:
        previous = signal.signal(signal.SIGINT, interrupt)
    except ValueError:  # not the main thread: signals are not ours to catch
        previous = None
    sys.unraisablehook, hook = unraisable, sys.unraisablehook
    try:
        if pooled_study(sys.argv[1:]):
            start_fork_server()
        from .cli import main
    except KeyboardInterrupt:
        interrupted.append(signal.SIGINT)
    finally:
        sys.unraisablehook = hook
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
    if interrupted:
        forget_interrupt()
        print("vtm-pin: interrupted; nothing written", file=sys.stderr)
        return EXIT_INTERRUPTED
    code = main()
    gc.freeze()
    return code


if __name__ == "__main__":
    sys.exit(entry_point())
