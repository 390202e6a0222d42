"""A container agent's greedy request threshold (ActorCritic.request_threshold): a request wherever the
network's probability of requesting is above τ instead of its most likely action, carried by the model file
and applied by every greedy evaluation and by DAgger's collection."""

from __future__ import annotations

import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from containergym_marl.policies.actor_critic import ActorCritic, check_request_threshold, policy_for  # noqa: E402
from containergym_marl.training import TrainArgs, train  # noqa: E402


def _requests_with(probabilities, threshold=None) -> tuple[ActorCritic, np.ndarray]:
    """A model whose request probability is ``probabilities[i]`` on the one-hot observation e_i (one hidden
    layer of k units, unit i reading entry i: tanh(10) on e_i, 0 elsewhere), and those observations."""
    k = len(probabilities)
    model = ActorCritic("decentralised", k, 2, hidden=(k,), generator=torch.Generator().manual_seed(0),
                        request_threshold=threshold)
    logit_gap = [math.log(p / (1 - p)) for p in probabilities]  # logit(request) - logit(wait)
    with torch.no_grad():
        hidden, head = model.net.actor[0], model.net.actor[-1]
        hidden.weight.copy_(torch.eye(k) * 10.0)  # tanh(10) = 1 - 4e-9: the hidden unit i is 1 on e_i, 0 elsewhere
        hidden.bias.zero_()
        head.weight.zero_()
        head.bias.zero_()
        head.weight[1].copy_(torch.tensor(logit_gap) / math.tanh(10.0))
    return model, np.eye(k, dtype=np.float32)


PROBABILITIES = [0.05, 0.2, 0.35, 0.45, 0.55, 0.9]


@pytest.mark.parametrize("threshold, expected", [
    (None, [0, 0, 0, 0, 1, 1]),  # the most likely action
    (0.5, [0, 0, 0, 0, 1, 1]),
    (0.3, [0, 0, 1, 1, 1, 1]),
    (0.1, [0, 1, 1, 1, 1, 1]),
    (0.6, [0, 0, 0, 0, 0, 1]),
])
def test_a_greedy_agent_requests_where_its_probability_is_above_the_threshold(threshold, expected):
    model, observations = _requests_with(PROBABILITIES, threshold)
    probs = torch.softmax(model.decision_logits(torch.from_numpy(observations)), -1)[:, 1].numpy()
    assert np.allclose(probs, PROBABILITIES, atol=1e-6)  # the construction holds
    policy = policy_for(model, "thresholded")
    assert policy.act_batch(observations, None).tolist() == expected
    # sampling ignores the threshold: over many draws each agent requests at its own probability
    sampled = policy_for(model, "sampled", deterministic=False)
    torch.manual_seed(0)
    draws = np.mean([sampled.act_batch(observations, None) for _ in range(2000)], axis=0)
    assert np.allclose(draws, PROBABILITIES, atol=0.04)


def test_the_greedy_rule_is_the_probability_against_the_threshold_on_many_logits_and_after_a_change():
    """greedy() requests exactly where softmax(logits)[1] > τ, on 20,000 random logit pairs, for several τ
    set one after another on the same model (its cached shift follows the threshold)."""
    model = ActorCritic("decentralised", 3, 2, generator=torch.Generator().manual_seed(0))
    logits = torch.randn(20_000, 2, generator=torch.Generator().manual_seed(1), dtype=torch.float32) * 4
    p_request = torch.softmax(logits.double(), -1)[:, 1].numpy()
    for tau in (0.3, 0.05, 0.5, 0.3, 0.9):
        model.request_threshold = tau
        got = model.greedy(logits).numpy()
        assert got.dtype == np.int64
        far = np.abs(p_request - tau) > 1e-6  # away from float rounding at the boundary
        assert far.mean() > 0.99 and np.array_equal(got[far], (p_request[far] > tau).astype(np.int64))
    model.request_threshold = None
    assert np.array_equal(model.greedy(logits).numpy(), logits.argmax(-1).numpy())


def test_a_masked_request_is_never_made_whatever_the_threshold():
    model, observations = _requests_with([0.9, 0.9], 0.1)
    model.action_mask = True
    masks = np.array([[True, False], [True, True]])
    assert policy_for(model, "masked").act_batch(observations, masks).tolist() == [0, 1]


