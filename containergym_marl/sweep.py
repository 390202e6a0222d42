"""compare's job graph on Ray: one task per training run, one per evaluation, progress in the driver.

What Ray does here, and what this module adds:

* **Resources**: every training asks for ``num_cpus=1`` (torch runs one thread), so Ray runs as many
  trainings at once as the cluster has CPUs, on whichever node has one free. On a local instance
  evaluations use a slot resource of their own (one per core) instead of a CPU, so a finished run is
  evaluated at once rather than after every queued training; on a cluster they ask for a CPU.
* **Retries**: training and evaluation tasks carry ``max_retries``; when the worker process or its
  node dies, Ray runs the task again. A training task decides for itself what to do with its run
  directory (:func:`prepare_run`): a finished run is returned as is, a run with a checkpoint is
  resumed from its latest intact checkpoint (``train(TrainArgs(..., resume=True))``, losing at
  most one checkpoint interval), a run that died before its first checkpoint starts over. So a
  retried task, a rerun after Ctrl-C and a rerun after a crash all continue where the run stands.
* **Dependencies**: an evaluation task takes the training task's result (the run's small files,
  models included) as its argument; Ray starts it when the training ends.
* **Progress**: training tasks send events (started, samples so far, finished) through a
  ``ray.util.queue.Queue``; the driver folds them into one live line (runs done / running / left,
  evaluations, ETA, samples/s of every running run).

Storage: a training task writes its run directory at the same absolute path on whichever node runs
it, and returns the run's small files (everything except ``checkpoints/``, ``tb/``, the lock and
temporary files: args, config, metrics, best and final model, ~0.5 MB) to the driver, which writes
them into its own copy (crash-safe) when they differ. With a filesystem shared by all nodes nothing
is copied; without one the driver still gets every file the table, the figures and a later rerun
need, while checkpoints stay on the node that trained (a run interrupted there resumes only if Ray
schedules it on that node again, otherwise it starts over).

Each training task holds its run's lock (:class:`~containergym_marl.rundir.RunLock`, the one a
``containergym-marl train`` takes) from deciding what to do with the run to the end of the training,
so two sweeps, or a sweep and a ``train``, never write one run at once; it appends one line per
attempt to ``<runs>/.sweep/<run>.log``. Run directories follow :mod:`containergym_marl.rundir`.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, TextIO

try:
    import fcntl
except ImportError:  # not POSIX: no lock between sweeps
    fcntl = None

from containergym_marl import ray_reaper
from containergym_marl.manifest import sha256_bytes
from containergym_marl.rundir import (
    RunError,
    RunLock,
    check_model_file,
    clear_run,
    finished_budget,
    latest_intact_checkpoint,
    measured_rate,
    model_file,
    read_metrics,
    run_args,
    small_files,
    write_files,
)

#: Samples per second per CPU assumed for an ETA before any run has reported (PPO, n = 5 or 11, here).
DEFAULT_RATE = 2_000.0


class SweepError(RuntimeError):
    """The sweep cannot run (no Ray) or some of its tasks failed after Ray's retries; finished runs are kept."""


def ray_missing_message() -> str:
    from containergym_marl.extras import INSTALL

    return ("containergym-marl compare runs its training and evaluation on Ray, which is not installed: "
            f"{INSTALL['sweep']} (./run setup installs it)")


# ---- what a training run is --------------------------------------------------------------------
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

    def train_args(self, resume: bool):
        from containergym_marl.training.runs import TrainArgs

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
    state, start = prepare_run(spec, lock)
    host = socket.gethostname()
    action = {"finished": "finished already", "resume": f"resume from {start} samples", "new": "start"}[state]
    with (spec.sweep_dir / f"{spec.name}.log").open("a") as log:
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
    """One evaluation under the test protocol: a controller (a method of
    :mod:`containergym_marl.methods` with one), or a run's best model (its files come with the task)."""

    key: str  # the evaluation file's stem: <method>_s<seed> or <method>
    method: str
    config: str
    episodes: int
    arbitration: str = "fullest"
    seed: int | None = None


