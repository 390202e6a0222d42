"""studies/request_threshold.py on a short run: each threshold's numbers are a batched evaluation of the
run's standing model with that threshold on the validation episodes from seed 20100, a rerun reuses them,
and a centralised run is refused before anything is written."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("torch")

from containergym_marl.evaluation import EvalProtocol  # noqa: E402
from containergym_marl.evaluation.batched import evaluate_batched  # noqa: E402
from containergym_marl.evaluation.run_policies import policy_from_run  # noqa: E402
from containergym_marl.training import TrainArgs, train  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
SCRIPT = str(REPO / "studies" / "request_threshold.py")


def _run(tmp_path: Path, algo: str) -> Path:
    return train(TrainArgs(algo=algo, out=str(tmp_path / f"tiny_{algo}_run"), timesteps=1200, n_envs=2, seed=3,
                           progress_bar=False, hyperparams={"n_steps": 16, "minibatch_size": 80},
                           overrides={"episode_length_steps": 20}))


def test_each_threshold_is_the_models_evaluation_with_it_and_a_rerun_reuses_them(tmp_path):
    run, out = _run(tmp_path, "fast_shared_ppo"), tmp_path / "out"
    command = [sys.executable, SCRIPT, str(run), "--episodes", "2", "--thresholds", "0.5", "0.05", "--out", str(out)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    store = json.loads((out / "thresholds.json").read_text())
    entry = store["runs"][run.name]
    assert (entry["row"], entry["episodes"], entry["first_seed"], entry["model"]) == ("n5_m2_dt120", 2, 20_100, "best")
    protocol = EvalProtocol(episodes=2, first_seed=20_100)
    for tau in (0.5, 0.05):
        policy = policy_from_run(run, "best")
        policy.model.request_threshold = None if tau == 0.5 else tau
        expected = evaluate_batched(policy, "n5_m2_dt120", protocol)
        assert entry["thresholds"][str(tau)]["return_mean"] == pytest.approx(float(expected.returns.mean()))
        assert entry["thresholds"][str(tau)]["overflowing_episodes"] == sum(e.overflow for e in expected.episodes)
    assert store["references"]["n5_m2_dt120"]["episodes"] == 2
    assert "| fast_shared_ppo | n5_m2_dt120 | 1 × 2 |" in (out / "thresholds.md").read_text()
    again = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0 and run.name not in again.stdout  # nothing evaluated again


def test_a_centralised_run_is_refused_before_anything_is_written(tmp_path):
    run, out = _run(tmp_path, "fast_ppo"), tmp_path / "out"
    done = subprocess.run([sys.executable, SCRIPT, str(run), "--out", str(out)], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 2 and "fast_ppo run" in done.stderr
    assert not out.exists()


def test_two_runs_of_one_name_are_refused_before_anything_is_written(tmp_path):
    # the stores key each run by its folder's name: the second run would overwrite the first's numbers (refused
    # before either folder is read, so two empty folders stand for the runs)
    run, twin, out = tmp_path / "a" / "tiny_run_s3", tmp_path / "other" / "tiny_run_s3", tmp_path / "out"
    run.mkdir(parents=True)
    twin.mkdir(parents=True)
    done = subprocess.run([sys.executable, SCRIPT, str(run), str(twin), "--episodes", "1", "--out", str(out)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and f"two runs named {run.name!r}" in done.stderr, done.stderr
    assert not out.exists()


def test_the_fresh_report_sets_both_decision_rules_against_the_reference(tmp_path):
    """``--fresh τ``: the run's model as trained and with τ on the published fresh episodes, as a batched
    evaluation of each gives, as shares of the reference's fresh mean read from ``--results``; refused
    before anything is written where that file is missing."""
    from containergym_marl.evaluation.protocol import FRESH

    run, out, results = _run(tmp_path, "fast_shared_ppo"), tmp_path / "out", tmp_path / "results"
    command = [sys.executable, SCRIPT, str(run), "--fresh", "0.2", "--out", str(out), "--results", str(results)]
    refused = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert refused.returncode == 2 and "planner_agents_shielded" in refused.stderr and not out.exists()
    reference = results / "fresh" / "n5_m2_dt120" / "planner_agents_shielded.json"
    reference.parent.mkdir(parents=True)
    reference.write_text(json.dumps({"summary": {"return_mean": 50.0}}))
    done = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    row = json.loads((out / "fresh_summary.json").read_text())["rows"][0]
    for label, tau in (("as_trained", None), ("threshold", 0.2)):
        policy = policy_from_run(run, "best")
        policy.model.request_threshold = tau
        expected = evaluate_batched(policy, "n5_m2_dt120", FRESH)
        assert row[label]["iqm_share"] == pytest.approx(float(expected.returns.mean()) / 50.0)
        assert row[label]["overflow_rate"] == pytest.approx(sum(e.overflow for e in expected.episodes) / 200)


def test_the_own_check_goes_into_every_policy_evaluated_and_a_bad_one_is_refused(tmp_path):
    run, out = _run(tmp_path, "fast_shared_ppo"), tmp_path / "out"
    base = [sys.executable, SCRIPT, str(run), "--episodes", "2", "--thresholds", "0.3", "--out", str(out)]
    refused = subprocess.run(base + ["--own-check", "1e-4"], capture_output=True, text=True, timeout=120)
    assert refused.returncode == 2 and "--own-check" in refused.stderr and not out.exists()
    done = subprocess.run(base + ["--own-check", "0.2:0"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    entry = json.loads((out / "thresholds.json").read_text())["runs"][run.name]
    assert entry["own_check"] == {"risk": 0.2, "lead_steps": 0}
    policy = policy_from_run(run, "best")
    policy.model.request_threshold, policy.model.own_check = 0.3, {"risk": 0.2, "lead_steps": 0}
    expected = evaluate_batched(policy, "n5_m2_dt120", EvalProtocol(episodes=2, first_seed=20_100))
    assert entry["thresholds"]["0.3"]["return_mean"] == pytest.approx(float(expected.returns.mean()))
    assert "own check 0.2:0 in every policy" in (out / "thresholds.md").read_text()
