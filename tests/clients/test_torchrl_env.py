"""The batched TorchRL environment (``containergym_marl.envs.torchrl_env``).

* TorchRL's ``check_env_specs`` and rollouts with autoreset, for both action encodings.
* B batched simulations equal B ``container_agents_v0.parallel_env`` environments seeded
  ``seed + b``, step for step through ends and autoresets: observations, masks, normalised state,
  rewards (individual and team), terminated/truncated and infos.
* Partial resets through ``"_reset"`` masks touch only the masked simulations; seeding.

Needs torchrl (skipped without it; the ``clients`` extra installs it).
"""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")
from tensordict import TensorDict  # noqa: E402
from torchrl.envs.utils import check_env_specs  # noqa: E402

from containergym_marl import container_agents_v0  # noqa: E402
from containergym_marl.envs.torchrl_env import GROUP, ContainerAgentsTorchRLEnv  # noqa: E402
from tests.helpers import CFG  # noqa: E402

# both kinds of ends within a few dozen steps: time limits and overflows (full starting volumes)
ENDS = dict(episode_length_steps=20, initial_volume_min=25.0, initial_volume_max=39.5)


@pytest.mark.parametrize("categorical", [True, False], ids=["categorical", "one_hot"])
def test_check_env_specs_and_autoreset_rollout(categorical):
    env = ContainerAgentsTorchRLEnv(CFG, num_envs=4, categorical_actions=categorical, **ENDS)
    check_env_specs(env, seed=0)
    td = env.rollout(45, break_when_any_done=False)
    n, F = 5, 12 + 2 + 5
    assert td.batch_size == (4, 45)
    assert td[GROUP, "observation"].shape == (4, 45, n, F)
    assert td["next", GROUP, "reward"].shape == (4, 45, n, 1)
    assert td["next", GROUP, "done"].shape == (4, 45, n, 1) and td["next", "done"].shape == (4, 45, 1)
    assert td["state"].shape == (4, 45, n + 2) and td[GROUP, "action_mask"].shape == (4, 45, n, 2)
    assert td[GROUP, "action"].shape == ((4, 45, n) if categorical else (4, 45, n, 2))
    # episodes of at most 20 steps: every simulation ended at least twice and carried on
    assert (td["next", "done"].sum(dim=(1, 2)) >= 2).all()
    # the group's end flags are the simulation's, for every agent
    assert torch.equal(td["next", GROUP, "done"], td["next", "done"][:, :, None].expand(4, 45, n, 1))
    assert env.group_map == {GROUP: [f"container_{i}" for i in range(n)]}


def _pz_envs(B, seed, reward_mode, **config):
    envs = [container_agents_v0.parallel_env(CFG, agent_names="indexed", observation_mode="dict",
                                             state_mode="normalised", reward_mode=reward_mode, **config)
            for _ in range(B)]
    obs = [e.reset(seed=seed + b)[0] for b, e in enumerate(envs)]
    return envs, obs


def _assert_root_matches(td, envs, obs):
    for b, (e, o) in enumerate(zip(envs, obs)):
        agents = e.possible_agents
        np.testing.assert_array_equal(td[GROUP, "observation"][b].numpy(), np.stack([o[a]["observation"] for a in agents]))
        np.testing.assert_array_equal(td[GROUP, "action_mask"][b].numpy(), np.stack([o[a]["action_mask"] for a in agents]) == 1)
        np.testing.assert_array_equal(td["state"][b].numpy(), e.state())


@pytest.mark.parametrize("reward_mode", ["individual", "team"])
@pytest.mark.parametrize("B", [3, 70], ids=["B3", "B70"])  # 70: the core's large-batch paths
def test_batch_equals_parallel_envs_with_autoreset(reward_mode, B):
    seed, steps = 11, 45
    env = ContainerAgentsTorchRLEnv(CFG, num_envs=B, reward_mode=reward_mode, seed=seed, **ENDS)
    envs, obs = _pz_envs(B, seed, reward_mode, **ENDS)
    td = env.reset()
    _assert_root_matches(td, envs, obs)
    rng = np.random.default_rng(0)
    ends = 0
    for _ in range(steps):
        actions = (rng.random((B, 5)) < 0.3).astype(np.int64)
        td[GROUP, "action"] = torch.from_numpy(actions)
        td, td_root = env.step_and_maybe_reset(td)
        nxt = td["next"]
        for b, e in enumerate(envs):
            o, r, term, trunc, info = e.step({a: int(actions[b, i]) for i, a in enumerate(e.possible_agents)})
            agents = e.possible_agents
            np.testing.assert_array_equal(nxt[GROUP, "observation"][b].numpy(),
                                          np.stack([o[a]["observation"] for a in agents]))
            np.testing.assert_array_equal(nxt[GROUP, "reward"][b, :, 0].numpy(),
                                          np.array([r[a] for a in agents], dtype=np.float32))
            np.testing.assert_array_equal(nxt["state"][b].numpy(), e.state())
            assert bool(nxt["terminated"][b]) == term[agents[0]] and bool(nxt["truncated"][b]) == trunc[agents[0]]
            for key in ("granted", "denied", "overflowed"):
                np.testing.assert_array_equal(nxt[GROUP, "info", key][b].numpy(), [info[a][key] for a in agents])
            for key in ("emptying_reward", "plant_reward"):
                np.testing.assert_array_equal(nxt[GROUP, "info", key][b].numpy(),
                                              np.array([info[a][key] for a in agents], dtype=np.float32))
            if term[agents[0]] or trunc[agents[0]]:
                ends += 1
                obs[b] = e.reset()[0]  # no seed: the simulation continues its own stream
            else:
                obs[b] = o
        _assert_root_matches(td_root, envs, obs)
        assert not td_root["done"].any()
        td = td_root
    assert ends >= B  # time limits and overflows happened and were reset


