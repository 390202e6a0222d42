"""studies/model_choice.py on a short run: its three models on the same validation episodes past the
curve's (as a batched evaluation of each gives), a rerun reuses them, a run without a validated model
is refused before anything is written."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from containergym_marl.evaluation import EvalProtocol
from containergym_marl.evaluation.batched import evaluate_batched
from containergym_marl.evaluation.curves import run_curve
from containergym_marl.evaluation.run_policies import policy_from_run
from containergym_marl.training import TrainArgs, train

REPO = Path(__file__).resolve().parents[2]
SCRIPT = str(REPO / "studies" / "model_choice.py")


def _run(tmp_path: Path, curve: bool) -> Path:
    run = train(TrainArgs(algo="fast_shared_ppo", out=str(tmp_path / f"r{int(curve)}"), timesteps=3000, n_envs=2,
                          seed=3, checkpoint_every=600, progress_bar=False,
                          hyperparams={"n_steps": 16, "minibatch_size": 80}, overrides={"episode_length_steps": 20}))
    if curve:
        run_curve(run, EvalProtocol(episodes=2, first_seed=20_000, episode_length_steps=30))
    return run


def test_three_models_on_the_same_episodes_and_a_rerun_reuses_them(tmp_path):
    run, out = _run(tmp_path, curve=True), tmp_path / "out"
    done = subprocess.run([sys.executable, SCRIPT, str(run), "--episodes", "3", "--out", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    entry = json.loads((out / "model_choice.json").read_text())[run.name]
    assert (entry["row"], entry["episodes"], entry["first_seed"]) == ("n5_m2_dt120", 3, 20_100)
    for which in ("validated", "best", "final"):
        result = evaluate_batched(policy_from_run(run, which), "n5_m2_dt120", EvalProtocol(episodes=3, first_seed=20_100))
        assert entry[which]["return_mean"] == pytest.approx(float(result.returns.mean()))
        assert entry[which]["overflowing_episodes"] == sum(e.overflow for e in result.episodes)
    assert entry["method"] == "fast_shared_ppo"
    assert "| fast_shared_ppo | n5_m2_dt120 | 1 |" in (out / "model_choice.md").read_text()
    again = subprocess.run([sys.executable, SCRIPT, str(run), "--episodes", "3", "--out", str(out)],
                           capture_output=True, text=True, timeout=300)
    assert again.returncode == 0 and run.name not in again.stdout.split("# Which")[0]  # nothing evaluated again


def test_a_run_without_a_validated_model_is_refused_before_anything_is_written(tmp_path):
    run = _run(tmp_path, curve=False)
    done = subprocess.run([sys.executable, SCRIPT, str(run), "--out", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode != 0 and "has no validated_model.pt" in done.stderr and not (tmp_path / "out").exists()


def test_two_runs_of_one_name_are_refused_before_anything_is_written(tmp_path):
    # its store keys runs by their folder's name: the second would replace the first's numbers
    first, second = tmp_path / "a" / "run_s1", tmp_path / "b" / "run_s1"
    first.mkdir(parents=True)
    second.mkdir(parents=True)
    done = subprocess.run([sys.executable, SCRIPT, str(first), str(second), "--out", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "two runs named 'run_s1'" in done.stderr and str(second) in done.stderr
    assert not (tmp_path / "out").exists()


def test_the_same_run_twice_is_one_run(tmp_path):
    from containergym_marl.rundir import check_distinct_names

    run = tmp_path / "run_s1"
    run.mkdir()
    check_distinct_names([run, tmp_path / "." / "run_s1"])  # one folder, two spellings: nothing to refuse
    with pytest.raises(ValueError, match="two runs named 'run_s1'"):
        check_distinct_names([run, tmp_path / "copy" / "run_s1"])
