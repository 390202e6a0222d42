"""Every baseline script runs end to end with a tiny budget (CleanRL-style smoke tests)."""

from __future__ import annotations

import json
import runpy
import sys
from pathlib import Path

import pytest

from containergym_marl.training import ALGORITHMS, get_algorithm

BASELINES = Path(__file__).resolve().parents[1] / "baselines"
# a tiny budget may end no training episode: evaluating "best" then warns and uses the final model
pytestmark = pytest.mark.filterwarnings(
    "ignore:.*no training episode finished:containergym_marl.training.runs.RunWarning")


def run_script(name: str, argv: list[str]) -> dict:
    old = sys.argv
    sys.argv = [str(BASELINES / name), *argv]
    try:
        namespace = runpy.run_path(str(BASELINES / name), run_name="not_main")
        args = namespace["parse_args"](namespace["Args"], argv)
        return namespace["main"](args)
    finally:
        sys.argv = old


@pytest.mark.parametrize("algo", ALGORITHMS)
def test_learning_baseline_trains_and_evaluates(tmp_path, algo):
    out = tmp_path / "run"
    results = run_script("train_baseline.py", ["--algo", algo, "--timesteps", "256", "--n-envs", "2",
                                               "--episodes", "2", "--out", str(out), "--no-progress-bar"])
    assert set(results) == {"best", "final"}
    for result in results.values():
        assert len(result.episodes) == 2
        assert all(1 <= e.steps <= 600 for e in result.episodes)  # the paper's test protocol
    saved = json.loads((out / "args.json").read_text())
    assert saved["algo"] == algo and saved["n_envs"] == 2
    spec = get_algorithm(algo)
    assert (out / spec.model_file("final")).is_file()
    # a best model exactly when a training episode finished (run.json says which)
    summary = json.loads((out / "run.json").read_text())
    assert (out / spec.model_file("best")).is_file() == (summary["episodes"] > 0)
    assert (out / "evaluation_best.json").is_file()


def test_shared_ppo_script_through_supersuit(tmp_path):
    results = run_script("train_baseline.py", ["--algo", "shared_ppo", "--timesteps", "256", "--n-envs", "2",
                                               "--episodes", "1", "--vec", "supersuit", "--out", str(tmp_path / "r"),
                                               "--no-progress-bar"])
    assert results["final"].view == "decentralised"


def test_rule_based_script():
    results = run_script("rule_based.py", ["--episodes", "2"])
    assert set(results) == {"rule_based", "rule_based_agents"}
    # the rule keeps n5_m2_dt120 alive for the whole test episode with mostly good emptyings
    for result in results.values():
        s = result.summary()
        assert s["overflow_rate"] == 0.0 and s["good_emptying_share"] > 0.8
