"""The ``vtm-pin`` command and ``python -m vtm_pin``: the CLI, with Ctrl-C caught from the start.

The CLI imports Pinocchio, SciPy and Matplotlib, which takes a second or two; this module
imports nothing heavy itself, so that Ctrl-C during those imports exits with status 130 and
one line, as it does during a run.
"""

from __future__ import annotations

import signal
import sys

from .files.interrupts import EXIT_INTERRUPTED, forget_interrupt


def entry_point() -> int:
    """Run ``vtm-pin`` on ``sys.argv``; returns the exit status."""
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
    return main()


if __name__ == "__main__":
    sys.exit(entry_point())
