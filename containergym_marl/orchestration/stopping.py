"""How a study script stops when it is killed: SIGTERM taken as Ctrl-C takes SIGINT.

Python's default SIGTERM ends a process at once, so its ``finally`` clauses never run: the child
processes it started (training runs, search workers) go on without it, outside its locks, and a
second run of the same script meets them. :func:`exit_on_sigterm` makes SIGTERM raise ``SystemExit``
(143, as a shell reports it) in the main thread, so that the script stops its children and frees its
locks on the way out. (``containergym-marl compare`` has its own handler, in the CLI, which raises
``KeyboardInterrupt`` for Ray's sake.)
"""

from __future__ import annotations

import signal


def _exit(signum, frame):
    raise SystemExit(128 + signum)


def exit_on_sigterm() -> None:
    """From now on, SIGTERM raises ``SystemExit(143)`` in the main thread (call it from there)."""
    signal.signal(signal.SIGTERM, _exit)


__all__ = ["exit_on_sigterm"]
