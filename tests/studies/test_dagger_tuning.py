"""studies/dagger_tuning.py at its smoke size: trains two variants, evaluates them on validation
episodes, and after a deadline that stops a run early still evaluates its best model so far."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers import sigterm_leaves_no_child

REPO = Path(__file__).resolve().parents[2]
SCRIPT = str(REPO / "studies" / "dagger_tuning.py")


@pytest.mark.slow  # a study's end-to-end smoke run, ~30 s
def test_smoke_run_evaluates_each_variant_on_validation_seeds(tmp_path):
    out, runs = tmp_path / "out", tmp_path / "runs"
    subprocess.run([sys.executable, SCRIPT, "--smoke", "--workers", "2", "--out", str(out), "--runs", str(runs)],
                   capture_output=True, text=True, timeout=300, check=True)
    saved = json.loads((out / "tuning.json").read_text())
    assert saved["variants"] == {name: {"hp": [hp], "method": "dagger_agents", "reward_mode": None}
                                 for name, hp in (("sampled", "greedy=false"), ("greedy", "greedy=true"))}
    found = {(e["variant"], e["model"]) for e in saved["evaluations"]}
    assert found == {(v, m) for v in ("sampled", "greedy") for m in ("best", "final")}
    for e in saved["evaluations"]:
        assert e["first_seed"] == 20_000 and e["episodes"] == 2 == len(e["returns"])
        assert e["finished"] and e["trained_samples"] >= 20_000
    args = json.loads((runs / "greedy" / "dagger_agents_n5_m2_dt120_s1" / "args.json").read_text())
    assert args["hyperparams"] == {"greedy": True}
    assert "| greedy | greedy=true | n5_m2_dt120 | 1 |" in (out / "tuning.md").read_text()


@pytest.mark.slow  # trains and evaluates a study run, ~30 s
def test_a_run_stopped_by_the_deadline_is_evaluated_by_its_best_model(tmp_path):
    out, runs = tmp_path / "out", tmp_path / "runs"
    common = [sys.executable, SCRIPT, "--variants", "greedy", "--rows", "n5_m2_dt120", "--seeds", "1",
              "--episodes", "2", "--workers", "1", "--out", str(out), "--runs", str(runs), "--timesteps", "5000000"]
    run = runs / "greedy" / "dagger_agents_n5_m2_dt120_s1"
    # The deadline is wall time, so how far a run gets by it depends on the machine's load: a deadline
    # that fires before the first training episode leaves no model. Each next call resumes the run
    # with twice the deadline, until one fires after its best model was saved (on an idle machine:
    # the first); what is asserted is what the script does with a run the deadline stopped.
    for deadline_s in (30, 60, 120, 240, 480):
        done = subprocess.run([*common, "--deadline-s", str(deadline_s)], capture_output=True, text=True,
                              timeout=deadline_s + 1800)
        if (run / "best_model.pt").exists():
            break
    assert done.returncode == 0, done.stderr[-2000:]
    assert not (run / "final_model.pt").exists() and (run / "best_model.pt").exists()
    saved = json.loads((out / "tuning.json").read_text())
    [entry] = saved["evaluations"]
    assert entry["model"] == "best" and not entry["finished"] and 0 < entry["trained_samples"] < 5_000_000


@pytest.mark.slow  # trains a study run, ~20 s
def test_a_fine_tuning_variant_trains_its_method_with_its_reward_mode(tmp_path):
    out, runs = tmp_path / "out", tmp_path / "runs"
    subprocess.run([sys.executable, SCRIPT, "--variants", "ppo_team_share_0.5", "--rows", "n5_m2_dt120", "--seeds", "1",
                    "--episodes", "2", "--workers", "1", "--out", str(out), "--runs", str(runs), "--timesteps", "20000"],
                   capture_output=True, text=True, timeout=300, check=True)
    run = runs / "ppo_team_share_0.5" / "dagger_ppo_agents_n5_m2_dt120_s1"
    args = json.loads((run / "args.json").read_text())
    assert (args["algo"], args["reward_mode"]) == ("dagger_ppo_agents", "team")
    assert args["hyperparams"] == {"imitation_share": 0.5}
    assert (run / "imitation.json").is_file() and (run / "final_model.pt").is_file()
    md = (out / "tuning.md").read_text()
    assert "| ppo_team_share_0.5 | dagger_ppo_agents --reward-mode team imitation_share=0.5 | n5_m2_dt120 | 1 |" in md


def test_an_evaluation_made_before_its_run_finished_is_dropped_once_it_has(tmp_path, monkeypatch):
    """A run stopped early (a deadline, a kill) is evaluated by its best model so far; once it has been
    resumed to its end, that evaluation no longer stands for it and the finished run is evaluated."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("dagger_tuning", SCRIPT)
    script = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, script)  # its dataclasses look their module up there
    spec.loader.exec_module(script)
    runs = tmp_path / "runs"
    entries = [{"variant": "greedy", "row": row, "seed": 1, "model": "best", "finished": done}
               for row, done in (("n11_m2_dt60", False), ("n11_m2_dt120", False), ("n16_m2_dt120", True))]
    assert script.without_stale(entries, runs) == entries  # no run folder here: every evaluation stands
    for row in ("n11_m2_dt60", "n16_m2_dt120"):  # these two runs have finished since
        run = script.run_dir(runs, "greedy", row, 1)
        run.mkdir(parents=True)
        (run / "args.json").write_text(json.dumps({"algo": "dagger_agents"}))
        (run / "final_model.pt").write_bytes(b"")
    assert script.finished(script.run_dir(runs, "greedy", "n11_m2_dt60", 1))
    assert script.without_stale(entries, runs) == entries[1:]


