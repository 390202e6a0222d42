"""Choosing the native PPO's settings on validation episodes: a recorded Optuna search (issue 34).

    python studies/native_ppo_tuning.py --method fast_shared_ppo --trials 40 --workers 2
    python studies/native_ppo_tuning.py --method fast_shared_ppo --report      # the tables only
    python studies/native_ppo_tuning.py --method fast_ppo --smoke --out /tmp/t  # 2 tiny trials
    python studies/native_ppo_tuning.py --method fast_shared_ppo --write-config  # the best trial's settings
                                                          # into configs/hyperparams/fast_shared_ppo.toml

**What a trial is.** Optuna's TPE sampler proposes one setting of :class:`~containergym_marl.training.fast_ppo.PPOArgs`
(:data:`SPACE`: samples per update, rollout length, minibatch, epochs, step size and its annealing,
entropy bonus, clip range). The trial trains ``--method`` with it at the paper's budget on every
search row (:data:`ROWS`: the four n = 5 rows and n11_m11_dt60) with every search seed
(:data:`SEEDS`, 101-105: no published run uses them), one run after another in the worker's
process (one torch thread), and evaluates each run's best model (the paper's choice: best 100-episode
training return) on the *validation* episodes (δ = 120 s, T = 600, seeds 20000-20029; never the
test seeds 10000-10014 or the fresh ones). A run's score is its validation return as a share of
``rule_based_agents``' on the same episodes; the trial's value is the IQM of its 25 scores.

**Pruning.** Runs go seed by seed (all rows of seed 101, then of 102, …). After each run the trial
reports the mean score so far; from the fourth run on (every n = 5 row seen once) the median rule
(:class:`MedianOfOthersPruner`) stops a trial whose mean is below the median of every other trial that
reached the same run, finished or still running, so a weak setting costs four n = 5 runs rather than
25 even while no trial has finished. The default setting is never stopped: it is every trial's reference.
A setting the sampler proposes again after a trial judged it takes that trial's verdict (state
``(= trial N)`` in the table) without training; each setting counts once in the median. A pruned
setting may have been stopped by noise when close to the median: ``--finalists K`` queues the K
settings (judged on at least the first four runs) that beat the default by most on the runs both did
again as *finalists*, which are never pruned and so are judged on every run, their earlier runs reused. A search can start
from another method's results in the same space: ``--start-from fast_shared_ppo:3`` queues that search's three best
settings (``fast_shared_ppo_team`` and ``fast_ppo`` need not search from scratch); with ``--space wide`` it reads
that method's wide search. They are judged on every run, never pruned (chosen on another method's results,
a setting is not stopped on this method's first four runs), their runs so far reused; on a search under way
it queues only settings no trial has judged in full or waits to, so the same command run again queues nothing
more.

**What is recorded.** Every trial, its settings, state, each run's validation return, overflowing
validation episodes, the validation return of the checkpoint nearest half the budget, and its
CPU seconds, in Optuna's journal (``--out``/<method>/journal.log, append-only, committed) and
in tables generated from it (trials.md, trials.json). The first trial is the package's default
setting (:data:`DEFAULT_TRIAL`), so every other trial is compared with it on the same runs.

**Resumable.** Runs live under ``--runs``/<method>/<settings hash>/; a run a kill interrupted
resumes from its checkpoint, a finished one is reused with its cached validation. A trial a kill
left running is marked failed when the search starts again and its setting is queued anew; its
finished runs are reused, from the journal where their folders are gone (another machine). One search per method at a time (a lock on its folder); the ``--workers``
processes share the journal.

**Regression guards.** ``--guards`` trains the default and every setting judged on every run on
:data:`GUARD_ROWS` (the contended rows, where the published native PPO does well) with the same
seeds, validates them the same way and adds their table to trials.md (``guards.json``). A setting
*passes* them where, on every guard row, the IQM of its runs' shares is at least the default's minus
:data:`GUARD_TOLERANCE`: a chosen setting must not lose there what it gains on the search rows.

**The discount at δ = 60 s.** ``--discount`` trains the best finished trial's setting with γ = 0.995
per decision (:data:`DT60_GAMMA`; or the γ given) on the search's δ = 60 s rows with the same seeds
and sets it beside the same setting's own runs at γ = 0.99 (``discount.json``, a table in trials.md):
γ = 0.99 per 60-s decision halves the horizon in plant time. The result is a labelled variant; the
settings file keeps the paper's γ.

**The agents' own check.** ``--own-check`` trains the best finished trial's setting with the container
agents' own deadline check (ε = 1e-4, a lead of one fill: ``own_check_risk``, ``own_check_lead_steps``
of :class:`~containergym_marl.training.fast_ppo.PPOArgs`) on the search's rows and the guard rows with
the same seeds, beside the same setting's runs without it (the search's and the guards', reused)
(``own_check.json``, a table in trials.md). A labelled variant: the settings file does not take it.

**A heavier overflow in training.** ``--overflow-scale`` trains the best finished trial's setting with the
learner's reward at an overflow 10 × the plant's r_min (``overflow_reward_scale`` of
:class:`~containergym_marl.training.fast_ppo.PPOArgs`: reward shaping; the plant, the best-model criterion
and every validation keep r_min) on the search's rows and the guard rows with the same seeds, beside the
same setting's runs without it (``overflow_scale.json``, a table in trials.md). A labelled variant.

**A wider space.** ``--space wide`` searches :data:`WIDE_SPACE`: the default space with SB3's minibatch of 64
and its 6144 samples per update among the choices (a smaller minibatch costs more CPU per sample, which
the default space kept down). It is a study of its own (``--out``/<method>/wide/: its journal, tables,
comparisons and settings-file choice), whose first trials are the default, the first search's settings
judged on every run (their runs and guard runs reused, nothing trained again) and SB3's update shape
(:data:`SB3_SHAPE_TRIAL`), all judged on every run; the other options work on it as on the first search.

**What is chosen.** ``--write-config`` writes the settings of the best finished trial (highest value)
that passes the regression guards (every finished trial's guards must have run; before any guard has
run, the best finished trial, and the file says so) as the method's settings file. With ``--by-size``
it writes settings per plant size instead: for the plants of fewer than :data:`LARGE_PLANTS` containers
the finished setting of highest IQM share over its runs on the search rows of that size, and for the
larger plants (a ``[[by_size]]`` entry) the one of highest IQM share over its runs on the larger search
rows and its guard runs. The file, ``configs/hyperparams/<method>.toml``, is what ``train`` and
``compare`` read (:mod:`containergym_marl.config.hyperparams`).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import multiprocessing
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from containergym_marl.config import load_config
from containergym_marl.core.params import PlantParams
from containergym_marl.evaluation import evaluate
from containergym_marl.evaluation.protocol import VALIDATION
from containergym_marl.evaluation.stats import iqm
from containergym_marl.config.bounds import MAX_OVERFLOW_REWARD_SCALE
from containergym_marl.config.hyperparams import settings_file, write_settings
from containergym_marl.files import atomic_write_text
from containergym_marl.methods import get_method
from containergym_marl.policies import RuleBasedAgents
from containergym_marl.policies.safety import OWN_CHECK_LEAD_STEPS, OWN_CHECK_RISK  # --own-check's default
from containergym_marl.rundir import RunLock, checkpoints, read_run_summary, run_name, run_status

REPO = Path(__file__).resolve().parents[1]
#: The rows every trial trains on: where the native PPO fell furthest below SB3's (issue 34).
ROWS = ("n5_m2_dt60", "n5_m2_dt120", "n5_m5_dt60", "n5_m5_dt120", "n11_m11_dt60")
#: Training seeds of the search; the published runs use 1-15.
SEEDS = (101, 102, 103, 104, 105)
#: The regression guards: the contended rows, where the published native PPO does well, on which the
#: chosen setting is checked against the default with the same seeds (``--guards``).
GUARD_ROWS = ("n11_m2_dt120", "n16_m2_dt120")
#: A setting passes the guards where, on every guard row, the IQM of its runs' shares of rule_based_agents'
#: validation return is at least the default's minus this: about the spread of a 5-seed IQM there.
GUARD_TOLERANCE = 0.05
#: ``--write-config --by-size``: settings of their own for the plants of at least this many containers
#: (the search's n11_m11_dt60 and the guard rows), chosen on those runs alone.
LARGE_PLANTS = 11
#: The discount every trial trains with (the paper's, per decision), and the labelled variant for δ = 60 s:
#: 0.995 per decision of 60 s is about 0.99 per 120 s, the horizon in plant time of the δ = 120 s rows.
GAMMA, DT60_GAMMA = 0.99, 0.995
#: --overflow-scale's default: the learner's reward at an overflow 10 × r_min
OVERFLOW_SCALE = 10.0
#: Runs before the pruner may stop a trial: every n = 5 row of the first seed.
WARMUP_RUNS = 4
#: The searched settings: a list of choices, or (low, high) for a log-uniform float.
SPACE: dict[str, Any] = {
    "rollout_samples": [2048, 4096, 8192, 16384],
    "n_steps": [32, 64, 128, 256],
    "minibatch_size": [256, 512, 1024, 2048],
    "n_epochs": [3, 5, 10, 20],
    "learning_rate": (5e-5, 2e-3),
    "anneal_lr": [False, True],
    "ent_coef": [0.0, 1e-4, 1e-3, 3e-3, 1e-2],
    "clip_range": [0.1, 0.2, 0.3],
}
#: ``--space wide``: :data:`SPACE` with SB3's minibatch of 64 and its 6144 samples per update among the
#: choices. The first search kept minibatches of at least 256 for speed (the update's cost per sample
#: grows as its minibatch shrinks), and so never tried the shape SB3's paper runs learn with: 960
#: gradient steps per 6144 samples where its settings took 20-80 per 4096.
WIDE_SPACE: dict[str, Any] = {**SPACE, "rollout_samples": [2048, 4096, 6144, 8192, 16384],
                              "minibatch_size": [64, 128, 256, 512, 1024, 2048]}
SPACES = {"default": SPACE, "wide": WIDE_SPACE}
#: The first trial of every search: the package's defaults (PPOArgs), stated in full.
DEFAULT_TRIAL = {"rollout_samples": 4096, "n_steps": 64, "minibatch_size": 1024, "n_epochs": 10,
                 "learning_rate": 3e-4, "anneal_lr": False, "ent_coef": 0.0, "clip_range": 0.2}
#: The wide search's first trial after the default and the first search's finished settings: SB3's update
#: shape at the paper's settings (about 6144 samples per update, minibatches of 64, 10 epochs, SB3's step
#: size), the rollout 128 steps long (SB3's shared runs: 152 steps of 8 simulations).
SB3_SHAPE_TRIAL = {"rollout_samples": 6144, "n_steps": 128, "minibatch_size": 64, "n_epochs": 10,
                   "learning_rate": 3e-4, "anneal_lr": False, "ent_coef": 0.0, "clip_range": 0.2}


def require_optuna():
    try:
        import optuna
    except ImportError as exc:
        raise SystemExit("the search needs Optuna: pip install -e '.[tune]' -c constraints.txt") from exc
    return optuna


def suggest(trial, space: dict[str, Any] = SPACE) -> dict[str, Any]:
    """The trial's settings, drawn from ``space`` (:data:`SPACE` or :data:`WIDE_SPACE`)."""
    hp = {}
    for name, choices in space.items():
        if isinstance(choices, tuple):
            hp[name] = trial.suggest_float(name, *choices, log=True)
        else:
            hp[name] = trial.suggest_categorical(name, choices)
    return hp


