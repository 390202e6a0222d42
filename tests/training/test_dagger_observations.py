"""DAgger students that differ in what they see (``--hp observation=...``): the run records the variant
(args.json, the model files, the checkpoints), its evaluation builds the same observation (single and
batched evaluations agree), a model is refused on another observation, even one of the same size,
and a resume cannot switch the observation; bad values are refused before anything is written."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from containergym_marl.config import load_config
from containergym_marl.envs.container_agents_v0 import parallel_env
from containergym_marl.evaluation import EvalProtocol, evaluate
from containergym_marl.evaluation.batched import evaluate_batched
from containergym_marl.evaluation.run_policies import policy_from_run
from containergym_marl.policies.actor_critic import ActorCritic, policy_for
from containergym_marl.rundir import RunError, RunWarning, checkpoints
from containergym_marl.training import TrainArgs, train
from containergym_marl.training.dagger import DAggerArgs, load_checkpoint
from containergym_marl.training.train_args import memory_estimate
from tests.helpers import CFG

TINY = dict(n_envs=2, progress_bar=False, overrides={"episode_length_steps": 20})
HP = {"n_steps": 16, "minibatch_size": 64}
SHORT = EvalProtocol(episodes=3, episode_length_steps=60, first_seed=20_000)


def _model(config: str, observation: str, seed: int = 0) -> ActorCritic:
    """An untrained shared policy of ``observation``'s size on ``config`` (its weights are irrelevant here)."""
    env = parallel_env(config, observation=observation)
    size = env.observation_space(env.possible_agents[0]).shape[0]
    return ActorCritic("decentralised", size, 2, observation=observation, generator=torch.Generator().manual_seed(seed))


def test_a_student_records_its_observation_evaluates_with_it_and_is_refused_on_another(tmp_path):
    run = train(TrainArgs(algo="dagger_agents", out=str(tmp_path / "r"), timesteps=1600, seed=3,
                          checkpoint_every=480, hyperparams={**HP, "observation": "history4"}, **TINY))
    assert json.loads((run / "args.json").read_text())["hyperparams"]["observation"] == "history4"
    for name in ("best_model.pt", "final_model.pt"):
        model = ActorCritic.load(run / name)
        assert model.observation == "history4" and model.observation_size == 4 * (12 + 2 + 5)
    _, ckpt = checkpoints(run)[0]
    assert torch.load(ckpt, weights_only=True)["model"]["observation"] == "history4"

    policy = policy_from_run(run)
    assert policy.observation == "history4"
    single = evaluate(policy, CFG, SHORT, keep_records=False)
    batched = evaluate_batched(policy, CFG, SHORT)
    np.testing.assert_allclose(single.returns, batched.returns, rtol=1e-12)  # both build the history4 observation

    local = parallel_env(CFG)
    observations, _ = local.reset(seed=0)
    with pytest.raises(ValueError, match="trained on the 'history4' observation but is given the 'local' observation"):
        policy.act(observations, local)


def test_two_observations_of_the_same_size_are_told_apart_by_name():
    """At m = n, "global" (n + m entries) and "broadcast" (2n) have the same size: the shape check
    passes, the names refuse it."""
    config = "n5_m5_dt120"
    policy = policy_for(_model(config, "broadcast"), "student")
    env = parallel_env(config, observation="global")
    assert env.observation_space(env.possible_agents[0]).shape == policy.observation_space.shape
    observations, _ = env.reset(seed=0)
    with pytest.raises(ValueError, match="'broadcast' observation but is given the 'global'"):
        policy.act(observations, env)
    same = parallel_env(config, observation="broadcast")
    observations, _ = same.reset(seed=0)
    assert set(policy.act(observations, same)) == set(same.possible_agents)


def test_evaluations_build_the_policys_observation():
    """An untrained broadcast model on n11_m2: the single and the batched evaluation step the same
    episodes (with any other observation the model's input size would not fit, and both would fail)."""
    policy = policy_for(_model("n11_m2_dt120", "broadcast", seed=1), "student")
    single = evaluate(policy, "n11_m2_dt120", SHORT, keep_records=False)
    batched = evaluate_batched(policy, "n11_m2_dt120", SHORT)
    np.testing.assert_allclose(single.returns, batched.returns, rtol=1e-12)  # sums in another order
    assert [e.overflow for e in single.episodes] == [e.overflow for e in batched.episodes]