def evaluate_policy(spec: EvalSpec, run: dict[str, Any] | None = None, keep_records: bool = False):
    """Body of an evaluation task; ``run`` holds the run's files (a training task's result or
    ``{"files": {...}}``). Returns the EvaluationResult (records only with ``keep_records``) and the
    sha256 of the evaluated model."""
    import torch

    torch.set_num_threads(1)
    from containergym_marl.config import load_config
    from containergym_marl.evaluation import EvalProtocol, evaluate

    protocol = EvalProtocol(episodes=spec.episodes)
    if run is None:
        from containergym_marl.core.params import PlantParams
        from containergym_marl.methods import get_method

        policy = get_method(spec.method).controller(PlantParams.from_config(load_config(spec.config)))
        model_sha = None
        result = evaluate(policy, spec.config, protocol, arbitration=spec.arbitration, keep_records=keep_records)
    else:
        from containergym_marl.evaluation.runs import evaluated_model, policy_from_run

        files = run["files"]  # evaluation.runs.evaluated_files of the run
        model_sha = sha256_bytes(evaluated_model(files))
        with tempfile.TemporaryDirectory(prefix="cgm-eval-") as tmp:
            write_files(tmp, {k: v for k, v in files.items()
                              if k in ("args.json", "run.json") or k.startswith(("best_model.", "final_model."))})
            policy = policy_from_run(tmp, "best")
            result = evaluate(policy, spec.config, protocol, arbitration=spec.arbitration, keep_records=keep_records)
    return result, model_sha


# ---- the cluster --------------------------------------------------------------------------------
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
        ray.init(address="local", num_cpus=cpus, resources={EVALUATION_SLOTS: cpus}, **opts)
        # the processes this ray.init started, stopped by the reaper if this driver is killed
        self._reaper = ray_reaper.watch(sorted(ray_reaper.child_pids() - before))

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


# ---- progress -----------------------------------------------------------------------------------
def format_duration(seconds: float | None) -> str:
    if seconds is None or seconds != seconds or seconds == float("inf"):
        return "?"
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds}s"
    if seconds < 3600:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"