def settings_key(hp: dict[str, Any]) -> str:
    """A short name for a setting (its runs' folder): the same setting always gets the same one."""
    return hashlib.sha256(json.dumps(hp, sort_keys=True).encode()).hexdigest()[:12]


def trial_settings(trial) -> dict[str, Any]:
    """A trial's setting: its parameters, or Optuna's fixed parameters while it is queued (or was killed
    before its first suggestion)."""
    return dict(trial.params or trial.system_attrs.get("fixed_params", {}))


def never_pruned(trial) -> bool:
    """The default, finalists and settings queued to be judged in full: judged on every run (never
    pruned, nor given an earlier trial's verdict)."""
    return any(trial.user_attrs.get(k) for k in ("default", "finalist", "in_full"))


def rule_returns(rows, cache: Path) -> dict[str, float]:
    """``rule_based_agents``' mean validation return per row (the scores' unit), cached in ``cache``."""
    known = json.loads(cache.read_text()) if cache.is_file() else {}
    for row in rows:
        if row not in known:
            policy = RuleBasedAgents(PlantParams.from_config(VALIDATION.plant(row)))
            known[row] = float(evaluate(policy, row, VALIDATION, keep_records=False).returns.mean())
            atomic_write_text(cache, json.dumps(known, indent=1, sort_keys=True) + "\n")
    return known


def _validation(policy, row: str) -> tuple[float, int]:
    result = evaluate(policy, row, VALIDATION, keep_records=False)
    return float(result.returns.mean()), int(sum(e.overflow for e in result.episodes))


def recorded_runs(study) -> dict[tuple[str, str, int], dict[str, Any]]:
    """Every run the journal records, by (settings key, row, seed): a trial queued again on another
    machine (where the runs' folders are gone) takes them from there instead of training again."""
    known = {}
    for t in study.get_trials(deepcopy=False):
        folder = t.user_attrs.get("folder")
        for name, entry in t.user_attrs.items():
            if folder and name.startswith("run_"):
                known[(folder, entry["row"], entry["seed"])] = entry
    return known


def train_and_validate(method: str, row: str, seed: int, hp: dict[str, Any], run: Path,
                       timesteps: int | None, gamma: float = GAMMA) -> dict[str, Any]:
    """Train (or resume, or reuse) one run, discounting by ``gamma``, and evaluate its best model,
    and the checkpoint nearest half its budget, on the validation episodes; cached in
    ``run``/validation.json."""
    from containergym_marl.evaluation.run_policies import policy_from_run
    from containergym_marl.policies.actor_critic import policy_for
    from containergym_marl.training import TrainArgs, train
    from containergym_marl.training.fast_ppo import PPOArgs, load_checkpoint

    cached = run / "validation.json"
    if cached.is_file():
        return json.loads(cached.read_text())
    spec = get_method(method)
    cpu_file = run / "cpu_time_s.txt"  # CPU seconds of earlier, interrupted attempts
    cpu = float(cpu_file.read_text()) if cpu_file.is_file() else 0.0
    status = run_status(run)
    if status != "finished":
        start = time.process_time()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # a resume's notes
                train(TrainArgs(algo=spec.algo, config=row, seed=seed, out=str(run), timesteps=timesteps,
                                resume=status == "interrupted", hyperparams=dict(hp), progress_bar=False, gamma=gamma,
                                **spec.train_settings()))
        finally:
            cpu += time.process_time() - start
            atomic_write_text(cpu_file, f"{cpu:.1f}\n")
    summary = read_run_summary(run)
    val_return, overflows = _validation(policy_from_run(run), row)
    half = summary["budget"] / 2
    steps, path = min(checkpoints(run), key=lambda c: abs(c[0] - half), default=(None, None))
    half_return = math.nan
    if path is not None:
        half_return, _ = _validation(policy_for(load_checkpoint(path, PPOArgs.from_hyperparams(hp)).model), row)
    entry = {"row": row, "seed": seed, "validation_return": val_return, "overflowing_episodes": overflows,
             "half_budget_samples": steps, "half_budget_return": half_return, "samples": summary["timesteps"],
             "cpu_s": round(cpu, 1), "wall_time_s": summary["wall_time_s"]}
    atomic_write_text(cached, json.dumps(entry) + "\n")
    return entry