@pytest.mark.parametrize("suffix", [".pt", ".safetensors"])
def test_model_files_keep_the_observation_and_older_files_read_as_local(tmp_path, suffix):
    model = _model(CFG, "global")
    path = tmp_path / f"m{suffix}"
    (model.save if suffix == ".pt" else model.save_safetensors)(path)
    loaded = ActorCritic.load(path)
    assert loaded.observation == "global" and policy_for(loaded).observation == "global"
    older = model.to_dict()
    del older["observation"]  # a file written before the variants existed
    torch.save(older, tmp_path / "old.pt")
    assert ActorCritic.load(tmp_path / "old.pt").observation == "local"


@pytest.mark.parametrize("edit, match", [
    ({"observation": "oracle"}, r"old\.pt'?: observation: unknown observation 'oracle'"),
    ({"observation": ["global"]}, r"observation: unknown observation \['global'\]"),
    ({"view": "centralised", "n_actions": 2, "observation": "global"}, "a centralised model with the container"),
])
def test_a_model_file_with_a_bad_observation_is_refused_naming_it(tmp_path, edit, match):
    torch.save({**_model(CFG, "local").to_dict(), **edit}, tmp_path / "old.pt")
    with pytest.raises(ValueError, match=match):
        ActorCritic.load(tmp_path / "old.pt")


def test_a_resume_keeps_the_observation_and_a_checkpoint_refuses_another(tmp_path):
    out = tmp_path / "r"
    args = dict(algo="dagger_agents", out=str(out), timesteps=960, seed=1, checkpoint_every=320, **TINY)
    train(TrainArgs(**args, hyperparams={**HP, "observation": "global"}))
    before = sorted(p.name for p in out.rglob("*"))
    with pytest.raises(RunError, match=r"--resume: hp observation='local' differs from the run's observation='global'"):
        train(TrainArgs(**{**args, "timesteps": 1600}, resume=True, hyperparams={"observation": "local"}))
    assert sorted(p.name for p in out.rglob("*")) == before  # nothing set aside, nothing written
    _, ckpt = checkpoints(out)[-1]
    with pytest.raises(RunError, match="'global' observation but is given the 'local'"):
        load_checkpoint(ckpt, DAggerArgs(**HP))
    with pytest.warns(RunWarning):  # the data set is gone with the imitation's end; rows after the checkpoint
        resumed = train(TrainArgs(**{**args, "timesteps": 1600}, resume=True))  # the run's own observation
    assert ActorCritic.load(resumed / "final_model.pt").observation == "global"


@pytest.mark.parametrize("algo, hp, match", [
    ("dagger_agents", {"observation": "oracle"}, r"hp: observation: unknown observation 'oracle'"),
    ("dagger_agents", {"observation": 3}, r"hp: observation=3 is not valid \(expected a name\)"),
    ("dagger_ppo_agents", {"observation": "History4"}, "hp: observation: unknown observation 'History4'"),
    ("fast_shared_ppo", {"observation": "oracle"}, r"hp: observation: unknown observation 'oracle'"),
    ("fast_ppo", {"observation": "global"}, r"options of the native container-agent env, not of fast_ppo's"),
])
def test_a_bad_observation_setting_is_refused_before_anything_is_written(tmp_path, algo, hp, match):
    with pytest.raises(ValueError, match=match):
        train(TrainArgs(algo=algo, out=str(tmp_path / "r"), timesteps=100, hyperparams=hp, progress_bar=False))
    assert not (tmp_path / "r").exists()


def test_settings_and_memory_follow_the_observation():
    """The CLI's string parses; the data set's memory estimate counts the variant's F per sample."""
    assert DAggerArgs.from_hyperparams({"observation": "broadcast"}).observation == "broadcast"
    assert DAggerArgs().observation == "local"
    plant = load_config("n11_m2_dt120")
    n, m = 11, 2
    for observation, size in (("local", 12 + m + n), ("global", 12 + 2 * (m + n)),
                              ("history4", 4 * (12 + m + n)), ("broadcast", 12 + m + 3 * n)):
        estimate = memory_estimate(TrainArgs(algo="dagger_agents", hyperparams={"observation": observation}), plant, 64)
        assert estimate["dataset_size=1000000"] == 1_000_000 * (size * 4 + 2), observation  # F float32, label, flag