class Progress:
    """The sweep's live line: runs done / running / left, evaluations, ETA, samples/s per running run.

    On a terminal the line is redrawn in place every second; otherwise it is printed every
    ``interval_s`` seconds. Events (a run finished, resumed, retried, failed) are printed as lines."""

    def __init__(self, budgets: dict[str, int], evaluations: int, cpus: int, stream: TextIO | None = None,
                 interval_s: float = 60.0):
        self.budgets = dict(budgets)  # runs to train in this sweep -> budget
        self.eval_total, self.evals_done = evaluations, 0
        self.cpus = max(cpus, 1)
        self.stream = stream or sys.stdout
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.interval_s = interval_s
        self.running: dict[str, dict] = {}  # run -> {"samples", "rate", "host"}
        self.done: dict[str, dict] = {}
        self.failed: dict[str, str] = {}
        self.attempts: dict[str, int] = {}
        self.t0 = time.perf_counter()
        self._last_print = -float("inf")
        self._width = 0

    # events
    def started(self, name: str, host: str, pid: int, state: str, start: int) -> None:
        self.attempts[name] = self.attempts.get(name, 0) + 1
        if self.attempts[name] > 1:
            self.say(f"retry {name} (attempt {self.attempts[name]}, {state} from {start:,} samples) on {host}")
        elif state == "resume":
            self.say(f"resume {name} from its checkpoint at {start:,} samples")
        self.running[name] = {"samples": start, "rate": None, "host": host, "start": start}

    def sampled(self, name: str, samples: int, rate: float | None) -> None:
        if name in self.running:
            self.running[name].update(samples=samples, rate=rate)

    def run_done(self, name: str, result: dict) -> None:
        self.running.pop(name, None)
        self.done[name] = result
        rate = result.get("samples_per_s")
        how = {"finished": "already finished", "resume": f"resumed from {result['resumed_from']:,}",
               "new": "trained"}[result["state"]]
        self.say(f"done {name}: {how}, {result['samples']:,} samples in {format_duration(result['wall_s'])}"
                 + (f" ({rate:,.0f} samples/s)" if rate else "") + f" on {result['host']}")

    def run_failed(self, name: str, error: str) -> None:
        self.running.pop(name, None)
        self.failed[name] = error
        self.say(f"FAILED {name}: {error}")

    def eval_done(self) -> None:
        self.evals_done += 1

    # rendering
    def rate_per_run(self) -> float | None:
        rates = [r["rate"] for r in self.running.values() if r.get("rate")]
        rates += [d["samples_per_s"] for d in self.done.values() if d.get("samples_per_s")]
        return sum(rates) / len(rates) if rates else None

    def eta_s(self) -> float | None:
        left = [n for n in self.budgets if n not in self.done and n not in self.failed]
        if not left:
            return 0.0
        rate = self.rate_per_run()
        if rate is None:
            return None
        samples = sum(self.budgets[n] - self.running.get(n, {}).get("samples", 0) for n in left)
        return samples / (rate * min(self.cpus, len(left)))

    def line(self) -> str:
        total = len(self.budgets)
        done, running = len(self.done) + len(self.failed), len(self.running)
        parts = [f"[{format_duration(time.perf_counter() - self.t0)}]"]
        if total:
            parts += [f"runs {done}/{total} done, {running} running, {total - done - running} queued"]
        parts += [f"evaluations {self.evals_done}/{self.eval_total}"]
        if total:
            parts += [f"ETA {format_duration(self.eta_s())}"]
        for name, r in sorted(self.running.items()):
            budget = self.budgets.get(name, 0) or 1
            rate = f" {r['rate']:,.0f}/s" if r.get("rate") else ""
            parts.append(f"{name} {100 * r['samples'] / budget:.0f}%{rate}")
        return parts[0] + " " + " · ".join(parts[1:])

    def say(self, text: str) -> None:
        self._clear()
        print(f"  {text}", file=self.stream, flush=True)

    def _clear(self) -> None:
        if self.tty and self._width:
            print("\r" + " " * self._width + "\r", end="", file=self.stream, flush=True)
            self._width = 0

    def tick(self, force: bool = False) -> None:
        now = time.perf_counter()
        if self.tty:
            cols = shutil.get_terminal_size((120, 20)).columns
            text = self.line()[: cols - 1]
            self._clear()
            print(text, end="", file=self.stream, flush=True)
            self._width = len(text)
        elif force or now - self._last_print >= self.interval_s:
            print(self.line(), file=self.stream, flush=True)
            self._last_print = now

    def finish(self) -> None:
        self._clear()
        if not self.tty:
            return
        print(self.line(), file=self.stream, flush=True)


# ---- running a batch of tasks -------------------------------------------------------------------
@dataclass
class Outcome:
    runs: dict[str, dict] = field(default_factory=dict)  # run name -> training task result
    evaluations: dict[tuple[str, str], tuple[Any, str | None]] = field(default_factory=dict)  # (config, key) -> (result, model sha)
    failures: dict[str, str] = field(default_factory=dict)
    attempts: dict[str, int] = field(default_factory=dict)  # run name -> training attempts seen (retries + 1)


