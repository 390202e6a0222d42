"""The sweep's two kinds of task, as data and as bodies: a training run (:class:`RunSpec`,
:func:`train_run`) and an evaluation (:class:`EvalSpec`, :func:`evaluate_policy`).

A training task decides for itself what to do with its run directory (:func:`prepare_run`): a
finished run is returned as is, a run with a checkpoint is resumed from its latest intact checkpoint
(losing at most one checkpoint interval), a run that died before its first checkpoint starts over. So
a retried task, a rerun after Ctrl-C and a rerun after a crash all continue where the run stands.
Each training task holds its run's lock (:class:`~containergym_marl.rundir.RunLock`, the one a
``containergym-marl train`` takes) from that decision to the end of the training, so two sweeps, or a
sweep and a ``train``, never write one run at once; it appends one line per attempt to
``<runs>/.sweep/<run>.log``, and sends its progress (started, samples so far) to the driver.

A task returns the run's small files (everything except ``checkpoints/``, ``tb/``, the lock and
temporary files: args, config, metrics, best and final model, ~0.5 MB), which the driver writes into
its own copy of the run directory (:func:`~containergym_marl.rundir.write_files`): without a
filesystem shared by all nodes the driver still gets every file the table, the figures and a later
rerun need.
"""

from __future__ import annotations

import contextlib
import os
import socket
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from containergym_marl.core.dynamics import DEFAULT_ARBITRATION
from containergym_marl.files import open_file
from containergym_marl.manifest import sha256_bytes
from containergym_marl.rundir import (
    MODELS,
    RunLock,
    check_model_file,
    clear_run,
    finished_budget,
    latest_intact_checkpoint,
    measured_rate,
    model_file,
    read_metrics,
    small_files,
    write_files,
)


@dataclass(frozen=True)
class RunSpec:
    """One training run of a sweep: ``train(TrainArgs(algo, config, seed, timesteps, out=run_dir, **train))``."""

    name: str  # <method>_<config>_s<seed>
    method: str
    algo: str
    config: str
    seed: int
    timesteps: int
    run_dir: str  # absolute; the same path on every node
    train: dict[str, Any] = field(default_factory=dict)  # further TrainArgs fields (n_envs, reward_mode, …)
    #: after training, the run's sample-efficiency curve (RUN/curve.json, from its checkpoints, which
    #: stay on the node): made here, where the checkpoints are, and returned with the small files
    curve: bool = False

    def train_args(self, resume: bool):
        from containergym_marl.training.train_args import TrainArgs

        return TrainArgs(algo=self.algo, config=self.config, seed=self.seed, timesteps=self.timesteps,
                         out=self.run_dir, resume=resume, progress_bar=False, torch_threads=1, **self.train)

    @property
    def sweep_dir(self) -> Path:
        return Path(self.run_dir).parent / ".sweep"


def check_budget(spec: RunSpec) -> bool:
    """True when ``spec``'s run is finished here with the same budget; a finished run with another
    budget is an error (never retrained or overwritten)."""
    budget = finished_budget(spec.run_dir)
    if budget is not None and budget != spec.timesteps:
        raise ValueError(f"{spec.run_dir} holds a finished run with a budget of {budget} samples, not "
                         f"{spec.timesteps}; use another --runs directory or the same --timesteps")
    return budget is not None


def prepare_run(spec: RunSpec, held_lock: RunLock | None = None) -> tuple[str, int]:
    """What a training task does with its run directory, and from which sample count:
    ``("finished", budget)``, ``("resume", checkpoint samples)`` or ``("new", 0)``.

    Everything is decided and cleaned while holding the run's lock (``held_lock``, or taken here: a
    directory that a running ``train`` holds is never touched, :class:`~containergym_marl.rundir.RunError`).
    Broken checkpoints are set aside; a run directory without an intact checkpoint (the run died
    before its first one) is cleared of what training wrote and the run starts over."""
    run = Path(spec.run_dir)
    if check_budget(spec):
        return "finished", spec.timesteps
    with contextlib.nullcontext() if held_lock is not None else RunLock(run):
        steps = latest_intact_checkpoint(run)
        if steps is not None and (run / "args.json").is_file():
            best = run / model_file(run, "best")
            if best.exists():
                try:
                    check_model_file(best)
                except ValueError:
                    best.unlink()  # cut short by a kill; the resumed run saves its next best
            return "resume", steps
        clear_run(run)
    return "new", 0


class MetricsReporter(threading.Thread):
    """Sends ("progress", run, samples, samples/s) whenever the run's metrics.csv grows."""

    def __init__(self, run_dir: Path, name: str, events, start_samples: int, every_s: float = 5.0):
        super().__init__(daemon=True, name=f"metrics-{name}")
        self.run_dir, self.run_name, self.events = run_dir, name, events
        self.start_samples, self.every_s = start_samples, every_s
        self.skip = len(read_metrics(run_dir, quiet=True))  # rows of earlier attempts
        self.stopped = threading.Event()

    def run(self) -> None:  # the thread's body
        seen = self.skip
        while not self.stopped.wait(self.every_s):
            rows = read_metrics(self.run_dir, quiet=True)
            if len(rows) > seen:
                seen = len(rows)
                last = rows[-1]
                wall = last.get("wall_time_s", 0.0)
                rate = (last["timesteps"] - self.start_samples) / wall if wall > 0 else None
                _emit(self.events, ("progress", self.run_name, int(last["timesteps"]), rate))

    def stop(self) -> None:
        self.stopped.set()