class Objective:
    def __init__(self, method: str, runs: Path, rows, seeds, rule: dict[str, float], timesteps: int | None,
                 known: dict[tuple[str, str, int], dict[str, Any]], space: dict[str, Any] = SPACE):
        self.method, self.runs, self.rows, self.seeds = method, runs, tuple(rows), tuple(seeds)
        self.rule, self.timesteps, self.known, self.space = rule, timesteps, known, space

    def __call__(self, trial) -> float:
        optuna = require_optuna()
        hp = suggest(trial, self.space)
        # TPE proposes a setting of this discrete space again now and then: a setting already judged
        # takes the earlier trial's verdict, training nothing (a duplicate is not a new trial's evidence)
        finished = (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED)
        twin = next((t for t in trial.study.get_trials(deepcopy=False, states=finished) if t.params == trial.params),
                    None)
        if twin is not None and not never_pruned(trial):
            trial.set_user_attr("duplicate_of", twin.number)
            if twin.state == optuna.trial.TrialState.PRUNED:
                raise optuna.TrialPruned()
            return twin.value
        folder = self.runs / settings_key(hp)
        trial.set_user_attr("folder", folder.name)
        scores = []
        for k, (seed, row) in enumerate((s, r) for s in self.seeds for r in self.rows):
            entry = self.known.get((folder.name, row, seed)) or train_and_validate(
                self.method, row, seed, hp, folder / run_name(self.method, row, seed), self.timesteps)
            entry["score"] = entry["validation_return"] / self.rule[row]
            entry["half_budget_score"] = entry["half_budget_return"] / self.rule[row]
            trial.set_user_attr(f"run_{k:02d}", entry)
            scores.append(entry["score"])
            trial.report(float(np.mean(scores)), k)
            if k + 1 >= WARMUP_RUNS and k + 1 < len(self.rows) * len(self.seeds) and trial.should_prune():
                raise optuna.TrialPruned()
        return iqm(scores)


def pruner():
    """:class:`MedianOfOthersPruner` as an Optuna pruner (Optuna is imported only when a search runs)."""
    optuna = require_optuna()

    class MedianOfOthersPruner(optuna.pruners.BasePruner):
        """Optuna's median rule, with every other trial that reached the same run as a reference (a
        running one too: Optuna's MedianPruner waits for finished trials, hours of runs each here)."""

        def prune(self, study, trial) -> bool:
            step = trial.last_step
            if step is None or step + 1 < WARMUP_RUNS or never_pruned(trial):
                return False
            # one value per other setting: a setting tried again (queued after a kill, a finalist)
            # reuses its runs, and counting each of its trials would make it the median
            others = {settings_key(t.params): t.intermediate_values[step]
                      for t in study.get_trials(deepcopy=False)
                      if t.params != trial.params and step in t.intermediate_values}
            return bool(others) and trial.intermediate_values[step] < float(np.median(list(others.values())))

    return MedianOfOthersPruner()


def run_workers(procs) -> None:
    """Start the search's processes and wait for them; however this ends (run as a script, a SIGTERM exits
    as Ctrl-C does: :mod:`containergym_marl.orchestration.stopping`), the ones still running are stopped
    first. The search's lock is held until then, so a search started again never runs beside a killed
    one's processes (they would fail the trials it queued again)."""
    try:
        for proc in procs:
            proc.start()
            time.sleep(1)  # the first takes the queued trial before the next asks
        for proc in procs:
            proc.join()
    finally:
        for proc in procs:
            if proc.pid is not None and proc.is_alive():
                proc.terminate()
                proc.join()



def open_study(method: str, journal: Path, sampler_seed: int, read_only: bool = False):
    """The search's study in ``journal``; ``read_only``: an existing study, opened without appending to
    its journal (``create_study`` appends a line at every opening)."""
    optuna = require_optuna()
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = JournalStorage(JournalFileBackend(str(journal)))
    if read_only:
        return optuna.load_study(study_name=method, storage=storage)
    sampler = optuna.samplers.TPESampler(seed=sampler_seed, n_startup_trials=8)
    return optuna.create_study(study_name=method, storage=storage, sampler=sampler, pruner=pruner(),
                               direction="maximize", load_if_exists=True)


def _worker(method: str, journal: str, runs: str, rows, seeds, rule, timesteps, total: int, space: str,
            reused: dict, index: int) -> None:
    """One search process; ``reused``: a wide search's runs of the first search (judged again without training)."""
    optuna = require_optuna()
    study = open_study(method, Path(journal), sampler_seed=index)
    done = (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED)
    known = {**reused, **recorded_runs(study)}
    study.optimize(Objective(method, Path(runs), rows, seeds, rule, timesteps, known, SPACES[space]),
                   callbacks=[optuna.study.MaxTrialsCallback(total, states=done)])


def enqueue_finalists(study, count: int, min_runs: int) -> list[int]:
    """Make ``count`` finalists in all: queue the settings with the largest advantage over the default
    setting (their mean score minus the default's on the same runs: a setting pruned on the easy n = 5
    runs is not ranked against another's mean over harder ones) over at least ``min_runs`` runs that
    no trial has finished all runs of, as finalists: the pruner never stops them, so each is judged on
    every run, as the default is (a setting pruned by a hair at a few runs gets its full comparison).
    Their runs so far are reused. Finalists queued, running or finished already count, so the same
    command run again after an interruption queues none more. Returns the numbers of the trials the
    new finalists come from."""
    optuna = require_optuna()
    alive = (optuna.trial.TrialState.WAITING, optuna.trial.TrialState.RUNNING, optuna.trial.TrialState.COMPLETE)
    count -= len({settings_key(trial_settings(t))
                  for t in study.get_trials(deepcopy=False) if t.user_attrs.get("finalist") and t.state in alive})
    if count <= 0:
        return []
    complete = {settings_key(t.params) for t in study.get_trials(deepcopy=False)
                if t.state == optuna.trial.TrialState.COMPLETE}
    queued = {settings_key(trial_settings(t))
              for t in study.get_trials(deepcopy=False)
              if t.state in (optuna.trial.TrialState.WAITING, optuna.trial.TrialState.RUNNING)}
    best: dict[str, Any] = {}
    rows = trial_rows(study)
    for row in rows:
        key = settings_key(row["params"])
        if key in complete or key in queued or len(row["runs"]) < min_runs:
            continue
        if key not in best or len(row["runs"]) > len(best[key]["runs"]):
            best[key] = row
    reference = max((r for r in rows if r["params"] == DEFAULT_TRIAL), key=lambda r: len(r["runs"]), default=None)
    chosen = sorted(best.values(), key=lambda r: advantage(r, reference), reverse=True)[:count]
    for row in chosen:
        study.enqueue_trial(row["params"], user_attrs={"finalist": True, "finalist_of": row["number"]})
    return [row["number"] for row in chosen]