def _error_text(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    cause = getattr(exc, "cause", None)
    if cause is not None:
        return f"{type(cause).__name__}: {cause}".splitlines()[0]
    return text[-1] if text else type(exc).__name__


def execute(cluster: Cluster, runs: list[RunSpec], evaluations: list[tuple[EvalSpec, RunSpec | dict | None]],
            keep_records: bool = False, on_run_done: Callable[[RunSpec, dict], None] | None = None,
            on_evaluation_done: Callable[[EvalSpec, Any], None] | None = None,
            stream: TextIO | None = None, interval_s: float = 60.0) -> Outcome:
    """Train ``runs`` and evaluate ``evaluations`` on ``cluster``, with live progress.

    Each evaluation names what it evaluates: a RunSpec of ``runs`` (it waits for that training), a
    ``{"files": {...}}`` dict of a finished run, or None for a rule-based controller. Failures (after
    Ray's retries) are collected, not raised; Ctrl-C propagates (every run stays resumable).
    ``on_run_done`` and ``on_evaluation_done`` are called in the driver as each result lands, so
    an interrupted sweep keeps what finished."""
    ray = cluster.ray()
    outcome = Outcome()
    if not runs and not evaluations:
        return outcome
    events = cluster.events() if runs else None
    by_name = {s.name: s for s in runs}
    pending: dict[Any, tuple[str, Any]] = {}
    train_refs = {}
    sender = EventSender(events.actor) if events is not None else None
    for spec in runs:
        ref = cluster.submit("train", spec, sender)
        train_refs[spec.name] = ref
        pending[ref] = ("train", spec)
    for spec, source in evaluations:
        arg = train_refs[source.name] if isinstance(source, RunSpec) else source
        pending[cluster.submit("evaluate", spec, arg, keep_records)] = ("evaluate", spec)
    progress = Progress({s.name: s.timesteps for s in runs}, len(evaluations), cluster.cpus(), stream, interval_s)
    progress.tick(force=True)
    try:
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=len(pending), timeout=1.0)
            _drain(events, progress)
            # trainings first: an evaluation never lands before the training it depends on
            for ref in sorted(ready, key=lambda r: pending[r][0] != "train"):
                kind, spec = pending.pop(ref)
                try:
                    value = ray.get(ref)
                except Exception as exc:  # RayTaskError, WorkerCrashedError after the retries…
                    label = spec.name if kind == "train" else f"evaluation {spec.config}/{spec.key}"
                    outcome.failures[label] = _error_text(exc)
                    if kind == "train":
                        progress.run_failed(spec.name, outcome.failures[label])
                    else:
                        progress.say(f"FAILED {label}: {outcome.failures[label]}")
                    continue
                if kind == "train":
                    outcome.runs[spec.name] = value
                    if on_run_done:
                        on_run_done(by_name[spec.name], value)
                    progress.run_done(spec.name, value)
                else:
                    outcome.evaluations[(spec.config, spec.key)] = value
                    if on_evaluation_done:
                        on_evaluation_done(spec, value)
                    progress.eval_done()
            progress.tick()
    finally:
        progress.finish()
        outcome.attempts = dict(progress.attempts)
    return outcome


def _drain(events, progress: Progress) -> None:
    if events is None:
        return
    try:
        n = events.qsize()
        items = events.get_nowait_batch(n) if n else []
    except Exception:
        return
    for item in items:
        if item[0] == "start":
            progress.started(*item[1:])
        elif item[0] == "progress":
            progress.sampled(*item[1:])


def estimate_rate(runs_root: str | Path) -> float:
    """Samples/s per run measured by earlier SB3 runs under ``runs_root`` (median), else
    :data:`DEFAULT_RATE`. Runs that compare does not train (MAPPO's, which count plant steps at a
    tenth of the rate) share the folder but say nothing about the sweep's runs."""
    from containergym_marl.algorithms import ALGORITHMS

    def sweep_run(run: Path) -> bool:
        try:
            return run_args(run).get("algo") in ALGORITHMS
        except (FileNotFoundError, RunError, AttributeError):
            return False

    rates = sorted(r for p in Path(runs_root).glob("*/metrics.csv")
                   if sweep_run(p.parent) and (r := measured_rate(p.parent)))
    return rates[len(rates) // 2] if rates else DEFAULT_RATE


__all__ = ["Cluster", "EvalSpec", "Outcome", "Progress", "RunSpec", "SweepError", "check_budget", "estimate_rate",
           "evaluate_policy", "execute", "format_duration", "prepare_run", "train_run"]