@pytest.mark.parametrize("value", [0, 1, 1.5, -0.2, float("nan"), True, "0.3"])
def test_a_bad_threshold_is_refused_naming_it(value):
    with pytest.raises(ValueError, match="request_threshold"):
        check_request_threshold(value)
    with pytest.raises(ValueError, match="request_threshold"):
        ActorCritic("decentralised", 14, 2, request_threshold=value)


@pytest.mark.parametrize("suffix", [".pt", ".safetensors"])
def test_the_threshold_travels_with_the_model_file_and_a_model_without_keeps_its_bytes(tmp_path, suffix):
    model, _ = _requests_with(PROBABILITIES, 0.3)
    path = tmp_path / f"m{suffix}"
    (model.save if suffix == ".pt" else model.save_safetensors)(path)
    assert ActorCritic.load(path).request_threshold == 0.3
    plain, _ = _requests_with(PROBABILITIES)
    assert "request_threshold" not in plain.to_dict()  # the file of a model without one is as before
    (plain.save if suffix == ".pt" else plain.save_safetensors)(path)
    assert ActorCritic.load(path).request_threshold is None
    with pytest.raises(ValueError, match="request_threshold"):
        ActorCritic("centralised", 7, 6, request_threshold=0.3)


def test_a_crafted_file_with_a_bad_threshold_is_refused_naming_the_field(tmp_path):
    model, _ = _requests_with(PROBABILITIES)
    data = model.to_dict()
    data["request_threshold"] = 2.0
    torch.save(data, tmp_path / "m.pt")
    with pytest.raises(ValueError, match="request_threshold: expected None or a probability"):
        ActorCritic.load(tmp_path / "m.pt")


@pytest.mark.parametrize("algo, hp", [
    ("dagger_agents", {"request_threshold": 0.0}),
    ("dagger_agents", {"request_threshold": 1.0}),
    ("dagger_agents", {"request_threshold": 0.3, "greedy": False}),  # a sampling learner has no greedy rule
    ("dagger_ppo_agents", {"request_threshold": 0.3}),  # PPO's fine-tuning: refused
])
def test_bad_threshold_settings_are_refused_before_anything_is_written(tmp_path, algo, hp):
    with pytest.raises(ValueError, match="request_threshold"):
        train(TrainArgs(algo=algo, out=str(tmp_path / "r"), timesteps=100, hyperparams=hp, progress_bar=False))
    assert not (tmp_path / "r").exists()


def test_dagger_collects_with_the_threshold_and_ships_it(tmp_path):
    """The learner acts in DAgger's collection as it is deployed: with τ, where its request probability is
    above τ; the trained model carries τ."""
    from containergym_marl.envs.vector import ContainerAgentsVecEnv
    from containergym_marl.training.checkpoints import TrainingProgress
    from containergym_marl.training.dagger import DAggerArgs, Episodes, Labeller, collect

    env = ContainerAgentsVecEnv("n5_m2_dt120", 2, episode_length_steps=60)
    env.seed(3)
    obs = torch.from_numpy(env.reset())
    model = ActorCritic("decentralised", env.observation_space.shape[0], 2, generator=torch.Generator().manual_seed(0),
                        request_threshold=0.45)
    with torch.no_grad():  # the action head says "request" with probability 0.4 whatever it sees
        model.net.actor[-1].weight.zero_()
        model.net.actor[-1].bias.copy_(torch.tensor([0.0, math.log(0.4 / 0.6)]))
    labeller = Labeller(env.num_sims, DAggerArgs(), 3)
    collected = {}
    for tau in (0.45, 0.35):
        model.request_threshold = tau
        rollout, *_ = collect(model, env, obs, torch.ones(env.num_envs), labeller, 5, 0.99,
                              torch.Generator().manual_seed(1), expert_acts=False, greedy=True,
                              episodes=Episodes(env.num_sims, TrainingProgress()), labels="planner")
        collected[tau] = rollout.actions.reshape(-1).tolist()
    assert set(collected[0.45]) == {0} and set(collected[0.35]) == {1}

    run = train(TrainArgs(algo="dagger_agents", config="n5_m2_dt120", out=str(tmp_path / "r"), timesteps=640,
                          n_envs=2, progress_bar=False, overrides={"episode_length_steps": 20},
                          hyperparams={"n_steps": 16, "minibatch_size": 64, "request_threshold": 0.3}))
    assert ActorCritic.load(run / "final_model.pt").request_threshold == 0.3
