"""How a study script stops when it is killed: SIGTERM taken as Ctrl-C takes SIGINT.

Python's default SIGTERM ends a process at once, so its ``finally`` clauses never run: the child
processes it started (training runs, search workers) go on without it, outside its locks, and a
second run of the same script meets them. :func:`exit_on_sigterm` makes SIGTERM raise ``SystemExit``
(143, as a shell reports it) in the main thread, so that the script stops its children and frees its
locks on the way out. A study's pool of worker processes is :func:`worker_pool`: leaving it by an
exception (that ``SystemExit``, Ctrl-C, an error) stops its workers in the middle of their tasks,
where ``ProcessPoolExecutor``'s own exit waits for every task under way to finish. (``containergym-marl compare`` has its own handler, in the CLI, which raises
``KeyboardInterrupt`` for Ray's sake.)
"""

from __future__ import annotations

import signal
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager


def _exit(signum, frame):
    raise SystemExit(128 + signum)


def exit_on_sigterm() -> None:
    """From now on, SIGTERM raises ``SystemExit(143)`` in the main thread (call it from there)."""
    signal.signal(signal.SIGTERM, _exit)


def _default_sigterm() -> None:
    # a worker forked after exit_on_sigterm would take SIGTERM as SystemExit, which its task loop
    # catches and reports as the task's outcome; the default action ends it at once
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


@contextmanager
def worker_pool(workers: int) -> Iterator[ProcessPoolExecutor]:
    """A ``ProcessPoolExecutor`` of ``workers`` processes that stop with the study: left normally, it
    waits for its tasks; left by an exception, it cancels the queued tasks, terminates the workers
    (their tasks under way end with them; results a study writes atomically are whole or absent),
    waits for them to end and re-raises."""
    pool = ProcessPoolExecutor(workers, initializer=_default_sigterm)
    try:
        yield pool
    except BaseException:
        # the workers, read before shutdown forgets them (ProcessPoolExecutor has no public handle
        # on them before Python 3.14's terminate_workers)
        processes = list((pool._processes or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.terminate()
        for process in processes:
            process.join()
        raise
    pool.shutdown(wait=True)


__all__ = ["exit_on_sigterm", "worker_pool"]
