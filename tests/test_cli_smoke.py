"""Every algorithm trains and is evaluated through the command line with a tiny budget (CleanRL-style
smoke tests of ``containergym-marl train --evaluate`` and ``evaluate``)."""

from __future__ import annotations

import json

import pytest

from containergym_marl.cli import main
from containergym_marl.training import ALGORITHMS, get_algorithm

# a tiny budget may end no training episode: evaluating "best" then warns and uses the final model
pytestmark = pytest.mark.filterwarnings(
    "ignore:.*no training episode finished:containergym_marl.rundir.RunWarning")


def _evaluation(path) -> dict:
    data = json.loads(path.read_text())
    assert len(data["episodes"]) == 2
    assert all(1 <= e["steps"] <= 600 for e in data["episodes"])  # the paper's test protocol: T = 600
    return data


@pytest.mark.parametrize("algo", ALGORITHMS)
def test_every_algorithm_trains_and_is_evaluated_from_the_command_line(tmp_path, algo):
    out = tmp_path / "run"
    assert main(["train", "--algo", algo, "--timesteps", "256", "--n-envs", "2", "--out", str(out),
                 "--no-progress", "--evaluate", "--episodes", "2", "--json", str(tmp_path / "e.json")]) == 0
    _evaluation(tmp_path / "e.json")
    saved = json.loads((out / "args.json").read_text())
    assert saved["algo"] == algo and saved["n_envs"] == 2 and saved["timesteps"] == 256
    spec = get_algorithm(algo)
    assert (out / spec.model_file("final")).is_file()
    # a best model exactly when a training episode finished (run.json says which)
    summary = json.loads((out / "run.json").read_text())
    assert (out / spec.model_file("best")).is_file() == (summary["episodes"] > 0)
    assert main(["evaluate", str(out), "--model", "final", "--episodes", "2", "--json", str(tmp_path / "f.json")]) == 0
    assert _evaluation(tmp_path / "f.json")["policy"]


def test_shared_ppo_trains_through_supersuit_from_the_command_line(tmp_path):
    out = tmp_path / "r"
    assert main(["train", "--algo", "shared_ppo", "--timesteps", "256", "--n-envs", "2", "--vec", "supersuit",
                 "--out", str(out), "--no-progress"]) == 0
    assert json.loads((out / "args.json").read_text())["vec"] == "supersuit"


@pytest.mark.parametrize("controller", ["rule_based", "rule_based_agents"])
def test_the_rule_based_controllers_keep_n5_m2_alive(tmp_path, controller):
    path = tmp_path / f"{controller}.json"
    assert main(["evaluate", controller, "--config", "n5_m2_dt120", "--episodes", "2", "--json", str(path)]) == 0
    data = _evaluation(path)
    # the rule keeps n5_m2_dt120 alive for the whole test episode with mostly good emptyings
    assert not any(e["overflow"] for e in data["episodes"])
    assert all(e["steps"] == 600 for e in data["episodes"])


def test_bad_key_values_are_refused_naming_the_option(tmp_path, capsys):
    assert main(["train", "--algo", "ppo", "--hp", "learning_rate", "--out", str(tmp_path / "x")]) == 2
    assert "--hp: expected KEY=VALUE, got 'learning_rate'" in capsys.readouterr().err
    assert main(["train", "--algo", "ppo", "--override", "a=1", "a=2", "--out", str(tmp_path / "x")]) == 2
    assert "--override: a given more than once" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_evaluate_runs_a_learned_policy_on_one_torch_thread(tmp_path):
    """`evaluate RUN` takes one torch thread, as training does: with two, on a busy machine, each
    forward of the small networks waited for the second (an SB3 evaluation took 7x as long)."""
    import torch

    out = tmp_path / "run"
    assert main(["train", "--algo", "fast_ppo", "--timesteps", "256", "--n-envs", "2", "--out", str(out),
                 "--no-progress"]) == 0
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        assert main(["evaluate", str(out), "--model", "final", "--episodes", "1", "--no-write"]) == 0
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)
