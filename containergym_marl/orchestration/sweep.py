"""compare's job graph on Ray: one task per training run, one per evaluation, progress in the driver.

:func:`execute` submits the tasks (:mod:`~containergym_marl.orchestration.tasks`) to a
:class:`~containergym_marl.orchestration.cluster.Cluster`: every training asks for one CPU (torch
runs one thread), so Ray runs as many trainings at once as the cluster has CPUs, on whichever node
has one free; an evaluation takes its training task's result (the run's small files, models
included) as its argument, so Ray starts it when the training ends. Training tasks send events
(started, samples so far) through a ``ray.util.queue.Queue``, which the driver folds into its progress
display (:class:`~containergym_marl.orchestration.sweep_progress.Progress`). Results are handed to the
caller as they land, so an interrupted sweep keeps what finished.

Storage: a training task writes its run directory at the same absolute path on whichever node runs
it. With a filesystem shared by all nodes nothing is copied; without one the driver still gets every
file the table, the figures and a later rerun need (the small files each task returns), while
checkpoints stay on the node that trained (a run interrupted there resumes only if Ray schedules it
on that node again, otherwise it starts over). Run directories follow :mod:`containergym_marl.rundir`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, TextIO

from containergym_marl.orchestration.cluster import Cluster
from containergym_marl.orchestration.sweep_progress import Progress
from containergym_marl.orchestration.tasks import EvalSpec, EventSender, RunSpec


@dataclass
class Outcome:
    """What a sweep's tasks returned: training results and evaluations by key, and the failures."""

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
    try:
        progress.tick(force=True)
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
