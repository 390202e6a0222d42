"""Evaluating run directories: the policy of a run's best or final model, under the test protocol."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

from containergym_marl.core.dynamics import DEFAULT_ARBITRATION
from containergym_marl.algorithms import get_algorithm
from containergym_marl.files import atomic_write_text
from containergym_marl.rundir import MODELS, STANDING_MODELS, read_run_summary, run_args, RunWarning
from containergym_marl.models import load_model


def evaluated_which(run: str | Path) -> str:
    """Which model of a finished run stands for its seed in every comparison, table and shipped file:
    the first of :data:`~containergym_marl.rundir.STANDING_MODELS` it has (its validated model, where
    its curve picked one, else its best model), or "best" (whose policy is the final model where no
    training episode finished)."""
    spec = get_algorithm(run_args(run)["algo"])
    return next((w for w in STANDING_MODELS if (Path(run) / spec.model_file(w)).is_file()), "best")


def evaluated_files(run: str | Path) -> tuple[str, ...]:
    """The files of a finished run that its evaluation reads (``policy_from_run(run,
    evaluated_which(run))``): ``args.json`` and that model, or, when no training episode finished (so
    no best model), ``args.json``, ``run.json`` and the final model (file names from the algorithm's
    registry entry)."""
    spec = get_algorithm(run_args(run)["algo"])
    standing = spec.model_file(evaluated_which(run))
    if (Path(run) / standing).is_file():
        return "args.json", standing
    return "args.json", "run.json", spec.model_file("final")


def evaluated_model(files: dict[str, bytes]) -> bytes:
    """The model among ``files`` (a run's files, e.g. :func:`evaluated_files`) that the evaluation
    uses: the first of :data:`~containergym_marl.rundir.STANDING_MODELS` there, else the final one."""
    spec = get_algorithm(json.loads(files["args.json"])["algo"])
    for which in STANDING_MODELS:
        if spec.model_file(which) in files:
            return files[spec.model_file(which)]
    return files[spec.model_file("final")]


def policy_from_run(run: str | Path, which: str = "best", deterministic: bool = True):
    """The evaluation policy of a run directory (``which`` = "best", "final", or "validated": the
    policy its curve picked on validation episodes, :mod:`~containergym_marl.evaluation.curves`): the model file and
    the policy adapter its algorithm's registry entry names (``best_model.zip`` and an SB3 adapter,
    or ``best_model.pt`` and :class:`~containergym_marl.policies.shared_actor.SharedActorPolicy`
    for a MAPPO run of ``baselines/train_mappo.py``).

    A run in which no training episode finished has no best model (its run.json says so): asking
    for "best" then gives the final model, named so, with a :class:`RunWarning`.
    """
    if which not in MODELS:
        raise ValueError(f"which: expected one of {MODELS}, got {which!r}")
    run = Path(run)
    saved = run_args(run)
    spec = get_algorithm(saved["algo"])
    path, label = run / spec.model_file(which), which
    if which == "validated" and not path.is_file():
        raise ValueError(f"{str(run)!r} has no {path.name}: the run's sample-efficiency curve picks it "
                         f"(compare --curves)")
    if which == "best" and not path.is_file():
        summary = read_run_summary(run)
        if summary is not None and summary.get("best_model") is None:
            final = spec.model_file("final")
            warnings.warn(f"{run}: {summary.get('note') or f'no best model; evaluating {final}'}",
                          RunWarning, stacklevel=2)
            path, label = run / final, "final: no training episode finished"
    model = load_model(path, algo=saved["algo"])
    method = spec.method_name(saved.get("reward_mode"))  # figure titles and evaluation files show it
    return spec.policy(model, name=f"{method}[s{saved['seed']},{label}]", deterministic=deterministic)


def evaluate_run(run: str | Path, config: str | None = None, which: str = "best", protocol=None,
                 arbitration: str | None = None, write: bool = True, on_episode=None):
    """Evaluate a run's model with the paper's test protocol (on its own config by default);
    writes ``RUN/evaluation_<which>.json`` (crash-safe) unless ``write`` is False. ``on_episode``:
    see :func:`~containergym_marl.evaluation.evaluate`. A run whose run.json records its training
    budget (``"training"``, as MAPPO runs do) passes it on to the result, where the table reads it."""
    from containergym_marl.evaluation import PAPER, evaluate

    saved = run_args(run)
    policy = policy_from_run(run, which)
    result = evaluate(policy, config or saved["config"], protocol or PAPER,
                      arbitration=arbitration or saved.get("arbitration", DEFAULT_ARBITRATION), on_episode=on_episode)
    summary = read_run_summary(run) or {}
    if isinstance(summary.get("training"), dict):
        result.training = summary["training"]
    if write:
        atomic_write_text(Path(run) / f"evaluation_{which}.json", result.to_json())
    return result