def advantage(row: dict[str, Any], reference: dict[str, Any] | None) -> float:
    """``row``'s mean score minus ``reference``'s over the runs (row, seed) both have; its mean score
    where there is no reference or no run in common."""
    theirs = {(r["row"], r["seed"]): r["score"] for r in reference["runs"]} if reference else {}
    paired = [r["score"] - theirs[r["row"], r["seed"]] for r in row["runs"] if (r["row"], r["seed"]) in theirs]
    return float(np.mean(paired)) if paired else row["mean_score"]


def best_settings(study, count: int, min_runs: int) -> list[tuple[int, dict[str, Any]]]:
    """The ``count`` best distinct settings of a search, (trial number, settings): finished trials by
    their IQM first, then the others by their mean score over at least ``min_runs`` runs."""
    optuna = require_optuna()
    ranked = []
    for row in trial_rows(study):
        if row["state"] == optuna.trial.TrialState.COMPLETE.name:
            ranked.append(((1, row["value"]), row))
        elif len(row["runs"]) >= min_runs:
            ranked.append(((0, row["mean_score"]), row))
    out, seen = [], set()
    for _, row in sorted(ranked, key=lambda r: r[0], reverse=True):
        key = settings_key(row["params"])
        if key not in seen:
            seen.add(key)
            out.append((row["number"], dict(row["params"])))
    return out[:count]


def requeue_interrupted(study) -> int:
    """Trials a kill left running: failed, and their settings queued again (their runs are reused)."""
    optuna = require_optuna()
    stale = [t for t in study.get_trials(deepcopy=False) if t.state == optuna.trial.TrialState.RUNNING]
    for t in stale:
        study._storage.set_trial_state_values(t._trial_id, optuna.trial.TrialState.FAIL)
        attrs = {"requeued_from": t.number,
                 **{k: t.user_attrs[k] for k in ("default", "finalist", "finalist_of", "in_full", "start_from")
                    if k in t.user_attrs}}
        study.enqueue_trial(trial_settings(t), user_attrs=attrs)
    return len(stale)


# ---- the tables -------------------------------------------------------------------------------------
def trial_rows(study) -> list[dict[str, Any]]:
    """One dict per trial: number, state, settings, value, the runs' entries and their totals."""
    out = []
    for t in study.get_trials(deepcopy=False):
        runs = [v for k, v in sorted(t.user_attrs.items()) if k.startswith("run_")]
        out.append({"number": t.number, "state": t.state.name, "duplicate_of": t.user_attrs.get("duplicate_of"),
                    "finalist_of": t.user_attrs.get("finalist_of"), "start_from": t.user_attrs.get("start_from"),
                    "params": trial_settings(t), "value": t.value,
                    "runs": runs, "mean_score": float(np.mean([r["score"] for r in runs])) if runs else None,
                    "overflowing_episodes": sum(r["overflowing_episodes"] for r in runs),
                    "half_budget_score": _nanmean([r["half_budget_score"] for r in runs]),
                    "cpu_s": sum(r["cpu_s"] for r in runs)})
    return out


def _nanmean(values) -> float | None:
    values = [v for v in values if not math.isnan(v)]
    return float(np.mean(values)) if values else None


def best_trial(study, option: str):
    """The finished trial with the highest value; a ValueError naming ``option`` when none has finished."""
    optuna = require_optuna()
    done = [t for t in study.get_trials(deepcopy=False) if t.state == optuna.trial.TrialState.COMPLETE]
    if not done:
        raise ValueError(f"{option}: no trial has finished yet")
    return max(done, key=lambda t: t.value)


def finished_settings(study, option: str) -> list:
    """The finished trials, best value first, one per setting (the best of a setting's trials); a
    ValueError naming ``option`` when none has finished."""
    best_trial(study, option)
    optuna = require_optuna()
    done = [t for t in study.get_trials(deepcopy=False) if t.state == optuna.trial.TrialState.COMPLETE]
    out, seen = [], set()
    for t in sorted(done, key=lambda t: (-t.value, t.number)):
        if settings_key(t.params) not in seen:
            seen.add(settings_key(t.params))
            out.append(t)
    return out


def guard_label(trial) -> str:
    return "default" if trial.params == DEFAULT_TRIAL else f"trial {trial.number}"


def guard_settings(study) -> list[tuple[str, dict[str, Any], float]]:
    """(label, settings, γ) the guards compare: the default, then every setting judged on every run,
    best first."""
    chosen = [("default", dict(DEFAULT_TRIAL), GAMMA)]
    chosen += [(guard_label(t), dict(t.params), GAMMA) for t in finished_settings(study, "--guards")
               if t.params != DEFAULT_TRIAL]
    return chosen


def guard_entry(guards: dict[str, Any], params: dict[str, Any]) -> dict[str, Any] | None:
    """The entry of ``params`` at the search's γ in ``guards`` (guards.json; one of an earlier version
    names no γ: its runs are at the search's), or None."""
    return next((entry for entry in guards["settings"].values()
                 if settings_key(entry["params"]) == settings_key(params) and entry.get("gamma", GAMMA) == GAMMA),
                None)


def guard_verdict(guards: dict[str, Any], params: dict[str, Any]) -> tuple[bool, list[str]] | None:
    """Whether ``params`` passes the regression guards of ``guards`` (guards.json), with the reason for
    each guard row it fails ("n16_m2_dt120: IQM share 0.808 < the default's 0.986 - 0.05"); None where
    the setting or the default lacks a run of some guard row and seed."""
    def shares(hp) -> dict[str, list[float]] | None:
        entry = guard_entry(guards, hp)
        if entry is None:
            return None
        got = {row: [e["score"] for e in entry["runs"] if e["row"] == row] for row in guards["rows"]}
        return got if all(len(v) == len(guards["seeds"]) for v in got.values()) else None

    mine, default = shares(params), shares(DEFAULT_TRIAL)
    if mine is None or default is None:
        return None
    failed = [f"{row}: IQM share {iqm(mine[row]):.3f} < the default's {iqm(default[row]):.3f} - {GUARD_TOLERANCE}"
              for row in guards["rows"] if iqm(mine[row]) < iqm(default[row]) - GUARD_TOLERANCE]
    return not failed, failed


def discount_settings(study, gamma: float) -> list[tuple[str, dict[str, Any], float]]:
    """(label, settings, γ) of the discount variant: the best finished trial's setting with the
    search's γ and with ``gamma``."""
    best = best_trial(study, "--discount")
    return [(f"trial {best.number}, γ = {GAMMA}", dict(best.params), GAMMA),
            (f"trial {best.number}, γ = {gamma}", dict(best.params), gamma)]


def own_check_settings(study, risk: float) -> list[tuple[str, dict[str, Any], float]]:
    """(label, settings, γ) of the own-check variant: the best finished trial's setting, and the same
    with the container agents' own check (ε = ``risk``, a lead of :data:`OWN_CHECK_LEAD_STEPS` fill)."""
    best = best_trial(study, "--own-check")
    return [(f"trial {best.number}", dict(best.params), GAMMA),
            (f"trial {best.number}, own check ε = {risk:g}",
             {**best.params, "own_check_risk": risk, "own_check_lead_steps": OWN_CHECK_LEAD_STEPS}, GAMMA)]


