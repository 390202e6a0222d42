"""Sample-efficiency curves: what a run's policy scores on validation episodes as its training goes on.

A run's checkpoints (``checkpoints/ckpt_<S>_steps``) each hold the policy at S samples;
:func:`run_curve` evaluates the newest one at or before each tenth of the budget and the final model with
:func:`~containergym_marl.evaluation.batched.evaluate_batched` on the validation episodes (seeds
20000+, never the test or fresh ones) and writes ``RUN/curve.json``, a small file that travels with
the run when it is published (its checkpoints stay where it trained). :func:`iqm_curve` aggregates
the runs of one method on one plant, as marl-eval and rliable draw them: the IQM over seeds at
each tenth of the budget, with a 95 % bootstrap interval.

The curve also picks the run's **validated model**: of the policies it evaluated, the one with the
highest validation return (the earliest on a tie), copied to ``RUN/validated_model.<ext>`` and named
in curve.json (``"validated"``). It is early stopping on validation episodes, where the best model
(``best_model``) is the policy of the highest 100-episode training return, which on the contended and
δ = 60 s rows often overflows more than the policies before and after it.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from containergym_marl.core.dynamics import DEFAULT_ARBITRATION
from containergym_marl.algorithms import get_algorithm
from containergym_marl.evaluation.batched import evaluate_batched
from containergym_marl.evaluation.protocol import VALIDATION, EvalProtocol
from containergym_marl.evaluation.stats import iqm, stratified_bootstrap_ci
from containergym_marl.files import atomic_write, atomic_write_text
from containergym_marl.rundir import checkpoints, read_run_summary, run_args

CURVE_FILE = "curve.json"
#: Where :func:`iqm_curve` reads every run's curve: each tenth of the budget.
BUDGET_FRACTIONS = tuple(np.round(np.linspace(0.1, 1.0, 10), 2))


def _checkpoint_policy(run: Path, path: Path, algo: str):
    """The evaluation policy of the checkpoint at ``path``: the model a native checkpoint holds
    (tensors only), or an SB3 checkpoint model."""
    spec = get_algorithm(algo)
    if spec.native:
        from containergym_marl.policies.actor_critic import ActorCritic, load_tensors

        data = load_tensors(path)
        model = ActorCritic.from_dict(data.get("model") if isinstance(data, dict) else None, f"checkpoint {path}")
    else:
        from containergym_marl.models import load_model

        model = load_model(path, algo=algo)
    return spec.policy(model, name=f"{algo}[{path.name}]")


def run_curve(run: str | Path, protocol: EvalProtocol = VALIDATION, write: bool = True) -> dict:
    """The checkpoints of a finished run that :func:`curve_at` reads (at each tenth of the budget,
    the newest checkpoint at or before it) and its final model, on ``protocol``'s episodes: a dict
    with the protocol and ``points``, one per policy by samples: ``samples``, ``return_mean``,
    ``overflow_rate``. Written to ``RUN/curve.json`` unless ``write`` is False."""
    from containergym_marl.evaluation.run_policies import policy_from_run

    run = Path(run)
    saved, summary = run_args(run), read_run_summary(run)
    if summary is None:
        raise ValueError(f"{str(run)!r} is not a finished run (no run.json): its curve would stop short")
    budget = int(summary["budget"])
    saved_at = [(steps, path) for steps, path in checkpoints(run) if steps < summary["timesteps"]]
    chosen = {}
    for fraction in BUDGET_FRACTIONS:
        before = [(steps, path) for steps, path in saved_at if steps <= fraction * budget + 1e-9]
        if before:
            steps, path = max(before, key=lambda c: c[0])
            chosen[steps] = path
    policies = [(steps, _checkpoint_policy(run, path, saved["algo"])) for steps, path in sorted(chosen.items())]
    policies.append((int(summary["timesteps"]), policy_from_run(run, "final")))
    points = []
    for steps, policy in policies:
        arbitration = saved.get("arbitration", DEFAULT_ARBITRATION)
        s = evaluate_batched(policy, saved["config"], protocol, arbitration=arbitration).summary()
        points.append({"samples": int(steps), "return_mean": s["return_mean"], "overflow_rate": s["overflow_rate"]})
    curve = {"protocol": asdict(protocol), "budget": int(summary["budget"]), "points": points}
    if write:
        curve = write_validated_model(run, curve)
        atomic_write_text(run / CURVE_FILE, json.dumps(curve, indent=1) + "\n")
    return curve


def validated_point(curve: dict) -> dict:
    """The curve's point of the highest validation return, the earliest on a tie."""
    points = sorted(curve["points"], key=lambda p: p["samples"])
    return max(points, key=lambda p: p["return_mean"])  # max keeps the first of equals


