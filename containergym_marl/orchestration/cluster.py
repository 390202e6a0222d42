"""The Ray session of a sweep: a local instance started on first use (with a reaper that stops its
processes if the driver is killed), or an existing cluster at ``--address``.

On a local instance evaluations use a slot resource of their own (one per core) instead of a CPU,
so a finished run is evaluated at once rather than after every queued training; on a cluster they
ask for a CPU. Every task carries ``max_retries``: when its worker process or node dies, Ray runs it
again (a retried training resumes, :mod:`~containergym_marl.orchestration.tasks`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import stat
import subprocess
import threading
import warnings
from pathlib import Path
from typing import Any

from containergym_marl.orchestration import ray_reaper
from containergym_marl.orchestration.tasks import evaluate_policy, train_run


class SweepError(RuntimeError):
    """The sweep cannot run (no Ray) or some of its tasks failed after Ray's retries; finished runs are kept."""


def ray_missing_message() -> str:
    """What to install when Ray is missing (the ``sweep`` extra), in the words compare prints."""
    from containergym_marl.extras import INSTALL

    return ("containergym-marl compare runs its training and evaluation on Ray, which is not installed: "
            f"{INSTALL['sweep']} (./run setup installs it)")



#: Where Ray keeps the token that its servers ask of every client (token authentication, on by default
#: for a local instance since Ray 2.59); the servers listen on every interface, so this file is what
#: keeps other users of the machine, and other machines, out of a local sweep.
RAY_TOKEN_FILE = Path("~/.ray/auth_token")


class RayTokenWarning(UserWarning):
    """Ray's token file can be read by other users: they could join the local instance and run code."""


def token_exposure(path: Path | None = None) -> str | None:
    """Why Ray's token file (default :data:`RAY_TOKEN_FILE`) can be read by users other than its owner,
    or None: the file readable by its group or by others, inside a folder they can enter."""
    path = (path or RAY_TOKEN_FILE).expanduser()
    try:
        file_mode, folder_mode = path.stat().st_mode, path.parent.stat().st_mode
    except OSError:
        return None
    readers = [who for who, read, enter in (("its group", stat.S_IRGRP, stat.S_IXGRP),
                                             ("other users", stat.S_IROTH, stat.S_IXOTH))
               if file_mode & read and folder_mode & enter]
    if not readers:
        return None
    return (f"Ray's token file {str(path)!r} can be read by {' and '.join(readers)} (file {stat.filemode(file_mode)}, "
            f"folder {stat.filemode(folder_mode)}): anyone who reads it can connect to this sweep's Ray servers, "
            f"which listen on every interface, and run code as you; run `chmod 600 {path}` and "
            f"`chmod 700 {path.parent}`")


#: Custom Ray resource of a local instance: evaluations running beside the trainings (one per core).
EVALUATION_SLOTS = "containergym_evaluation_slots"


@contextlib.contextmanager
def _keeping_sigterm_handler():
    """ray.init replaces the SIGTERM handler (in Python with ``sys.exit``, natively with a stack dump);
    put the caller's back, so that the CLI's SIGTERM stays the same orderly stop as Ctrl-C."""
    main = threading.current_thread() is threading.main_thread()
    handler = signal.getsignal(signal.SIGTERM) if main else None
    try:
        yield
    finally:
        if handler is not None:
            signal.signal(signal.SIGTERM, handler)


class Cluster:
    """A Ray session started on first use: a new local instance with ``num_cpus`` CPUs (default:
    this machine's cores), or the cluster at ``address`` (or ``$RAY_ADDRESS``). Quiet logging, no
    dashboard. ``close()`` disconnects, and stops the local instance if this object started it."""

    def __init__(self, address: str | None = None, num_cpus: int | None = None, max_retries: int = 3):
        self.address = address or os.environ.get("RAY_ADDRESS") or None
        self.num_cpus = num_cpus
        self.max_retries = max_retries
        self._ray = None
        self._owned = False
        self._reaper: subprocess.Popen | None = None
        self._tasks: dict[str, Any] = {}

    @property
    def started(self) -> bool:
        return self._ray is not None

    def ray(self):
        if self._ray is not None:
            return self._ray
        try:
            import ray
        except ImportError as exc:
            raise SweepError(ray_missing_message()) from exc
        if not ray.is_initialized():
            opts = dict(include_dashboard=False, logging_level=logging.ERROR, log_to_driver=False)
            with _keeping_sigterm_handler():
                self._init(ray, opts)
            self._owned = True
        self._ray = ray
        # On a local instance evaluations take slots of their own rather than CPUs: a finished run
        # is evaluated as soon as it lands (a short, briefly oversubscribed task) instead of waiting
        # behind hours of queued trainings. A cluster started elsewhere has no such slots.
        slots = ray.cluster_resources().get(EVALUATION_SLOTS, 0)
        evaluate_resources = {"num_cpus": 0, "resources": {EVALUATION_SLOTS: 1}} if slots else {"num_cpus": 1}
        self._tasks = {"train": ray.remote(num_cpus=1, max_retries=self.max_retries)(train_run),
                       "evaluate": ray.remote(max_retries=self.max_retries, **evaluate_resources)(evaluate_policy)}
        return ray

    def _init(self, ray, opts: dict) -> None:
        if self.address:
            if self.num_cpus:
                raise ValueError("--num-cpus sizes a local Ray instance; a cluster at --address has its own CPUs")
            ray.init(address=self.address, **opts)
            return
        cpus = self.num_cpus or os.cpu_count() or 1
        before = ray_reaper.child_pids()
        # Ray runs its workers at nice + 15 so that its own servers keep the CPU; here the workers are
        # the trainings themselves, and at nice + 15 any other process on the machine starves them. They
        # run at the caller's priority (`nice containergym-marl compare ...` still lowers it).
        ray.init(address="local", num_cpus=cpus, resources={EVALUATION_SLOTS: cpus},
                 _system_config={"worker_niceness": 0}, **opts)
        # the processes this ray.init started, stopped by the reaper if this driver is killed
        self._reaper = ray_reaper.watch(sorted(ray_reaper.child_pids() - before))
        exposed = token_exposure()  # Ray writes the file 0644 in a 0755 folder: readable on a shared machine
        if exposed:
            warnings.warn(exposed, RayTokenWarning, stacklevel=2)

    def cpus(self) -> int:
        return int(self.ray().cluster_resources().get("CPU", 1))

    def describe(self) -> str:
        ray = self.ray()
        nodes = [n for n in ray.nodes() if n.get("Alive")]
        where = f"cluster at {self.address}" if self.address else "local Ray instance"
        return f"{where}: {len(nodes)} node{'s' * (len(nodes) != 1)}, {self.cpus()} CPUs"

    def submit(self, kind: str, *args, **kwargs):
        self.ray()
        return self._tasks[kind].remote(*args, **kwargs)

    def events(self):
        from ray.util.queue import Queue

        self.ray()
        return Queue(actor_options={"num_cpus": 0})

    def close(self) -> None:
        if self._ray is not None and self._owned:
            self._ray.shutdown()
        if self._reaper is not None:
            self._reaper.stdin.close()  # the reaper stops whatever ray.shutdown() left behind
            try:
                self._reaper.wait(timeout=ray_reaper.GRACE_S + ray_reaper.POLL_S + 5)
            except subprocess.TimeoutExpired:
                self._reaper.kill()
        self._ray, self._owned, self._reaper = None, False, None

    def __enter__(self) -> "Cluster":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