def overflow_scale_settings(study, scale: float) -> list[tuple[str, dict[str, Any], float]]:
    """(label, settings, γ) of the overflow variant: the best finished trial's setting, and the same with
    the learner's reward at an overflow ``scale`` × r_min."""
    best = best_trial(study, "--overflow-scale")
    return [(f"trial {best.number}", dict(best.params), GAMMA),
            (f"trial {best.number}, overflow reward × {scale:g}", {**best.params, "overflow_reward_scale": scale},
             GAMMA)]


def comparison_folder(hp: dict[str, Any], gamma: float) -> str:
    """The runs' folder of a setting trained with ``gamma`` (the search's own for its γ)."""
    return settings_key(hp if gamma == GAMMA else {**hp, "gamma": gamma})


def _comparison_task(task: tuple) -> tuple[str, dict[str, Any]]:
    """One run of a comparison: (method, runs folder, label, settings, γ, row, seed, timesteps) -> (label, its entry)."""
    method, runs, label, hp, gamma, row, seed, timesteps = task
    run = Path(runs) / comparison_folder(hp, gamma) / run_name(method, row, seed)
    return label, train_and_validate(method, row, seed, hp, run, timesteps, gamma)


def run_comparison(method: str, settings, runs: Path, path: Path, rows, seeds, timesteps: int | None,
                   workers: int, rule: dict[str, float], known: dict) -> dict:
    """Train and validate each (label, settings, γ) of ``settings`` on ``rows`` with ``seeds``
    (resumable: finished runs are reused, from the journal (``known``) where the search ran them, and
    from ``path`` as an earlier call wrote it, where their folders are gone), on ``workers``
    processes; writes ``path`` (JSON) after every run."""
    result = {"rows": list(rows), "seeds": list(seeds), "rule_based_agents_validation_return": rule,
              "settings": {label: {"params": hp, "gamma": gamma, "runs": []} for label, hp, gamma in settings}}
    # an earlier call's runs, and the other comparisons' (the comparisons' own runs are not in the journal)
    known = {**comparison_runs(path.parent, first=path), **known}

    def record(label, entry):
        entry = {**entry, "score": entry["validation_return"] / rule[entry["row"]]}
        result["settings"][label]["runs"].append(entry)
        result["settings"][label]["runs"].sort(key=lambda e: (e["seed"], e["row"]))
        atomic_write_text(path, json.dumps(result, indent=1) + "\n")

    tasks = []
    for label, hp, gamma in settings:
        for seed in seeds:
            for row in rows:
                entry = known.get((comparison_folder(hp, gamma), row, seed))
                if entry is not None:
                    record(label, {k: v for k, v in entry.items() if k not in ("score", "half_budget_score")})
                else:
                    tasks.append((method, str(runs), label, hp, gamma, row, seed, timesteps))
    if tasks:
        ctx = multiprocessing.get_context("spawn")
        with ctx.Pool(max(workers, 1), maxtasksperchild=1) as pool:
            for label, entry in pool.imap_unordered(_comparison_task, tasks):
                record(label, entry)
    return result


def comparison_runs(folder: Path, first: Path | None = None) -> dict[tuple[str, str, int], dict[str, Any]]:
    """The runs the comparison files in ``folder`` record (guards.json, discount.json, own_check.json;
    ``first``'s entry kept where two record the same run), by (runs folder, row, seed)."""
    known: dict[tuple[str, str, int], dict[str, Any]] = {}
    files = [first] if first is not None else []
    for other in files + [folder / f for f, _, _ in COMPARISONS.values() if folder / f != first]:
        if not other.is_file():
            continue
        for earlier in json.loads(other.read_text())["settings"].values():
            for entry in earlier["runs"]:
                # guards.json of an earlier version names no γ: its runs are at the search's
                key = (comparison_folder(earlier["params"], earlier.get("gamma", GAMMA)), entry["row"], entry["seed"])
                known.setdefault(key, entry)
    return known


#: The comparisons beside the search: option, file, title, what the table says it is
COMPARISONS = {
    "guards": ("guards.json", "Regression guards",
               "The default and every setting judged on every run, on {rows} with seeds {seeds} at the paper's "
               "budget, scored as above (`--guards`)."),
    "discount": ("discount.json", "Discount for δ = 60 s (a labelled variant)",
                 "The chosen setting on the search's δ = 60 s rows ({rows}) with seeds {seeds}, with the search's "
                 "γ and with γ per decision that keeps the δ = 120 s horizon in plant time (`--discount`); its "
                 "γ = 0.99 runs are the search's own. A variant to cite as such, never a silent default."),
    "own_check": ("own_check.json", "The container agents' own check (a labelled variant)",
                  "The best finished trial's setting on {rows} with seeds {seeds}, without and with the container "
                  "agents' own deadline check (`--own-check`: in training, where the environment executes a request "
                  "wherever an agent's own observation is due, and in every evaluation); its runs without are the "
                  "search's and the guards' own. A variant to cite as such."),
    "overflow_scale": ("overflow_scale.json", "A heavier overflow in training (a labelled variant)",
                       "The best finished trial's setting on {rows} with seeds {seeds}, with the plant's reward and "
                       "with the learner's reward at an overflow a multiple of r_min (`--overflow-scale`: reward "
                       "shaping in training; the best model is chosen and validated on the plant's reward); its runs "
                       "with the plant's reward are the search's and the guards' own. A variant to cite as such."),
}


def comparison_report(out: Path, which: str) -> str:
    """A comparison's table (``out``/guards.json or discount.json), or "" when it has not run."""
    filename, title, text = COMPARISONS[which]
    path = out / filename
    if not path.is_file():
        return ""
    data = json.loads(path.read_text())
    lines = ["", f"## {title}", "",
             text.format(rows=", ".join(data["rows"]), seeds=f"{data['seeds'][0]}-{data['seeds'][-1]}"), "",
             "| setting | row | runs | IQM share | mean share | half budget | overflowing episodes |",
             "|---|---|---|---|---|---|---|"]
    for label, entry in data["settings"].items():
        for row in data["rows"]:
            runs = [e for e in entry["runs"] if e["row"] == row]
            if not runs:
                continue
            scores = [e["score"] for e in runs]
            half = _nanmean([e["half_budget_return"] / data["rule_based_agents_validation_return"][row] for e in runs])
            lines.append(f"| {label} | {row} | {len(runs)} | {iqm(scores):.3f} | {np.mean(scores):.3f} | "
                         f"{'–' if half is None else f'{half:.3f}'} | "
                         f"{sum(e['overflowing_episodes'] for e in runs)} |")
    if which == "guards":
        verdicts = {label: guard_verdict(data, entry["params"]) for label, entry in data["settings"].items()
                    if label != "default"}
        lines += ["", f"A setting passes where its IQM share on every guard row is at least the default's - "
                      f"{GUARD_TOLERANCE}: " + "; ".join(
                          f"{label} " + ("has not run on every guard row and seed" if v is None else
                                         "passes" if v[0] else "fails (" + ", ".join(v[1]) + ")")
                          for label, v in verdicts.items()) + "."]
    return "\n".join(lines) + "\n"


