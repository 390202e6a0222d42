"""studies/native_ppo_tuning.py at its smoke size: the default setting is the first trial, every
trial's runs are scored on validation episodes and recorded in the journal, the tables are generated
from it, and a trial a kill left running is run again with the same setting."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

optuna = pytest.importorskip("optuna")

from containergym_marl.policies.actor_critic import ActorCritic  # noqa: E402
from containergym_marl.rundir import run_name  # noqa: E402
from tests.helpers import sigterm_leaves_no_child  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
SCRIPT = str(REPO / "studies" / "native_ppo_tuning.py")
DEFAULT_TRIAL = {"rollout_samples": 4096, "n_steps": 64, "minibatch_size": 1024, "n_epochs": 10,
                 "learning_rate": 3e-4, "anneal_lr": False, "ent_coef": 0.0, "clip_range": 0.2}


def _search(out: Path, runs: Path, *extra: str) -> None:
    subprocess.run([sys.executable, SCRIPT, "--method", "fast_shared_ppo", "--smoke", "--workers", "1",
                    "--out", str(out), "--runs", str(runs), *extra],
                   capture_output=True, text=True, timeout=600, check=True)


def _study(out: Path):
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    storage = JournalStorage(JournalFileBackend(str(out / "fast_shared_ppo" / "journal.log")))
    return optuna.load_study(study_name="fast_shared_ppo", storage=storage)


@pytest.mark.slow  # a study's end-to-end smoke search, ~50 s
def test_smoke_search_records_every_trial_and_requeues_an_interrupted_one(tmp_path):
    out, runs = tmp_path / "out", tmp_path / "runs"
    _search(out, runs)
    saved = json.loads((out / "fast_shared_ppo" / "trials.json").read_text())
    trials = saved["trials"]
    assert len(trials) == 2 and trials[0]["params"] == DEFAULT_TRIAL
    assert all(t["state"] == "COMPLETE" and len(t["runs"]) == 1 for t in trials)
    rule = saved["rule_based_agents_validation_return"]["n5_m2_dt120"]
    for t in trials:
        [entry] = t["runs"]
        assert entry["row"] == "n5_m2_dt120" and entry["seed"] == 101 and entry["samples"] >= 8192
        assert entry["score"] == pytest.approx(entry["validation_return"] / rule)
    # the default: 13 simulations x 64 steps x 5 agents per rollout, a checkpoint after the first of two
    assert (trials[0]["runs"][0]["samples"], trials[0]["runs"][0]["half_budget_samples"]) == (8320, 4160)
    folders = sorted(p.name for p in (runs / "fast_shared_ppo").iterdir())
    assert len(folders) == 2
    for folder in folders:
        run = runs / "fast_shared_ppo" / folder / run_name("fast_shared_ppo", "n5_m2_dt120", 101)
        args = json.loads((run / "args.json").read_text())
        assert args["hyperparams"] in [t["params"] for t in trials] and args["seed"] == 101
    assert "| 0 | complete | 4096 | 64 | 1024 | 10 | 0.0003 | false | 0.0 | 0.2 | 1 |" in \
        (out / "fast_shared_ppo" / "trials.md").read_text()

    # a trial that a kill left running: failed, and its setting queued again; the default has been
    # judged already (trial 0), so the queued one takes its verdict without training
    import importlib.util

    spec = importlib.util.spec_from_file_location("native_ppo_tuning", SCRIPT)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    study = _study(out)
    study.enqueue_trial(DEFAULT_TRIAL)
    stale = study.ask()
    assert script.suggest(stale) == DEFAULT_TRIAL
    _search(out, runs, "--trials", "3")
    trials = {t.number: t for t in _study(out).get_trials()}
    assert trials[stale.number].state == optuna.trial.TrialState.FAIL
    [again] = [t for t in trials.values() if t.user_attrs.get("requeued_from") == stale.number]
    assert again.state == optuna.trial.TrialState.COMPLETE and again.params == DEFAULT_TRIAL
    assert again.value == trials[0].value and again.user_attrs["duplicate_of"] == 0
    assert f"| {stale.number} | interrupted (queued again as trial {again.number}) |" in \
        (out / "fast_shared_ppo" / "trials.md").read_text()
    assert len(list((runs / "fast_shared_ppo").iterdir())) == 2

    # a setting no trial has judged, whose trial a kill stopped after its run was recorded (what
    # Objective records after each run); on another machine (no run folders) the setting queued
    # again takes that run from the journal instead of training it again
    import shutil

    setting = {**DEFAULT_TRIAL, "n_epochs": 5, "learning_rate": 1e-3}
    study = _study(out)
    study.enqueue_trial(setting)
    stale = study.ask()
    assert script.suggest(stale) == setting
    key = script.settings_key(setting)
    entry = script.train_and_validate("fast_shared_ppo", "n5_m2_dt120", 101, setting,
                                      runs / "fast_shared_ppo" / key / run_name("fast_shared_ppo", "n5_m2_dt120", 101),
                                      8192)
    entry.update(score=entry["validation_return"] / rule, half_budget_score=entry["half_budget_return"] / rule)
    stale.set_user_attr("folder", key)
    stale.set_user_attr("run_00", entry)
    shutil.rmtree(runs)
    _search(out, runs, "--trials", "5")
    [again] = [t for t in _study(out).get_trials() if t.user_attrs.get("requeued_from") == stale.number]
    assert again.state == optuna.trial.TrialState.COMPLETE and "duplicate_of" not in again.user_attrs
    assert again.user_attrs["run_00"]["validation_return"] == entry["validation_return"]
    assert not (runs / "fast_shared_ppo" / key).exists()  # nothing trained again

    # the best finished trial's settings, as the method's settings file that train reads
    from containergym_marl.config.hyperparams import read_settings

    _search(out, runs, "--write-config", str(tmp_path / "chosen.toml"))
    finished = [t for t in _study(out).get_trials() if t.state == optuna.trial.TrialState.COMPLETE]
    best = max(finished, key=lambda t: t.value)
    settings, source = read_settings(tmp_path / "chosen.toml")
    judged = {script.settings_key(t.params) for t in finished}
    tried = {script.settings_key(t.params) for t in _study(out).get_trials() if t.params}
    assert settings == best.params and f"trial {best.number} (" in source
    assert (f"the best of {len(judged)} setting{'s' if len(judged) > 1 else ''} judged on every run (no regression guard run), of {len(tried)} "
            f"setting{'s' if len(tried) > 1 else ''} tried") in source

    # the regression guards (at smoke size: the search's own row and seed) compare the default with
    # the chosen setting, reusing the runs the search trained, and leave the journal alone
    journal = (out / "fast_shared_ppo" / "journal.log").read_bytes()
    _search(out, runs, "--guards")
    guards = json.loads((out / "fast_shared_ppo" / "guards.json").read_text())
    # the default first, then every setting judged on every run, best first
    ranked, seen = [], set()
    for t in sorted(finished, key=lambda t: (-t.value, t.number)):
        if script.settings_key(t.params) not in seen:
            seen.add(script.settings_key(t.params))
            ranked.append(t)
    expected = {"default": DEFAULT_TRIAL} | {f"trial {t.number}": t.params for t in ranked if t.params != DEFAULT_TRIAL}
    assert list(guards["settings"]) == list(expected)
    assert {label: g["params"] for label, g in guards["settings"].items()} == expected
    searched = {(t.params == DEFAULT_TRIAL, e["row"], e["seed"]): e["validation_return"]
                for t in finished for k, e in t.user_attrs.items() if k.startswith("run_")}
    searched = {(script.settings_key(t.params), e["row"], e["seed"]): e["validation_return"]
                for t in finished for k, e in t.user_attrs.items() if k.startswith("run_")}
    for label, g in guards["settings"].items():
        (entry,) = g["runs"]
        assert entry["validation_return"] == searched[(script.settings_key(g["params"]), entry["row"], entry["seed"])]
    assert "## Regression guards" in (out / "fast_shared_ppo" / "trials.md").read_text()
    assert (out / "fast_shared_ppo" / "journal.log").read_bytes() == journal

    # the discount variant: the chosen setting again with γ = 0.995 beside its own search runs (γ = 0.99,
    # taken from the journal, not trained again), the journal left alone
    _search(out, runs, "--discount")
    discount = json.loads((out / "fast_shared_ppo" / "discount.json").read_text())
    (same, other) = discount["settings"].values()
    assert same["params"] == other["params"] == best.params and (same["gamma"], other["gamma"]) == (0.99, 0.995)
    assert same["runs"][0]["validation_return"] == searched[(script.settings_key(best.params), "n5_m2_dt120", 101)]
    (variant_run,) = [p for p in (runs / "fast_shared_ppo").glob("*/*") if json.loads(
        (p / "args.json").read_text())["gamma"] == 0.995]
    assert json.loads((variant_run / "args.json").read_text())["hyperparams"] == best.params
    assert other["runs"][0]["samples"] >= 8192
    assert "## Discount for δ = 60 s (a labelled variant)" in (out / "fast_shared_ppo" / "trials.md").read_text()
    assert (out / "fast_shared_ppo" / "journal.log").read_bytes() == journal

    # the agents' own check: the chosen setting again with the check, beside its own search run (reused)
    _search(out, runs, "--own-check")
    checked = json.loads((out / "fast_shared_ppo" / "own_check.json").read_text())
    (plain, with_check) = checked["settings"].values()
    assert plain["params"] == best.params and with_check["params"] == {**best.params, "own_check_risk": 1e-4,
                                                                         "own_check_lead_steps": 1}
    assert plain["runs"][0]["validation_return"] == searched[(script.settings_key(best.params), "n5_m2_dt120", 101)]
    (checked_run,) = [p for p in (runs / "fast_shared_ppo").glob("*/*") if p.is_dir() and json.loads(
        (p / "args.json").read_text())["hyperparams"].get("own_check_risk") == 1e-4]
    assert ActorCritic.load(checked_run / "final_model.pt").own_check == {"risk": 1e-4, "lead_steps": 1}
    assert "## The container agents' own check (a labelled variant)" in (out / "fast_shared_ppo" / "trials.md").read_text()
    assert (out / "fast_shared_ppo" / "journal.log").read_bytes() == journal

    # the heavier overflow in training: the chosen setting again with 10 x r_min, beside its own search run
    _search(out, runs, "--overflow-scale")
    shaped = json.loads((out / "fast_shared_ppo" / "overflow_scale.json").read_text())
    (plain, heavier) = shaped["settings"].values()
    assert plain["params"] == best.params and heavier["params"] == {**best.params, "overflow_reward_scale": 10.0}
    assert plain["runs"][0]["validation_return"] == searched[(script.settings_key(best.params), "n5_m2_dt120", 101)]
    assert heavier["runs"][0]["samples"] >= 8192
    assert "## A heavier overflow in training (a labelled variant)" in (out / "fast_shared_ppo" / "trials.md").read_text()
    assert (out / "fast_shared_ppo" / "journal.log").read_bytes() == journal

    # another method's search starts from this one's best settings after its own default, reading this
    # search's journal without writing to it (as --report reads its own)
    journal = (out / "fast_shared_ppo" / "journal.log").read_bytes()
    _search(out, runs, "--report")
    subprocess.run([sys.executable, SCRIPT, "--method", "fast_shared_ppo_team", "--smoke", "--workers", "1",
                    "--trials", "2", "--start-from", "fast_shared_ppo:2", "--out", str(out), "--runs", str(runs)],
                   capture_output=True, text=True, timeout=600, check=True)
    team = json.loads((out / "fast_shared_ppo_team" / "trials.json").read_text())["trials"]
    shared_best = [t.params for t in sorted(finished, key=lambda t: -t.value) if t.params != DEFAULT_TRIAL]
    assert [t["params"] for t in team[:2]] == [DEFAULT_TRIAL, shared_best[0]]
    assert (out / "fast_shared_ppo" / "journal.log").read_bytes() == journal

    # the wide space: a search of its own beside the first, whose first trials are the default, the
    # first search's settings judged on every run (their runs taken from its journal: nothing trained
    # again) and SB3's update shape, each judged on every run; the first search's journal left alone
    first = {script.settings_key(t.params): t for t in ranked}
    expected = [DEFAULT_TRIAL] + [t.params for t in ranked if t.params != DEFAULT_TRIAL] + [script.SB3_SHAPE_TRIAL]
    folders = {p.name for p in (runs / "fast_shared_ppo").iterdir()}
    _search(out, runs, "--space", "wide", "--trials", str(len(expected)))
    wide = json.loads((out / "fast_shared_ppo" / "wide" / "trials.json").read_text())
    assert [t["params"] for t in wide["trials"]] == expected and wide["space_name"] == "wide"
    assert all(t["state"] == "COMPLETE" and len(t["runs"]) == 1 for t in wide["trials"])
    for t in wide["trials"][:-1]:
        (entry,) = t["runs"]
        theirs = first[script.settings_key(t["params"])].user_attrs["run_00"]
        assert (entry["validation_return"], entry["cpu_s"]) == (theirs["validation_return"], theirs["cpu_s"])
    sb3 = script.settings_key(script.SB3_SHAPE_TRIAL)
    assert {p.name for p in (runs / "fast_shared_ppo").iterdir()} - folders == {sb3}  # only SB3's shape trained
    run = runs / "fast_shared_ppo" / sb3 / run_name("fast_shared_ppo", "n5_m2_dt120", 101)
    assert json.loads((run / "args.json").read_text())["hyperparams"] == script.SB3_SHAPE_TRIAL
    # its compute counts only what it trained itself
    assert wide["core_hours"] == round(wide["trials"][-1]["runs"][0]["cpu_s"] / 3600, 2)
    text = (out / "fast_shared_ppo" / "wide" / "trials.md").read_text()
    assert "(wide space)" in text and "--space wide --report" in text and "(SB3's update shape)" in text
    assert (out / "fast_shared_ppo" / "journal.log").read_bytes() == journal


@pytest.mark.slow  # starts a smoke search and stops it, ~15 s
def test_a_sigterm_to_the_search_stops_its_worker_processes_before_it_exits(tmp_path):
    """A killed search's workers must not outlive it: a search started again (its lock free) would run
    beside them, and they would fail the trials it queued again."""
    pytest.importorskip("psutil")
    sigterm_leaves_no_child([SCRIPT, "--method", "fast_shared_ppo", "--smoke", "--workers", "2", "--out",
                             str(tmp_path / "out"), "--runs", str(tmp_path / "runs")],
                            lambda cmd: "spawn_main" in cmd and "resource_tracker" not in cmd, count=2)


def test_the_wide_space_holds_every_setting_of_the_first_and_sb3s_update_shape():
    """A wide search starts from the first search's settings and SB3's shape: each must be a point of
    its space (Optuna stops a queued trial whose value is not among a parameter's choices)."""
    script = _load_script()
    for name, choices in script.SPACE.items():
        wide = script.WIDE_SPACE[name]
        assert wide == choices if isinstance(choices, tuple) else set(choices) <= set(wide)
    for name, value in script.SB3_SHAPE_TRIAL.items():
        choices = script.WIDE_SPACE[name]
        assert choices[0] <= value <= choices[1] if isinstance(choices, tuple) else value in choices
    assert 64 in script.WIDE_SPACE["minibatch_size"] and 64 not in script.SPACE["minibatch_size"]
    study = optuna.create_study(direction="maximize", sampler=optuna.samplers.RandomSampler(seed=0))
    study.enqueue_trial(script.SB3_SHAPE_TRIAL)
    assert script.suggest(study.ask(), script.WIDE_SPACE) == script.SB3_SHAPE_TRIAL


def test_a_wide_search_without_its_first_search_is_refused_before_anything_is_written(tmp_path, capsys):
    script = _load_script()
    with pytest.raises(SystemExit):
        script.main(["--method", "fast_shared_ppo", "--space", "wide", "--out", str(tmp_path / "out"),
                     "--runs", str(tmp_path / "runs")])
    assert "starts from the first search's journal" in capsys.readouterr().err
    assert not (tmp_path / "out").exists() and not (tmp_path / "runs").exists()


def _recorded_run(row: str, validation_return: float) -> dict:
    """A run's entry as a comparison's file records it (seed 101)."""
    return {"row": row, "seed": 101, "validation_return": validation_return, "overflowing_episodes": 2,
            "half_budget_samples": 1000, "half_budget_return": 40.0, "samples": 2000, "cpu_s": 1.0,
            "wall_time_s": 1.0}


def _load_script():
    import importlib.util

    spec = importlib.util.spec_from_file_location("native_ppo_tuning", SCRIPT)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    return script


def _setting(study, x: int):
    """A trial of setting ``x`` (its only parameter)."""
    study.enqueue_trial({"x": x})
    trial = study.ask()
    trial.suggest_int("x", 0, 100)
    return trial


def test_a_trial_below_the_median_of_the_others_at_the_same_run_is_stopped_but_never_the_default():
    script = _load_script()
    study = optuna.create_study(direction="maximize", pruner=script.pruner())
    reference = _setting(study, 1)  # still running: a reference all the same
    for step, value in enumerate([0.9, 0.9, 0.9, 0.9, 0.9]):
        reference.report(value, step)
    weak, strong = _setting(study, 2), _setting(study, 3)
    for step in range(script.WARMUP_RUNS - 1):  # before the fourth run nothing is stopped
        weak.report(0.1, step)
        assert not weak.should_prune()
    weak.report(0.1, script.WARMUP_RUNS - 1)
    strong.report(0.95, script.WARMUP_RUNS - 1)
    assert weak.should_prune() and not strong.should_prune()
    for attr in ("default", "finalist"):
        protected = _setting(study, 4 if attr == "default" else 5)
        protected.set_user_attr(attr, True)
        protected.report(0.0, script.WARMUP_RUNS - 1)
        assert not protected.should_prune()


def test_a_setting_tried_several_times_counts_once_in_the_median():
    """The default queued again after kills is one setting: three trials of it at 0.9 and one other
    setting at 0.5 make a median of 0.7 (two settings), not 0.9 (four trials)."""
    script = _load_script()
    study = optuna.create_study(direction="maximize", pruner=script.pruner())
    step = script.WARMUP_RUNS - 1
    for _ in range(3):
        _setting(study, 1).report(0.9, step)
    _setting(study, 2).report(0.5, step)
    candidate = _setting(study, 3)
    candidate.report(0.8, step)
    assert not candidate.should_prune()  # above 0.7; below 0.9, the median of the four trials
    other = _setting(study, 4)
    other.report(0.6, step)
    assert other.should_prune()  # the median of (0.9, 0.5, 0.8) is 0.8


def test_finalists_are_the_settings_that_beat_the_default_most_on_the_same_runs():
    script = _load_script()
    study = optuna.create_study(direction="maximize")
    keys = [(row, seed) for seed in (101, 102) for row in ("a", "b", "c", "d", "e")]
    rates = [script.DEFAULT_TRIAL["learning_rate"]] + [1.1e-4 * i for i in range(1, 7)]

    def finished(rate: float, scores: list[float], state):
        params = {**script.DEFAULT_TRIAL, "learning_rate": rate}
        study.enqueue_trial(params)
        trial = study.ask()
        for name, value in params.items():
            trial.suggest_categorical(name, rates if name == "learning_rate" else [value])
        for k, score in enumerate(scores):
            row, seed = keys[k]
            trial.set_user_attr(f"run_{k:02d}", {"row": row, "seed": seed, "score": score, "overflowing_episodes": 0,
                                                 "half_budget_score": score, "cpu_s": 1.0})
        study.tell(trial, float(np.mean(scores)) if state == optuna.trial.TrialState.COMPLETE else None, state=state)
        return trial

    pruned, complete = optuna.trial.TrialState.PRUNED, optuna.trial.TrialState.COMPLETE
    default = finished(rates[0], [0.9] * 4 + [0.5] * 6, complete)  # easy first runs, then hard ones
    judged = finished(rates[1], [0.95] * 10, complete)  # judged on every run: never a finalist
    early = finished(rates[2], [0.92] * 4, pruned)  # mean 0.92; +0.02 on the default's same runs
    later = finished(rates[3], [0.88] * 4 + [0.6] * 3, pruned)  # mean 0.76; +0.22 / 7 on the same runs
    lower = finished(rates[4], [0.6] * 7, pruned)  # -0.9 / 7
    finished(rates[5], [0.99] * 3, pruned)  # too few runs to rank
    lowest = finished(rates[6], [0.55] * 5, pruned)  # -1.35 / 5: fourth
    rows = {r["number"]: r for r in script.trial_rows(study)}
    assert script.advantage(rows[early.number], rows[default.number]) == pytest.approx(0.02)
    assert script.advantage(rows[later.number], rows[default.number]) == pytest.approx(0.22 / 7)
    assert script.advantage(rows[early.number], None) == pytest.approx(0.92)  # no reference: the mean
    assert script.enqueue_finalists(study, 3, min_runs=4) == [later.number, early.number, lower.number]
    waiting = study.get_trials(states=(optuna.trial.TrialState.WAITING,))
    assert [t.user_attrs["finalist_of"] for t in waiting] == [later.number, early.number, lower.number]
    assert all(t.user_attrs["finalist"] for t in waiting) and judged.number not in [
        t.user_attrs["finalist_of"] for t in waiting]
    assert script.enqueue_finalists(study, 2, min_runs=4) == []  # queued already
    assert script.enqueue_finalists(study, 3, min_runs=4) == []  # the same command again queues none more
    # an interrupted finalist is queued again as a finalist of the same trial, and still counts
    trial = study.ask()  # takes the first finalist (later's setting)
    assert trial.user_attrs["finalist_of"] == later.number
    assert script.requeue_interrupted(study) == 1
    requeued = study.get_trials(states=(optuna.trial.TrialState.WAITING,))[-1]
    assert requeued.user_attrs["finalist"] and requeued.user_attrs["finalist_of"] == later.number
    assert script.enqueue_finalists(study, 3, min_runs=4) == []
    assert script.enqueue_finalists(study, 4, min_runs=4) == [lowest.number]  # one more in all


def test_a_setting_proposed_again_takes_the_earlier_verdict_without_training(tmp_path, monkeypatch):
    import importlib.util

    spec = importlib.util.spec_from_file_location("native_ppo_tuning", SCRIPT)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    study = optuna.create_study(direction="maximize", sampler=optuna.samplers.RandomSampler(seed=0))
    judged = {**DEFAULT_TRIAL, "n_epochs": 5}
    study.enqueue_trial(DEFAULT_TRIAL)
    study.enqueue_trial(judged)
    complete, pruned = study.ask(), study.ask()
    script.suggest(complete), script.suggest(pruned)
    study.tell(complete, 0.8)
    study.tell(pruned, state=optuna.trial.TrialState.PRUNED)
    runs = tmp_path / "runs"
    objective = script.Objective("fast_shared_ppo", runs, ["n5_m2_dt120"], [101], {"n5_m2_dt120": 50.0}, 8192, {})
    for params in (DEFAULT_TRIAL, judged):
        study.enqueue_trial(params)
    study.optimize(objective, n_trials=2)
    again = study.get_trials()[2:]
    assert (again[0].state, again[0].value, again[0].user_attrs["duplicate_of"]) == (
        optuna.trial.TrialState.COMPLETE, 0.8, complete.number)
    assert (again[1].state, again[1].user_attrs["duplicate_of"]) == (optuna.trial.TrialState.PRUNED, pruned.number)
    assert not runs.exists()  # nothing trained
    rows = {r["number"]: r for r in script.trial_rows(study)}
    assert rows[again[0].number]["duplicate_of"] == complete.number
    # a setting queued to be judged in full (from another search) is judged, not given the pruned verdict
    trained = []
    monkeypatch.setattr(script, "train_and_validate", lambda *a: trained.append(a[1]) or {
        "validation_return": 40.0, "half_budget_return": 30.0, "overflowing_episodes": 0})
    study.enqueue_trial(judged, user_attrs={"in_full": True})
    study.optimize(objective, n_trials=1)
    last = study.get_trials()[-1]
    assert trained == ["n5_m2_dt120"] and "duplicate_of" not in last.user_attrs
    assert (last.state, last.value) == (optuna.trial.TrialState.COMPLETE, pytest.approx(0.8))


def test_a_search_starts_from_another_searchs_best_distinct_settings():
    """--start-from: finished trials by IQM first, then the others by mean score over enough runs,
    each setting once (a finalist repeats a pruned trial's setting)."""
    script = _load_script()
    study = optuna.create_study(direction="maximize")

    def trial(x: int, scores: list[float], state, value=None):
        t = _setting(study, x)
        for k, score in enumerate(scores):
            t.set_user_attr(f"run_{k:02d}", {"score": score, "overflowing_episodes": 0,
                                             "half_budget_score": score, "cpu_s": 1.0})
        study.tell(t, value, state=state)
        return t

    pruned, complete = optuna.trial.TrialState.PRUNED, optuna.trial.TrialState.COMPLETE
    finished = trial(1, [0.8] * 10, complete, value=0.8)
    near = trial(2, [0.95] * 7, pruned)
    trial(2, [0.95] * 8, pruned)  # the same setting again
    trial(3, [0.99] * 3, pruned)  # too few runs
    lower = trial(4, [0.7] * 7, pruned)
    assert script.best_settings(study, 5, min_runs=5) == [(finished.number, {"x": 1}), (near.number, {"x": 2}),
                                                         (lower.number, {"x": 4})]


def test_a_wide_search_under_way_starts_from_another_methods_wide_search_once(tmp_path, capsys):
    """--start-from in the wide space reads the other method's wide search (its settings are points of
    this space) and, on a search that has trials already, queues the best settings no trial of it has,
    once: the same command again queues nothing more."""
    script = _load_script()
    out, runs = tmp_path / "out", tmp_path / "runs"
    (out / "fast_shared_ppo").mkdir(parents=True)
    script.open_study("fast_shared_ppo", out / "fast_shared_ppo" / "journal.log", 0)  # the first search
    wide = out / "fast_shared_ppo" / "wide"
    argv = ["--method", "fast_shared_ppo", "--space", "wide", "--trials", "3", "--start-from",
            "fast_shared_ppo_team:3", "--out", str(out), "--runs", str(runs)]
    with pytest.raises(SystemExit):  # the other method's first search is not its wide search
        (out / "fast_shared_ppo_team").mkdir()
        script.open_study("fast_shared_ppo_team", out / "fast_shared_ppo_team" / "journal.log", 0)
        script.main(argv)
    assert "--start-from: no other search 'fast_shared_ppo_team' in the wide space" in capsys.readouterr().err
    assert not wide.exists() and not runs.exists()
    wide.mkdir()

    def finished(method: str, params: dict, value: float):
        study = script.open_study(method, out / method / "wide" / "journal.log", 0)
        study.enqueue_trial(params)
        trial = study.ask()
        script.suggest(trial, script.WIDE_SPACE)
        trial.set_user_attr("run_00", {**_recorded_run("n5_m2_dt120", 50.0), "score": value,
                                       "half_budget_score": value})
        study.tell(trial, value)

    (out / "fast_shared_ppo_team" / "wide").mkdir(parents=True)
    team_best = {**DEFAULT_TRIAL, "rollout_samples": 16384, "n_steps": 128, "minibatch_size": 256, "n_epochs": 5}
    team_second = {**DEFAULT_TRIAL, "n_epochs": 5}
    finished("fast_shared_ppo_team", team_best, 0.97)
    finished("fast_shared_ppo_team", team_second, 0.9)
    finished("fast_shared_ppo_team", DEFAULT_TRIAL, 0.8)
    finished("fast_shared_ppo", DEFAULT_TRIAL, 0.85)
    finished("fast_shared_ppo", team_second, 0.7)  # this search judged it in full already: not queued again
    study = script.open_study("fast_shared_ppo", wide / "journal.log", 0)
    study.enqueue_trial(team_best)  # stopped by the pruner at its first runs: queued again, in full
    trial = study.ask()
    script.suggest(trial, script.WIDE_SPACE)
    study.tell(trial, state=optuna.trial.TrialState.PRUNED)
    rule = {row: 50.0 for row in script.ROWS}
    (wide / "rule_based_agents_validation.json").write_text(json.dumps(rule))
    for _ in range(2):
        script.main(argv)
        study = script.open_study("fast_shared_ppo", wide / "journal.log", 0, read_only=True)
        waiting = study.get_trials(states=(optuna.trial.TrialState.WAITING,))
        assert [(script.trial_settings(t), t.user_attrs["start_from"], t.user_attrs["in_full"]) for t in waiting] == [
            (team_best, "fast_shared_ppo_team trial 0", True)]
    assert not runs.exists()  # nothing trained: the search has its three finished trials


def test_a_comparison_reuses_the_runs_its_own_file_records_where_their_folders_are_gone(tmp_path, monkeypatch):
    """--discount or --guards again on a machine without their runs' folders: the runs recorded in
    their JSON file (not in the search's journal) are taken from it, and nothing is trained again."""
    tuning = _load_script()
    hp = {"rollout_samples": 2048, "n_steps": 64}
    entry = _recorded_run("n5_m2_dt60", 50.0)
    path = tmp_path / "discount.json"
    path.write_text(json.dumps({"settings": {"old label": {"params": hp, "gamma": 0.995, "runs": [entry]}}}))
    monkeypatch.setattr(tuning.multiprocessing, "get_context", lambda *_: pytest.fail("a recorded run trained again"))
    result = tuning.run_comparison("fast_shared_ppo", [("trial 1, γ = 0.995", hp, 0.995)], tmp_path / "no_runs", path,
                                   ["n5_m2_dt60"], [101], None, 1, {"n5_m2_dt60": 100.0}, known={})
    [got] = result["settings"]["trial 1, γ = 0.995"]["runs"]
    assert got == {**entry, "score": 0.5} and not (tmp_path / "no_runs").exists()
    assert json.loads(path.read_text()) == json.loads(json.dumps(result))
    with pytest.raises(pytest.fail.Exception, match="trained again"):  # another γ is another run, not that one
        tuning.run_comparison("fast_shared_ppo", [("γ = 0.99", hp, 0.99)], tmp_path / "no_runs", path,
                              ["n5_m2_dt60"], [101], None, 1, {"n5_m2_dt60": 100.0}, known={})


def test_the_settings_file_takes_the_best_finished_setting_that_passes_the_regression_guards(tmp_path):
    """Three finished settings, best first: trial A loses 0.18 of the default's IQM share on one guard row
    (fails), B loses 0.04 (passes, within 0.05), the default passes by definition: the file takes B and
    names A as failing. A finished setting with no guard runs before the chosen one is an error, not a
    silent pick; with no guards.json at all the best finished setting is taken and the file says so."""
    from containergym_marl.config.hyperparams import read_settings

    script = _load_script()
    study = optuna.create_study(direction="maximize")
    a, b = {**DEFAULT_TRIAL, "n_epochs": 5}, {**DEFAULT_TRIAL, "n_epochs": 20}
    numbers = {}
    for params, value in ((DEFAULT_TRIAL, 0.6), (a, 0.8), (b, 0.7), (a, 0.75)):
        study.enqueue_trial(params)
        trial = study.ask()
        for name, v in params.items():
            trial.suggest_categorical(name, [3, 5, 10, 20] if name == "n_epochs" else [v])
        study.tell(trial, value)
        numbers.setdefault(script.settings_key(params), trial.number)
    rows, seeds = ["n11_m2_dt120", "n16_m2_dt120"], [101, 102, 103]

    def entry(params, shares):
        runs = [{"row": row, "seed": seed, "score": shares[row], "validation_return": 1.0, "overflowing_episodes": 0,
                 "half_budget_return": 1.0} for seed in seeds for row in rows]
        return {"params": params, "gamma": 0.99, "runs": runs}

    guards = {"rows": rows, "seeds": seeds, "rule_based_agents_validation_return": {r: 1.0 for r in rows},
              "settings": {"default": entry(DEFAULT_TRIAL, {"n11_m2_dt120": 0.85, "n16_m2_dt120": 0.99}),
                           "trial A": entry(a, {"n11_m2_dt120": 0.90, "n16_m2_dt120": 0.81}),
                           "trial B": entry(b, {"n11_m2_dt120": 0.81, "n16_m2_dt120": 0.95})}}
    assert script.guard_verdict(guards, a) == (False, ["n16_m2_dt120: IQM share 0.810 < the default's 0.990 - 0.05"])
    assert script.guard_verdict(guards, b) == (True, [])
    assert script.guard_verdict(guards, DEFAULT_TRIAL) == (True, [])
    assert script.guard_verdict(guards, {**DEFAULT_TRIAL, "n_epochs": 3}) is None
    assert [label for label, _, _ in script.guard_settings(study)] == [
        "default", f"trial {numbers[script.settings_key(a)]}", f"trial {numbers[script.settings_key(b)]}"]

    out, path = tmp_path / "out", tmp_path / "chosen.toml"
    out.mkdir()
    assert script.write_config("fast_shared_ppo_team", study, out, path) == a  # no guards run yet: the best
    assert "(no regression guard run)" in read_settings(path)[1]
    (out / "guards.json").write_text(json.dumps(guards))
    assert script.write_config("fast_shared_ppo_team", study, out, path) == b
    settings, source = read_settings(path)
    assert settings == b and f"trial {numbers[script.settings_key(b)]} (a searched setting)" in source
    assert f"trial {numbers[script.settings_key(a)]} fail" in source and "passes the regression guards" in source
    del guards["settings"]["trial B"]
    (out / "guards.json").write_text(json.dumps(guards))
    with pytest.raises(ValueError, match=f"trial {numbers[script.settings_key(b)]}'s setting has no regression guard"):
        script.write_config("fast_shared_ppo_team", study, out, path)
    assert read_settings(path)[0] == b  # the file is left as it was


def test_settings_by_plant_size_are_chosen_on_each_sizes_runs(tmp_path):
    """--by-size: A wins on the small plants' runs and loses on the large ones (its search run on
    n11_m11_dt60 and its guard runs), the default the other way round: the file holds A in [settings]
    and the default from 11 containers on, each with its own source; a plant takes the one of its size.
    Where one setting wins both, the file has no by_size entry."""
    from containergym_marl.config.hyperparams import read_settings

    script = _load_script()
    study = optuna.create_study(direction="maximize")
    a = {**DEFAULT_TRIAL, "n_epochs": 5}
    numbers = {}

    def finished(params, small_score, large_score):
        study.enqueue_trial(params)
        trial = study.ask()
        for name, v in params.items():
            trial.suggest_categorical(name, [3, 5, 10, 20] if name == "n_epochs" else [v])
        for k, (row, score) in enumerate([("n5_m2_dt120", small_score)] * 3 + [("n11_m11_dt60", large_score)] * 3):
            trial.set_user_attr(f"run_{k:02d}", {"row": row, "seed": 101 + k % 3, "score": score,
                                                 "overflowing_episodes": 0, "half_budget_score": score, "cpu_s": 1.0})
        study.tell(trial, (small_score + large_score) / 2)
        numbers[script.settings_key(params)] = trial.number

    rows, seeds = ["n11_m2_dt120", "n16_m2_dt120"], [101, 102, 103]

    def entry(params, share):
        return {"params": params, "gamma": 0.99, "runs": [{"row": r, "seed": s, "score": share} for s in seeds
                                                          for r in rows]}

    finished(DEFAULT_TRIAL, 0.5, 0.8)
    finished(a, 0.9, 0.3)
    out = tmp_path / "out"
    out.mkdir()
    path = tmp_path / "chosen.toml"
    with pytest.raises(ValueError, match="no regression guards"):
        script.write_config_by_size("fast_shared_ppo_team", study, out, path)
    guards = {"rows": rows, "seeds": seeds, "settings": {"default": entry(DEFAULT_TRIAL, 0.9)}}
    (out / "guards.json").write_text(json.dumps(guards))
    with pytest.raises(ValueError, match=f"trial {numbers[script.settings_key(a)]}'s setting has no regression"):
        script.write_config_by_size("fast_shared_ppo_team", study, out, path)
    assert not path.exists()
    guards["settings"]["trial A"] = entry(a, 0.85)
    (out / "guards.json").write_text(json.dumps(guards))
    scores = {k: script.size_scores(t, guards) for k, t in
              ((script.settings_key(t.params), t) for t in study.get_trials())}
    assert scores[script.settings_key(a)] == {"small": pytest.approx(0.9), "large": pytest.approx(
        float(np.mean(sorted([0.3] * 3 + [0.85] * 6)[2:7])))}  # IQM of 9: the middle 5 (after 2 cut each side)
    assert scores[script.settings_key(DEFAULT_TRIAL)]["large"] == pytest.approx(
        float(np.mean(sorted([0.8] * 3 + [0.9] * 6)[2:7])))
    got = script.write_config_by_size("fast_shared_ppo_team", study, out, path)
    assert got == {"settings": a, "by_size": {11: DEFAULT_TRIAL}}
    assert read_settings(path, 5)[0] == a and read_settings(path, 11)[0] == read_settings(path, 16)[0] == DEFAULT_TRIAL
    small_source, large_source = read_settings(path, 5)[1], read_settings(path, 16)[1]
    assert f"trial {numbers[script.settings_key(a)]} (a searched setting)" in small_source
    assert "fewer than 11 containers" in small_source and "n5_m2_dt120" in small_source
    assert "the trainer's default setting" in large_source
    assert "n11_m11_dt60, n11_m2_dt120, n16_m2_dt120" in large_source
    assert "## By plant size" in script.size_report(study, out)
    guards["settings"]["default"] = entry(DEFAULT_TRIAL, 0.5)  # now A wins the large plants too: one setting for all
    (out / "guards.json").write_text(json.dumps(guards))
    assert script.write_config_by_size("fast_shared_ppo_team", study, out, path) == {"settings": a}
    assert read_settings(path, 16)[0] == a
    source = read_settings(path, 16)[1]  # the one source names both sizes' runs and shares
    assert "fewer than 11 containers and on those of at least 11 containers" in source
    assert "n5_m2_dt120" in source and "n11_m11_dt60, n11_m2_dt120, n16_m2_dt120" in source


def test_a_comparison_reuses_another_comparisons_runs_also_from_a_file_that_names_no_gamma(tmp_path, monkeypatch):
    """--own-check beside guards.json written before the files named γ (fast_shared_ppo's): its runs are at
    the search's γ, taken from it, and nothing is trained again."""
    tuning = _load_script()
    hp = {"rollout_samples": 2048, "n_steps": 64}
    entry = _recorded_run("n11_m2_dt120", 80.0)
    (tmp_path / "guards.json").write_text(json.dumps({"settings": {"trial 1": {"params": hp, "runs": [entry]}}}))
    monkeypatch.setattr(tuning.multiprocessing, "get_context", lambda *_: pytest.fail("a recorded run trained again"))
    result = tuning.run_comparison("fast_shared_ppo", [("trial 1", hp, tuning.GAMMA)], tmp_path / "no_runs",
                                   tmp_path / "own_check.json", ["n11_m2_dt120"], [101], None, 1,
                                   {"n11_m2_dt120": 100.0}, known={})
    assert result["settings"]["trial 1"]["runs"] == [{**entry, "score": 0.8}]
    # and its guards are judged as at the search's γ (the report and --write-config read them)
    old = {"rows": ["n11_m2_dt120"], "seeds": [101],
           "settings": {"default": {"params": tuning.DEFAULT_TRIAL, "runs": [{**entry, "score": 0.9}]},
                        "trial 1": {"params": hp, "runs": [{**entry, "score": 0.8}]}}}
    assert tuning.guard_verdict(old, hp) == (False, ["n11_m2_dt120: IQM share 0.800 < the default's 0.900 - 0.05"])