@pytest.mark.slow  # starts a study's training and stops it, ~10 s
def test_a_sigterm_to_the_study_stops_its_training_processes_before_it_exits(tmp_path):
    """A killed study's `train` processes must not outlive it: run again, the study would find their
    run folders locked (and, before the fix, evaluate their best models so far as the runs' results)."""
    pytest.importorskip("psutil")
    sigterm_leaves_no_child([SCRIPT, "--variants", "greedy", "--rows", "n5_m2_dt120", "--seeds", "1", "2",
                             "--workers", "2", "--episodes", "2", "--out", str(tmp_path / "out"), "--runs",
                             str(tmp_path / "runs")], lambda cmd: " train " in f"{cmd} ", count=2)


def test_every_variant_is_a_valid_setting_of_its_method():
    """Each variant's --hp settings parse and pass its method's trainer checks (a typo in a key, or a
    combination the trainer refuses, fails here rather than after a study has started)."""
    from containergym_marl.algorithms import get_algorithm
    from containergym_marl.methods import METHODS
    from containergym_marl.options import key_values
    from tests.helpers import load_script

    study = load_script(SCRIPT)
    for name, variant in study.VARIANTS.items():
        trainer = get_algorithm(METHODS[variant.method].algo).trainer()
        trainer.settings(key_values(list(variant.hp), "--hp"))  # raises, naming the key, where one is bad


def test_checked_lead_2_is_what_dagger_checked_agents_trains_on_n11_m2_dt60():
    """The variant the study compares the longer look-ahead with stands for the published
    dagger_checked_agents runs of n11_m2_dt60 (their models are its seeds): the method's defaults with its
    settings file's entry for that plant, and nothing else changed."""
    from containergym_marl.config.hyperparams import plant_settings
    from containergym_marl.config.loading import load_config
    from containergym_marl.options import key_values
    from containergym_marl.training.dagger import CHECKED_SETTINGS
    from tests.helpers import load_script

    study = load_script(SCRIPT)
    variant = key_values(list(study.VARIANTS["checked_lead_2"].hp), "--hp")
    published = {"greedy": True, **CHECKED_SETTINGS,
                 **plant_settings("dagger_checked_agents", load_config("n11_m2_dt60"))}
    assert published["own_check_lead_steps"] == 2
    assert {k: float(v) if k != "greedy" else v for k, v in variant.items()} == \
        {k: float(v) if k != "greedy" else v for k, v in published.items()}
    longer = key_values(list(study.VARIANTS["checked_lead_2_h16"].hp), "--hp")
    assert longer == {**variant, "horizon": 16}