def test_partial_reset_touches_only_masked_simulations():
    env = ContainerAgentsTorchRLEnv(CFG, num_envs=4, seed=3)
    td = env.reset()
    for _ in range(5):
        td[GROUP, "action"] = torch.ones(4, 5, dtype=torch.int64)
        td = env.step(td)["next"].clone()
    before = env.simulator.state
    mask = torch.tensor([[False], [True], [False], [False]])
    out = env.reset(TensorDict({"_reset": mask}, batch_size=[4]))
    after = env.simulator.state
    assert after.step_count.tolist() == [5, 0, 5, 5]
    np.testing.assert_array_equal(after.volumes[[0, 2, 3]], before.volumes[[0, 2, 3]])
    assert not np.array_equal(after.volumes[1], before.volumes[1])
    # the group-level mask works the same way
    group_mask = torch.zeros(4, 5, 1, dtype=torch.bool)
    group_mask[2] = True
    env.reset(TensorDict({GROUP: TensorDict({"_reset": group_mask}, batch_size=[4, 5])}, batch_size=[4]))
    assert env.simulator.state.step_count.tolist() == [5, 0, 0, 5]
    assert out[GROUP, "observation"].shape == (4, 5, 19)


def test_seeding_repeats_and_differs():
    def first_obs(seed):
        env = ContainerAgentsTorchRLEnv(CFG, num_envs=2)
        env.set_seed(seed)
        return env.reset()[GROUP, "observation"]

    assert torch.equal(first_obs(1), first_obs(1))
    assert not torch.equal(first_obs(1), first_obs(2))
    # simulation b has seed + b: simulation 1 of seed 1 is simulation 0 of seed 2
    assert torch.equal(first_obs(1)[1], first_obs(2)[0])


def test_bad_arguments():
    with pytest.raises(ValueError, match="reward_mode"):
        ContainerAgentsTorchRLEnv(CFG, reward_mode="shared")
    with pytest.raises(ValueError, match="num_envs"):
        ContainerAgentsTorchRLEnv(CFG, num_envs=0)
    env = ContainerAgentsTorchRLEnv(CFG, num_envs=2, seed=0)
    td = env.reset()
    td[GROUP, "action"] = torch.full((2, 5), 2, dtype=torch.int64)
    with pytest.raises(ValueError, match="requests"):
        env.step(td)


# ---- evaluating a TorchRL policy with the paper's protocol -----------------------------------------
class _RuleModule(torch.nn.Module):
    """The decentralised rule-based controller written as a TensorDict policy on the env's keys:
    request when the gap to the target (observation entry 2 × v_max) is at most 1 volume unit."""

    def __init__(self, params, one_hot=False):
        super().__init__()
        self.vmax = torch.tensor(np.array(params.max_volume), dtype=torch.float64)
        self.one_hot = one_hot

    def forward(self, td):
        gap = td[GROUP, "observation"][..., 2].double() * self.vmax
        action = (gap <= 1.0).long()
        td[GROUP, "action"] = torch.nn.functional.one_hot(action, 2).bool() if self.one_hot else action
        return td


@pytest.mark.parametrize("one_hot", [False, True], ids=["categorical", "one_hot"])
def test_torchrl_policy_adapter_evaluates_like_the_rule_based_agents(one_hot):
    from containergym_marl.core.params import PlantParams
    from containergym_marl.evaluation import EvalProtocol, evaluate
    from containergym_marl.policies import RuleBasedAgents
    from containergym_marl.policies.torchrl_policy import TorchRLAgentsPolicy

    params = PlantParams.from_config(container_agents_v0.parallel_env("n11_m2_dt120").config)
    protocol = EvalProtocol(episodes=2, episode_length_steps=120)
    ours = evaluate(TorchRLAgentsPolicy(_RuleModule(params, one_hot), name="rule_module"), "n11_m2_dt120", protocol)
    reference = evaluate(RuleBasedAgents(params), "n11_m2_dt120", protocol)
    assert ours.view == "decentralised"
    assert [e.cumulative_reward for e in ours.episodes] == [e.cumulative_reward for e in reference.episodes]
    assert [e.emptying_actions for e in ours.episodes] == [e.emptying_actions for e in reference.episodes]
    assert sum(e.emptying_actions for e in ours.episodes) > 0


def test_torchrl_policy_adapter_feeds_what_the_batched_env_gives():
    from containergym_marl.policies.torchrl_policy import TorchRLAgentsPolicy

    batched = ContainerAgentsTorchRLEnv(CFG, num_envs=1, seed=5, **ENDS)
    single = container_agents_v0.parallel_env(CFG, **ENDS)  # evaluate's env: container names, physical state
    obs, _ = single.reset(seed=5)
    adapter = TorchRLAgentsPolicy(lambda td: td)
    td = batched.reset()
    rng = np.random.default_rng(1)
    for _ in range(15):
        fed = adapter.inputs(obs, single)
        for key in ((GROUP, "observation"), (GROUP, "action_mask"), "state"):
            assert torch.equal(fed[key], td[key]), key
        actions = (rng.random(5) < 0.5).astype(np.int64)
        td[GROUP, "action"] = torch.from_numpy(actions)[None]
        td, td = batched.step_and_maybe_reset(td)
        obs, *_ = single.step({a: int(x) for a, x in zip(single.possible_agents, actions)})
        if not single.agents:
            break
