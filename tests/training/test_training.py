"""Training runs: save/load/evaluate, determinism, resume, overwrite protection, clear errors."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from containergym_marl import ConfigError, load_config
from containergym_marl.cli import main as cli_main
from containergym_marl.evaluation import EvalProtocol, evaluate
from containergym_marl.policies import CentralisedModelPolicy, SharedModelPolicy
from containergym_marl.evaluation.run_policies import evaluate_run
from containergym_marl.training import RunError, TrainArgs, train
from containergym_marl.rundir import latest_checkpoint, read_metrics
from containergym_marl.models import load_model

NO_EPISODE = pytest.mark.filterwarnings(  # TINY runs end no training episode: "best" is the final model
    "ignore:.*no training episode finished:containergym_marl.rundir.RunWarning")
TINY = dict(timesteps=512, n_envs=2, checkpoint_every=128, progress_bar=False,
            hyperparams={"n_steps": 64, "batch_size": 64})
SHORT = EvalProtocol(episodes=3)


def test_save_load_evaluate_gives_identical_numbers(tmp_path):
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import configure

    from containergym_marl.envs.vector import ContainerAgentsVecEnv, ContainerGymVecEnv

    for venv, policy_cls in ((ContainerGymVecEnv("n5_m2_dt120", 2), CentralisedModelPolicy),
                             (ContainerAgentsVecEnv("n5_m2_dt120", 2), SharedModelPolicy)):
        model = PPO("MlpPolicy", venv, n_steps=64, batch_size=64, seed=0, device="cpu")
        model.set_logger(configure(str(tmp_path / "log"), []))  # no SB3-<date> folder in the temp dir
        model.learn(256)
        before = evaluate(policy_cls(model), "n5_m2_dt120", SHORT)
        model.save(tmp_path / "m.zip")
        after = evaluate(policy_cls(PPO.load(tmp_path / "m.zip", device="cpu")), "n5_m2_dt120", SHORT)
        np.testing.assert_array_equal(before.returns, after.returns)
        assert [e.emptyings for e in before.episodes] == [e.emptyings for e in after.episodes]


@NO_EPISODE
def test_evaluation_is_deterministic_and_uses_fixed_seeds(tmp_path):
    run = train(TrainArgs(algo="ppo", out=str(tmp_path / "r"), **TINY))
    a = evaluate_run(run, protocol=SHORT, write=False)
    b = evaluate_run(run, protocol=SHORT, write=False)
    np.testing.assert_array_equal(a.returns, b.returns)
    assert [e.seed for e in a.episodes] == [10_000, 10_001, 10_002]


def test_run_directory_contents_and_metrics(tmp_path):
    run = train(TrainArgs(algo="ppo", out=str(tmp_path / "r"), **{**TINY, "overrides": {"episode_length_steps": 50}}))
    names = {p.name for p in run.iterdir()}
    assert {"args.json", "config.toml", "metrics.csv", "best_model.zip", "final_model.zip", "checkpoints", "tb"} <= names
    rows = read_metrics(run)
    assert rows and rows[-1]["timesteps"] >= 512
    # short training episodes (T = 50) finish, so the best-model tracker saw plant returns
    assert rows[-1]["episodes"] > 0 and np.isfinite(rows[-1]["best_train_return"])
    saved = json.loads((run / "args.json").read_text())
    assert saved["overrides"] == {"episode_length_steps": 50}
    assert "episode_length_steps = 50" in (run / "config.toml").read_text()


def test_resume_continues_the_step_count(tmp_path):
    out = tmp_path / "r"
    run = train(TrainArgs(algo="ppo", out=str(out), **TINY))
    ckpt, steps = latest_checkpoint(run)
    assert steps >= 128
    first_final = load_model(run / "final_model.zip", "ppo").num_timesteps
    # an interrupted run: drop the final model, resume towards a larger budget
    os.remove(run / "final_model.zip")
    train(TrainArgs(algo="ppo", out=str(out), resume=True, **{**TINY, "timesteps": 1024}))
    resumed = load_model(run / "final_model.zip", "ppo").num_timesteps
    assert resumed >= 1024 and resumed > first_final
    assert latest_checkpoint(run)[1] > steps


def test_refuses_to_overwrite_a_run_with_results(tmp_path):
    out = tmp_path / "r"
    run = train(TrainArgs(algo="ppo", out=str(out), **TINY))
    stamp = (run / "final_model.zip").stat().st_mtime_ns
    with pytest.raises(RunError, match="refusing to overwrite"):
        train(TrainArgs(algo="ppo", out=str(out), **TINY))
    assert (run / "final_model.zip").stat().st_mtime_ns == stamp
    with pytest.raises(RunError, match="seed"):
        train(TrainArgs(algo="ppo", out=str(out), resume=True, **{**TINY, "seed": 99}))
    with pytest.raises(RunError, match="nothing to resume"):
        train(TrainArgs(algo="ppo", out=str(tmp_path / "empty"), resume=True, **TINY))


@NO_EPISODE
def test_clear_errors_for_unknown_algorithm_config_and_mismatched_model(tmp_path, capsys):
    with pytest.raises(ValueError, match="unknown algorithm 'a2c'"):
        train(TrainArgs(algo="a2c", out=str(tmp_path / "a")))
    with pytest.raises(ConfigError, match="unknown config 'n7_m3'"):
        train(TrainArgs(algo="ppo", config="n7_m3", out=str(tmp_path / "b")))
    assert not (tmp_path / "b").exists()  # nothing half-built
    run = train(TrainArgs(algo="ppo", out=str(tmp_path / "c"), **TINY))
    with pytest.raises(ValueError, match=r"expects observations of shape \(7,\).*\(13,\)"):
        evaluate_run(run, config="n11_m2_dt120", protocol=SHORT, write=False)
    assert cli_main(["evaluate", str(run), "--config", "n11_m2_dt120", "--episodes", "1"]) == 2
    assert "expects observations of shape" in capsys.readouterr().err


def test_unreadable_checkpoint_gives_a_clear_error(tmp_path):
    bad = tmp_path / "broken.zip"
    bad.write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match="cannot read model file .*broken.zip"):
        load_model(bad, "ppo")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_model(tmp_path / "missing.zip", "ppo")


def test_cli_train_and_evaluate(tmp_path, capsys):
    out = tmp_path / "cli"
    assert cli_main(["train", "--algo", "shared_ppo", "--timesteps", "256", "--n-envs", "1", "--out", str(out),
                     "--no-progress", "--hp", "n_steps=64", "--override", "episode_length_steps=40"]) == 0
    assert cli_main(["evaluate", str(out), "--episodes", "2", "--json", str(tmp_path / "e.json")]) == 0
    report = json.loads((tmp_path / "e.json").read_text())
    assert report["view"] == "decentralised" and len(report["episodes"]) == 2
    assert report["protocol"]["timestep_s"] == 120.0 and report["protocol"]["episode_length_steps"] == 600
    with pytest.raises(SystemExit, match="neither a run directory nor a built-in policy"):
        cli_main(["evaluate", "no_such_policy"])
    with pytest.raises(SystemExit):
        cli_main(["train", "--algo", "a2c"])


def test_default_budget_is_the_papers():
    from containergym_marl.training import paper_budget

    assert paper_budget(load_config("n5_m2_dt120").n_containers) == 2_000_000
    assert paper_budget(load_config("n11_m2_dt120").n_containers) == 5_000_000
    assert TrainArgs(algo="ppo").timesteps is None  # resolved from the plant in train()


def test_training_uses_fused_adam_unless_the_caller_overrides_it(tmp_path):
    """The run's model really has Adam's fused kernel with every other setting of SB3's default
    optimizer (its actor-critic policies use eps = 1e-5); --hp policy_kwargs replaces it key by
    key; torch.distributions' checks are off only during learn."""
    import torch
    from stable_baselines3 import DQN, PPO

    from containergym_marl.envs.vector import ContainerGymVecEnv
    from containergym_marl.training.loop import algorithm_kwargs

    before = torch.distributions.Distribution._validate_args
    run = train(TrainArgs(algo="ppo", out=str(tmp_path / "ppo"), **TINY))
    model = load_model(run / "final_model.zip", algo="ppo")
    venv = ContainerGymVecEnv("n5_m2_dt120", 2)
    for algo, cls in (("ppo", PPO), ("dqn", DQN)):
        ours = model if algo == "ppo" else cls("MlpPolicy", venv, device="cpu", **algorithm_kwargs(
            TrainArgs(algo="dqn"), 2))
        sb3 = cls("MlpPolicy", venv, device="cpu")  # SB3's own optimizer settings
        mine, theirs = dict(ours.policy.optimizer.defaults), dict(sb3.policy.optimizer.defaults)
        assert mine.pop("fused") is True and not theirs.pop("fused")
        assert mine == theirs, algo  # same lr, betas, eps, weight decay, ...
    assert torch.distributions.Distribution._validate_args == before  # restored after learn

    args = TrainArgs(algo="ppo", hyperparams={"policy_kwargs": {"optimizer_kwargs": {}, "net_arch": [32]}})
    kwargs = algorithm_kwargs(args, num_slots=8)
    assert kwargs["policy_kwargs"] == {"optimizer_kwargs": {}, "net_arch": [32]}
    assert kwargs["n_steps"] == 768 and kwargs["batch_size"] == 64
