"""Ctrl-C: the exit status it gives, and how a caught one ends the process with that status.

Kept apart from the command line so that ``python -m vtm_pin`` (:mod:`vtm_pin.__main__`) can
catch Ctrl-C before it imports anything heavy, and the CLI can use the same rules.
"""

from __future__ import annotations

#: Exit status after Ctrl-C (128 + SIGINT).
EXIT_INTERRUPTED = 130


def forget_interrupt() -> None:
    """Let a caught Ctrl-C end the process with its exit status, not by SIGINT.

    CPython marks a KeyboardInterrupt raised inside code that ``exec`` runs from a string
    (``namedtuple`` and others do so while modules are imported) as unhandled, even once it
    is caught, and then ends the process by SIGINT (status -2) whatever ``sys.exit`` asked.
    Running a string through ``exec`` clears that mark.
    """
    exec("pass")
