"""Stops the processes of a local Ray instance whose driver died without closing it.

A driver killed with SIGKILL (an OOM kill, a CI timeout) cannot run ``ray.shutdown()``; Ray's own
agents then notice the lost raylet only after a minute or more. :func:`watch` starts this module as
a small process that holds the read end of a pipe from the driver: when the driver exits, however it
exits, the pipe reaches end-of-file and the reaper stops the processes the instance had started
(SIGTERM, then SIGKILL after three seconds). Until then it records, every two seconds, which
processes descend from the instance's own (workers come and go), so it can find them after the
driver's death has re-parented them. A process is only signalled if its creation time still matches
the one recorded, so a reused pid is never hit.
"""

from __future__ import annotations

import json
import os
import select
import subprocess
import sys

#: Seconds between two looks at the instance's process tree.
POLL_S = 2.0
#: Seconds the processes get to end after SIGTERM before SIGKILL.
GRACE_S = 3.0


def child_pids() -> set[int]:
    """This process's children now (empty without psutil): taken before and after ``ray.init`` to
    find the processes it started."""
    try:
        import psutil
    except ImportError:
        return set()
    return {child.pid for child in psutil.Process().children()}


def watch(root_pids: list[int]) -> subprocess.Popen | None:
    """Start a reaper for the processes ``root_pids`` and their descendants; it acts once this process
    exits. Returns the reaper (None where psutil is missing: Ray installs it, so that is rare)."""
    try:
        import psutil
    except ImportError:
        return None
    roots = []
    for pid in root_pids:
        try:
            roots.append([pid, psutil.Process(pid).create_time()])
        except psutil.NoSuchProcess:
            continue
    # psutil may be the copy Ray puts on sys.path at import (ray/thirdparty_files): the reaper gets
    # the folder it came from.
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [os.path.dirname(os.path.dirname(psutil.__file__)),
                                                      env.get("PYTHONPATH")]))
    # The reaper must not die with the driver's terminal or process group: its own session.
    return subprocess.Popen([sys.executable, "-m", __name__, json.dumps(roots)], stdin=subprocess.PIPE,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
                            close_fds=True, env=env)


def _tree(known: dict[int, float]) -> dict[int, float]:
    """``known`` with every live process descending from one of them added (pid -> creation time)."""
    import psutil

    found = dict(known)
    for pid, created in known.items():
        try:
            proc = psutil.Process(pid)
            if proc.create_time() != created:
                continue
            for child in proc.children(recursive=True):
                found.setdefault(child.pid, child.create_time())
        except psutil.Error:
            continue
    return found


def _stop(known: dict[int, float]) -> None:
    import psutil

    procs = []
    for pid, created in known.items():
        try:
            proc = psutil.Process(pid)
            if proc.create_time() == created:
                proc.terminate()
                procs.append(proc)
        except psutil.Error:
            continue
    _, alive = psutil.wait_procs(procs, timeout=GRACE_S)
    for proc in alive:
        try:
            proc.kill()
        except psutil.Error:
            continue


def main(argv: list[str]) -> None:
    """The reaper process: ``argv[0]`` the instance's processes as JSON [(pid, creation time)]; it
    watches standard input (the driver's pipe) and stops them when it closes."""
    known = _tree({int(pid): float(created) for pid, created in json.loads(argv[0])})
    stdin = sys.stdin.fileno()
    while True:
        ready, _, _ = select.select([stdin], [], [], POLL_S)
        if ready and not os.read(stdin, 4096):
            break  # end-of-file: the driver is gone
        known = _tree(known)
    _stop(_tree(known))


if __name__ == "__main__":
    main(sys.argv[1:])