class EventSender:
    """What a task holds of the driver's event queue: ``put_nowait`` sends without waiting. (A task
    blocked in ``ray.get``, as ``Queue.put`` is, lends its CPU back to Ray, which then starts
    another training on it.)"""

    def __init__(self, queue_actor):
        self.queue_actor = queue_actor

    def put_nowait(self, item) -> None:
        self.queue_actor.put_nowait.remote(item)


def _emit(events, item) -> None:
    if events is None:
        return
    try:
        events.put_nowait(item)
    except Exception:  # the driver or its queue went away: progress is best effort
        pass


# ---- the tasks ----------------------------------------------------------------------------------
def train_run(spec: RunSpec, events=None) -> dict[str, Any]:
    """Body of a training task: finish, resume or start ``spec``'s run; returns its small files and
    timings. Idempotent: running it again on a finished run trains nothing. The run's lock is held
    from the decision to the end of the training (handed to ``train``), so two sweeps never train
    one run at once."""
    import torch

    torch.set_num_threads(1)
    from containergym_marl.training.loop import train

    run = Path(spec.run_dir)
    spec.sweep_dir.mkdir(parents=True, exist_ok=True)
    with RunLock(run) as lock:
        return _train_locked(spec, run, events, train, lock)


def _train_locked(spec: RunSpec, run: Path, events, train, lock: RunLock) -> dict[str, Any]:
    # Opened first, in the runs folder where no link is followed (containergym_marl.files): a log
    # linked elsewhere is refused before the run is touched.
    with open_file(spec.sweep_dir / f"{spec.name}.log", "a", within=run.parent) as log:
        state, start = prepare_run(spec, lock)
        host = socket.gethostname()
        action = {"finished": "finished already", "resume": f"resume from {start} samples", "new": "start"}[state]
        log.write(f"{time.strftime('%Y-%m-%d %H:%M:%S')} {host} pid {os.getpid()}: {action}\n")
    _emit(events, ("start", spec.name, host, os.getpid(), state, start))
    t0 = time.perf_counter()
    if state != "finished":
        reporter = MetricsReporter(run, spec.name, events, start)
        reporter.start()
        try:
            train(spec.train_args(resume=state == "resume"), held_lock=lock)
        finally:
            reporter.stop()
    wall = time.perf_counter() - t0
    if spec.curve:
        from containergym_marl.evaluation.curves import CURVE_FILE, run_curve  # torch: on the training node

        if not (run / CURVE_FILE).is_file():
            run_curve(run)
    trained = spec.timesteps - start if state != "finished" else 0
    # samples/s of the training itself (metrics.csv) when the run logged any, else over the whole call
    rate = (measured_rate(run) or trained / wall) if trained and wall > 0 else None
    result = {"name": spec.name, "state": state, "resumed_from": start if state == "resume" else 0,
              "samples": trained, "wall_s": wall, "samples_per_s": rate,
              "host": host, "node": _node_id(), "pid": os.getpid(), "files": small_files(run)}
    return result


def _node_id() -> str | None:
    try:
        import ray

        return ray.get_runtime_context().get_node_id() if ray.is_initialized() else None
    except Exception:
        return None


@dataclass(frozen=True)
class EvalSpec:
    """One evaluation on ``protocol``'s episodes (the paper's test protocol, or validation or fresh
    episodes: a study is a comparison on those): a controller (a method of
    :mod:`containergym_marl.methods` with one), or a run's best model (its files come with the task)."""

    key: str  # the evaluation file's stem: <method>_s<seed> or <method>
    method: str
    config: str
    protocol: Any  # an EvalProtocol (imported where the task runs)
    arbitration: str = DEFAULT_ARBITRATION
    seed: int | None = None


def evaluate_policy(spec: EvalSpec, run: dict[str, Any] | None = None, keep_records: bool = False):
    """Body of an evaluation task; ``run`` holds the run's files (a training task's result or
    ``{"files": {...}}``). Returns the EvaluationResult (records only with ``keep_records``) and the
    sha256 of the evaluated model."""
    import torch

    torch.set_num_threads(1)
    from containergym_marl.config import load_config
    from containergym_marl.evaluation import evaluate

    protocol = spec.protocol
    if run is None:
        from containergym_marl.core.params import PlantParams
        from containergym_marl.methods import get_method

        policy = get_method(spec.method).controller(PlantParams.from_config(load_config(spec.config)))
        model_sha = None
        result = evaluate(policy, spec.config, protocol, arbitration=spec.arbitration, keep_records=keep_records)
    else:
        from containergym_marl.evaluation.run_policies import evaluated_model, evaluated_which, policy_from_run

        files = run["files"]  # evaluation.run_policies.evaluated_files of the run
        model_sha = sha256_bytes(evaluated_model(files))
        with tempfile.TemporaryDirectory(prefix="cgm-eval-") as tmp:
            write_files(tmp, {k: v for k, v in files.items() if k in ("args.json", "run.json")
                              or k.startswith(tuple(f"{which}_model." for which in MODELS))})
            policy = policy_from_run(tmp, evaluated_which(tmp))
            result = evaluate(policy, spec.config, protocol, arbitration=spec.arbitration, keep_records=keep_records)
    return result, model_sha