def report(method: str, study, out: Path, rule: dict[str, float], space: str = "default",
           reused: dict | None = None) -> str:
    """Write ``out``/trials.json and trials.md from the journal; ``reused``: a wide search's runs of the
    first search (their CPU time counts in the first search's, not twice)."""
    rows = trial_rows(study)
    # a run reused by a trial queued again (the same setting), or from the first search, is counted once
    reused = reused or {}
    cpu_h = sum(entry["cpu_s"] for key, entry in recorded_runs(study).items() if key not in reused) / 3600
    data = {"method": method, "rows": list(ROWS), "seeds": list(SEEDS), "validation_seeds": VALIDATION.seeds,
            "rule_based_agents_validation_return": rule, "space_name": space,
            "space": {k: list(v) for k, v in SPACES[space].items()}, "core_hours": round(cpu_h, 2), "trials": rows}
    atomic_write_text(out / "trials.json", json.dumps(data, indent=1) + "\n")
    names = list(SPACES[space])
    option = "" if space == "default" else f" --space {space}"
    wide = ("" if space == "default" else
            " The wide search: the first search's space with minibatches down to SB3's 64 and SB3's 6144 samples "
            "per update among the choices; its first trials are the default, the first search's settings judged "
            "on every run (their runs reused, not trained again: their CPU time counts in the first search's) and "
            "SB3's update shape.")
    lines = [f"# `{method}`: the native PPO's settings searched on validation episodes"
             + ("" if space == "default" else f" ({space} space)"), "",
             f"Generated by `python studies/native_ppo_tuning.py --method {method}{option} --report` from the Optuna "
             f"journal beside it.{wide} Each trial trains on {', '.join(ROWS)} with seeds {SEEDS[0]}-{SEEDS[-1]} at the "
             f"paper's budget and scores each run's best model on validation episodes {VALIDATION.first_seed}-"
             f"{VALIDATION.seeds[-1]} (δ = 120 s, T = 600) as a share of rule_based_agents' return there; the "
             f"value is the IQM of the shares (pruned trials: the mean of the runs done). Half budget: the "
             f"same share for the checkpoint nearest half the budget. Compute so far: {cpu_h:.1f} core-hours "
             f"(CPU time of the training runs, one core each).", "",
             "| trial | state | " + " | ".join(names) + " | runs | value | mean share | half budget "
             "| overflowing episodes | CPU h of its runs |",
             "|" + "---|" * (len(names) + 8)]
    # a trial a kill stopped is failed and its setting queued again: its row says which trial took it on
    successor = {t.user_attrs["requeued_from"]: t.number for t in study.get_trials(deepcopy=False)
                 if "requeued_from" in t.user_attrs}
    for r in rows:
        if r["state"] == "FAIL" and r["number"] in successor:
            r["state"] = f"interrupted (queued again as trial {successor[r['number']]})"
    ranked = sorted(rows, key=lambda r: (r["state"] != "COMPLETE", -(r["value"] if r["value"] is not None else -1e9)))
    for r in ranked:
        cells = [_cell(r["params"].get(n)) for n in names]
        fmt = lambda x: "–" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.3f}"  # noqa: E731
        state = r["state"].lower() + ("" if r["duplicate_of"] is None else f" (= trial {r['duplicate_of']})")
        if r.get("finalist_of") is not None:
            state += f" (finalist: trial {r['finalist_of']}'s setting, never pruned)"
        if r.get("start_from"):
            state += f" ({r['start_from']})"
        lines.append(f"| {r['number']} | {state} | " + " | ".join(cells) +
                     f" | {len(r['runs'])} | {fmt(r['value'])} | {fmt(r['mean_score'])} | "
                     f"{fmt(r['half_budget_score'])} | {r['overflowing_episodes']} | {r['cpu_s'] / 3600:.2f} |")
    text = "\n".join(lines) + "\n" + "".join(comparison_report(out, which) for which in COMPARISONS)
    text += size_report(study, out)
    atomic_write_text(out / "trials.md", text)
    return text


def size_report(study, out: Path) -> str:
    """The table of each finished setting's IQM share by plant size (what ``--write-config --by-size``
    chooses on), or "" before the guards have run or before any trial has finished."""
    guards_file = out / COMPARISONS["guards"][0]
    optuna = require_optuna()
    if not guards_file.is_file() or not any(t.state == optuna.trial.TrialState.COMPLETE
                                            for t in study.get_trials(deepcopy=False)):
        return ""
    guards = json.loads(guards_file.read_text())
    lines = ["", "## By plant size", "",
             f"Each setting judged on every run: the IQM share of rule_based_agents over its runs on the plants of "
             f"fewer than {LARGE_PLANTS} containers (the search's), and over its runs on the plants of at least "
             f"{LARGE_PLANTS} (the search's and the regression guards'), what `--write-config --by-size` chooses on.",
             "", f"| setting | plants < {LARGE_PLANTS} | plants >= {LARGE_PLANTS} |", "|---|---|---|"]
    for t in finished_settings(study, "--report"):
        scores = size_scores(t, guards)
        cells = ("–", "–") if scores is None else (f"{scores['small']:.3f}", f"{scores['large']:.3f}")
        lines.append(f"| {guard_label(t)} | {cells[0]} | {cells[1]} |")
    return "\n".join(lines) + "\n"


def _cell(value) -> str:
    if isinstance(value, float) and value not in (0.0,) and (abs(value) < 1e-2 or abs(value) >= 1e4):
        return f"{value:.2g}"
    return str(value).lower() if isinstance(value, bool) else str(value)


def _count(settings) -> str:
    return "1 setting" if len(settings) == 1 else f"{len(settings)} settings"


def write_config(method: str, study, out: Path, path: Path) -> dict[str, Any]:
    """Write the settings of the best finished trial (highest IQM share of rule_based_agents over every
    run) that passes the regression guards of ``out``/guards.json (the best finished trial where no
    guard has run) as ``method``'s settings file, read by ``train`` and ``compare``; a ValueError when
    no trial has finished, or when a finished setting ranked before the chosen one has no guard runs."""
    ranked = finished_settings(study, "--write-config")
    best, guarded = ranked[0], ""
    guards_file = out / COMPARISONS["guards"][0]
    if guards_file.is_file():
        guards = json.loads(guards_file.read_text())
        failing = []
        for t in ranked:
            verdict = guard_verdict(guards, t.params)
            if verdict is None:
                raise ValueError(f"--write-config: trial {t.number}'s setting has no regression guard runs on every "
                                 f"guard row and seed in {guards_file}: run --guards first")
            if verdict[0]:
                best = t
                break
            failing.append(f"trial {t.number}")
        guarded = (f" that passes the regression guards (IQM share on {', '.join(guards['rows'])} at least the "
                   f"default's - {GUARD_TOLERANCE}" + (f"; {', '.join(failing)} fail" if failing else "") + ")")
    else:
        guarded = " (no regression guard run)"
    trials = study.get_trials(deepcopy=False)
    tried = {settings_key(t.params) for t in trials if t.params}
    which = "the trainer's default setting" if best.params == DEFAULT_TRIAL else "a searched setting"
    source = (f"studies/native_ppo_tuning.py: trial {best.number} ({which}), the best of {_count(ranked)} judged "
              f"on every run{guarded}, of {_count(tried)} tried (the others were pruned), IQM share of "
              f"rule_based_agents {best.value:.3f} on validation episodes ({_shown(out / 'trials.md')})")
    write_settings(path, dict(best.params), source)
    return dict(best.params)