def write_validated_model(run: str | Path, curve: dict) -> dict:
    """Copy the model of ``curve``'s :func:`validated_point` (the checkpoint it evaluated there, or
    the final model at the run's end) to ``RUN/validated_model.<ext>``; returns ``curve`` with
    ``"validated"``: its samples, validation return and the file's SHA-256. A ValueError when that
    checkpoint is gone (a curve is made where the run trained, before its checkpoints are cleared)."""
    import hashlib

    run = Path(run)
    saved, summary = run_args(run), read_run_summary(run)
    spec = get_algorithm(saved["algo"])
    point, target = validated_point(curve), run / spec.model_file("validated")
    at_end = point["samples"] == int(summary["timesteps"])
    source = run / spec.model_file("final") if at_end else dict(checkpoints(run)).get(point["samples"])
    if source is None:
        raise ValueError(f"{str(run)!r}: no checkpoint at {point['samples']} samples for its validated model")
    if spec.native and not at_end:  # a checkpoint holds the optimiser too: its model alone, tensors only
        _checkpoint_policy(run, source, saved["algo"]).model.save(target)
    else:  # a model file already (the final model, or an SB3 checkpoint)
        atomic_write(target, lambda tmp: tmp.write_bytes(source.read_bytes()))
    return {**curve, "validated": {"samples": int(point["samples"]), "return_mean": point["return_mean"],
                                   "model_sha256": hashlib.sha256(target.read_bytes()).hexdigest()}}


def read_curve(run: str | Path) -> dict | None:
    path = Path(run) / CURVE_FILE
    return json.loads(path.read_text()) if path.is_file() else None


def curve_at(curve: dict, fractions=BUDGET_FRACTIONS) -> np.ndarray:
    """A run's validation return at each fraction of its budget: the last policy evaluated at or
    before it (a step function, as the run had nothing newer to offer); nan before the first."""
    points = sorted(curve["points"], key=lambda p: p["samples"])  # whatever order the file lists them in
    samples = np.array([p["samples"] for p in points], dtype=float)
    returns = np.array([p["return_mean"] for p in points])
    out = np.full(len(fractions), np.nan)
    for k, fraction in enumerate(fractions):
        before = np.flatnonzero(samples <= fraction * curve["budget"] + 1e-9)
        if before.size:
            out[k] = returns[before[-1]]
    return out


def iqm_curve(curves: list[dict], fractions=BUDGET_FRACTIONS, reps: int = 2000, rng: int = 0) -> dict:
    """The IQM over runs (seeds) at each fraction of the budget, with its 95 % percentile bootstrap
    interval; fractions where a run has no policy yet are left out (nan)."""
    values = np.array([curve_at(c, fractions) for c in curves])
    point, low, high = (np.full(len(fractions), np.nan) for _ in range(3))
    for k in range(len(fractions)):
        column = values[:, k]
        if np.isnan(column).any():
            continue
        point[k], low[k], high[k] = stratified_bootstrap_ci(column, iqm, reps=reps, rng=rng)
    return {"fractions": list(fractions), "runs": len(curves), "iqm": point.tolist(), "low": low.tolist(),
            "high": high.tolist()}


__all__ = ["BUDGET_FRACTIONS", "CURVE_FILE", "curve_at", "iqm_curve", "read_curve", "run_curve", "validated_point",
           "write_validated_model"]