def _shown(path: Path) -> str:
    """``path`` as a settings file names it: relative to the repository (this one's, or the checkout's a
    frozen copy of the code writes into: from its ``results`` folder on)."""
    path = path.resolve()
    if path.is_relative_to(REPO):
        return path.relative_to(REPO).as_posix()
    parts = path.parts
    return Path(*parts[len(parts) - 1 - parts[::-1].index("results"):]).as_posix() if "results" in parts \
        else path.as_posix()


def plant_size(row: str) -> int:
    return load_config(row).n_containers


def size_scores(trial, guards: dict[str, Any]) -> dict[str, float] | None:
    """The IQM share of rule_based_agents of ``trial``'s runs on the plants of fewer than
    :data:`LARGE_PLANTS` containers (``"small"``: the search's own runs there) and of at least that many
    (``"large"``: its search runs there and its regression guard runs, all on validation episodes); None
    where its guard runs are not all there."""
    verdict = guard_verdict(guards, trial.params)
    if verdict is None:
        return None
    runs = [v for k, v in trial.user_attrs.items() if k.startswith("run_")]
    small = [r["score"] for r in runs if plant_size(r["row"]) < LARGE_PLANTS]
    large = [r["score"] for r in runs if plant_size(r["row"]) >= LARGE_PLANTS]
    large += [e["score"] for e in guard_entry(guards, trial.params)["runs"]]
    return {"small": iqm(small), "large": iqm(large)}


def write_config_by_size(method: str, study, out: Path, path: Path) -> dict[str, Any]:
    """Write settings per plant size as ``method``'s settings file: for the plants of fewer than
    :data:`LARGE_PLANTS` containers the finished setting of highest IQM share over its runs there, for the
    larger ones (a ``[[by_size]]`` entry) the one of highest IQM share over its runs there and its
    regression guard runs; one setting for all where both are the same. A ValueError when no trial has
    finished, the guards have not run, or a finished setting lacks guard runs."""
    ranked = finished_settings(study, "--write-config")
    guards_file = out / COMPARISONS["guards"][0]
    if not guards_file.is_file():
        raise ValueError(f"--write-config --by-size: no regression guards in {guards_file}: run --guards first")
    guards = json.loads(guards_file.read_text())
    scores = {}
    for t in ranked:
        scores[t.number] = size_scores(t, guards)
        if scores[t.number] is None:
            raise ValueError(f"--write-config --by-size: trial {t.number}'s setting has no regression guard runs "
                             f"on every guard row and seed in {guards_file}: run --guards first")
    rows = {"small": [r for r in ROWS if plant_size(r) < LARGE_PLANTS],
            "large": [r for r in ROWS if plant_size(r) >= LARGE_PLANTS] + list(guards["rows"])}
    best = {size: max(ranked, key=lambda t: (scores[t.number][size], -t.number)) for size in ("small", "large")}
    wheres = {"small": f"fewer than {LARGE_PLANTS} containers", "large": f"at least {LARGE_PLANTS} containers"}

    def source(*sizes: str) -> str:
        trial = best[sizes[0]]
        which = "the trainer's default setting" if trial.params == DEFAULT_TRIAL else "a searched setting"
        if trial.user_attrs.get("start_from"):  # where a queued trial came from: "first search trial 39"
            which += f", {trial.user_attrs['start_from']}"
        where = " and on those of ".join(wheres[size] for size in sizes)
        shares = "; ".join(f"{scores[trial.number][size]:.3f} over its runs on {', '.join(rows[size])}"
                           for size in sizes)
        return (f"studies/native_ppo_tuning.py: trial {trial.number} ({which}), of {_count(ranked)} judged on every "
                f"run the best on the plants of {where}: IQM share of rule_based_agents {shares}, with seeds "
                f"{SEEDS[0]}-{SEEDS[-1]}, validation episodes ({_shown(out / 'trials.md')})")

    small, large = best["small"], best["large"]
    if small.params == large.params:
        write_settings(path, dict(small.params), source("small", "large"))
    else:
        write_settings(path, dict(small.params), source("small"), by_size=[(LARGE_PLANTS, dict(large.params),
                                                                            source("large"))])
    return {"settings": dict(small.params),
            **({} if small.params == large.params else {"by_size": {LARGE_PLANTS: dict(large.params)}})}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--method", default="fast_shared_ppo",
                   choices=["fast_ppo", "fast_shared_ppo", "fast_shared_ppo_team"])
    p.add_argument("--trials", type=int, default=None,
                   help="finished (complete or pruned) trials to reach (default 40; 2 with --smoke)")
    p.add_argument("--workers", type=int, default=2, help="processes, one core each")
    p.add_argument("--out", default="results/ppo_tuning", help="the journal and tables, in <out>/<method>/")
    p.add_argument("--runs", default="runs/ppo_tuning", help="the trials' runs, in <runs>/<method>/")
    p.add_argument("--space", choices=sorted(SPACES), default="default",
                   help="the settings searched: 'wide' adds SB3's minibatch of 64 and its 6144 samples per update to "
                        "the default space, a search of its own in <out>/<method>/wide/ that starts from the default, "
                        "the first search's settings judged on every run (their runs reused) and SB3's update shape")
    p.add_argument("--report", action="store_true", help="train nothing: write the tables of the journal")
    p.add_argument("--smoke", action="store_true", help="trials of 1 row x 1 seed at 8192 samples (a test)")
    p.add_argument("--finalists", type=int, default=0, metavar="K",
                   help="first queue the K settings not yet judged on every run that beat the default by most on "
                        "the runs both did (at least the first 4) as finalists, which the pruner never stops")
    p.add_argument("--start-from", default=None, metavar="METHOD:K",
                   help="queue the K best settings of METHOD's search in the same space (its journal under --out), "
                        "each judged on every run, unless this search judged it in full already, e.g. "
                        "fast_shared_ppo:3 for fast_shared_ppo_team")
    p.add_argument("--guards", action="store_true",
                   help="train nothing new for the search: train and validate the default and the best finished "
                        f"trial's setting on the regression guards ({', '.join(GUARD_ROWS)}) with the same seeds")
    p.add_argument("--discount", nargs="?", const=DT60_GAMMA, default=None, type=float, metavar="GAMMA",
                   help="train nothing new for the search: train the best finished trial's setting with discount "
                        f"GAMMA (default {DT60_GAMMA}) on the search's δ = 60 s rows with the same seeds, beside its own "
                        f"runs at γ = {GAMMA}: a labelled variant")
    p.add_argument("--own-check", nargs="?", const=OWN_CHECK_RISK, default=None, type=float, metavar="RISK",
                   help="train nothing new for the search: train the best finished trial's setting with the container "
                        f"agents' own check (ε = RISK, default {OWN_CHECK_RISK}; a lead of {OWN_CHECK_LEAD_STEPS} fill) on "
                        "the search's rows and the guards' with the same seeds, beside its runs without: a labelled "
                        "variant (decentralised methods)")
    p.add_argument("--overflow-scale", nargs="?", const=OVERFLOW_SCALE, default=None, type=float, metavar="SCALE",
                   help="train nothing new for the search: train the best finished trial's setting with the "
                        f"learner's reward at an overflow SCALE x r_min (default {OVERFLOW_SCALE:g}) on the search's "
                        "rows and the guards' with the same seeds, beside its runs with the plant's reward: a "
                        "labelled variant")
    p.add_argument("--write-config", nargs="?", const="", default=None, metavar="PATH",
                   help="train nothing: write the best finished trial's settings as the method's settings file "
                        "(default configs/hyperparams/<method>.toml)")
    p.add_argument("--by-size", action="store_true",
                   help=f"with --write-config: settings of their own for the plants of at least {LARGE_PLANTS} "
                        "containers, chosen on the search's runs there and the regression guards' (which must have "
                        "run); the others chosen on the smaller plants' runs")
    ns = p.parse_args(argv)
    if ns.by_size and ns.write_config is None:
        p.error("--by-size: goes with --write-config")
    ns.report = ns.report or ns.write_config is not None
    # the options that train a comparison beside the search rather than the search
    comparison = ns.guards or any(v is not None for v in (ns.discount, ns.own_check, ns.overflow_scale))
    optuna = require_optuna()
    out, runs = Path(ns.out) / ns.method, Path(ns.runs) / ns.method
    # the wide search is a study of its own (Optuna keeps one space per study) beside the first one,
    # whose runs it reuses; the runs of both share one folder per setting
    parent_out = out if ns.space != "default" else None
    if parent_out is not None:
        if not (parent_out / "journal.log").is_file() and not ns.smoke:
            p.error(f"--space {ns.space}: starts from the first search's journal, {parent_out / 'journal.log'} "
                    "is missing")
        out = out / ns.space
    if ns.start_from:  # another method's search in the same space: its settings are points of this one
        other, _, count = ns.start_from.partition(":")
        source_journal = Path(ns.out) / other / ("" if parent_out is None else ns.space) / "journal.log"
        if other == ns.method or not source_journal.is_file():
            p.error(f"--start-from: no other search {other!r} in the {ns.space} space ({source_journal})")
    out.mkdir(parents=True, exist_ok=True)
    rows, seeds, timesteps, total = ROWS, SEEDS, None, ns.trials or 40
    if ns.smoke:  # two rollouts of about 4096 samples: a checkpoint after the first, at half the budget
        rows, seeds, timesteps, total = ROWS[1:2], SEEDS[:1], 8192, ns.trials or 2
    rule = rule_returns(rows, out / "rule_based_agents_validation.json")
    journal = out / "journal.log"
    with RunLock(out):  # one search of a method at a time (an OS lock, released however the search ends)
        study = open_study(ns.method, journal, sampler_seed=0,
                           read_only=(ns.report or comparison) and journal.is_file())
        parent = (open_study(ns.method, parent_out / "journal.log", 0, read_only=True)
                  if parent_out is not None and (parent_out / "journal.log").is_file() else None)
        # the first search's runs and comparisons, for a wide search: a setting it judged is not trained again
        reused = {**comparison_runs(parent_out), **recorded_runs(parent)} if parent is not None else {}
        if comparison:
            if ns.guards:
                which, chosen, compared = "guards", guard_settings(study), rows[:1] if ns.smoke else GUARD_ROWS
            elif ns.own_check is not None:
                if ns.method == "fast_ppo":
                    p.error("--own-check: the container agents' check; fast_ppo is a centralised controller")
                if not 0 < ns.own_check < 1:
                    p.error(f"--own-check: expected a probability in (0, 1), got {ns.own_check}")
                which, chosen = "own_check", own_check_settings(study, ns.own_check)
                compared = rows if ns.smoke else ROWS + GUARD_ROWS
            elif ns.overflow_scale is not None:
                if not 1 < ns.overflow_scale <= MAX_OVERFLOW_REWARD_SCALE:
                    p.error(f"--overflow-scale: expected a multiple of r_min in (1, {MAX_OVERFLOW_REWARD_SCALE:g}], "
                            f"got {ns.overflow_scale}")
                which, chosen = "overflow_scale", overflow_scale_settings(study, ns.overflow_scale)
                compared = rows if ns.smoke else ROWS + GUARD_ROWS
            else:
                if not 0 < ns.discount <= 1:
                    p.error(f"--discount: expected a discount factor in (0, 1], got {ns.discount}")
                which, chosen = "discount", discount_settings(study, ns.discount)
                compared = rows if ns.smoke else tuple(r for r in rows if r.endswith("_dt60"))
            run_comparison(ns.method, chosen, runs, out / COMPARISONS[which][0], compared, seeds, timesteps,
                           ns.workers, rule_returns(compared, out / "rule_based_agents_validation.json"),
                           {**reused, **recorded_runs(study)})
        elif not ns.report:
            requeued = requeue_interrupted(study)
            if requeued:
                print(f"{requeued} interrupted trial(s) queued again")
            if not study.get_trials(deepcopy=False):
                study.enqueue_trial(DEFAULT_TRIAL, user_attrs={"default": True})
                if parent is not None:  # judged on every run, never pruned: references, as the default is
                    judged = any(t.state == optuna.trial.TrialState.COMPLETE for t in parent.get_trials(deepcopy=False))
                    for t in finished_settings(parent, f"--space {ns.space}") if judged else []:
                        if t.params != DEFAULT_TRIAL:
                            study.enqueue_trial(t.params, user_attrs={"start_from": f"first search trial {t.number}",
                                                                      "in_full": True})
                    study.enqueue_trial(SB3_SHAPE_TRIAL, user_attrs={"start_from": "SB3's update shape",
                                                                     "in_full": True})
            if ns.start_from:
                # judged on every run, as the first search's settings are in a wide search: chosen for another
                # method's results, a setting is not to be stopped on this method's first four runs. Queued
                # once: not where a trial of this search judged it in full or waits to
                source = open_study(other, source_journal, 0, read_only=True)
                alive = (optuna.trial.TrialState.WAITING, optuna.trial.TrialState.RUNNING)
                present = {settings_key(trial_settings(t)) for t in study.get_trials(deepcopy=False)
                           if t.state == optuna.trial.TrialState.COMPLETE
                           or (t.state in alive and never_pruned(t))}
                for number, params in best_settings(source, int(count or 3), min_runs=len(rows)):
                    if settings_key(params) not in present:
                        study.enqueue_trial(params, user_attrs={"start_from": f"{other} trial {number}",
                                                                "in_full": True})
            done = sum(t.state in (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED)
                       for t in study.get_trials(deepcopy=False))
            if ns.finalists:
                finalists = enqueue_finalists(study, ns.finalists, min_runs=WARMUP_RUNS)
                print(f"finalists queued, the settings of trial(s) {finalists}")
                waiting = len(study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.WAITING,)))
                total = max(total, done + waiting)  # every queued trial runs, finalists requeued included
            if done < total:
                args = (ns.method, str(journal), str(runs), rows, seeds, rule, timesteps, total, ns.space,
                        reused)
                ctx = multiprocessing.get_context("spawn")
                run_workers([ctx.Process(target=_worker, args=(*args, k)) for k in range(max(ns.workers, 1))])
            study = open_study(ns.method, journal, sampler_seed=0, read_only=True)
        print(report(ns.method, study, out, rule, ns.space, reused))
        if ns.write_config is not None:
            path = Path(ns.write_config) if ns.write_config else settings_file(ns.method)
            try:
                chosen = (write_config_by_size if ns.by_size else write_config)(ns.method, study, out, path)
                print(f"wrote {path}: {chosen}")
            except ValueError as exc:
                p.error(str(exc))


if __name__ == "__main__":
    from containergym_marl.orchestration.stopping import exit_on_sigterm

    exit_on_sigterm()  # stopped by SIGTERM, the finally clauses stop the child processes first
    main()
