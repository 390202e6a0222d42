"""RLlib (new API stack) on ``container_agents_v0``: PPO with one policy shared by all container
agents trains one iteration on the Dict observation with action masks, and its logged returns are
n × the plant return in team mode (RLlib sums the agents' returns).

RLlib's action-masking module (``ActionMaskingTorchRLModule`` from its examples) reads the features
under ``"observations"``; :class:`ContainerActionMasking` below takes ours (``"observation"``); the
The RLlib block of docs/integrations.md points here for it. Needs ``ray[rllib]`` (the ``clients`` extra) and starts a local Ray
instance (~30 s): ``slow``.
"""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.slow

pytest.importorskip("ray.rllib")
torch = pytest.importorskip("torch")
import gymnasium as gym  # noqa: E402
import ray  # noqa: E402
from ray.rllib.algorithms.ppo import PPOConfig  # noqa: E402
from ray.rllib.core.columns import Columns  # noqa: E402
from ray.rllib.core.rl_module.multi_rl_module import MultiRLModuleSpec  # noqa: E402
from ray.rllib.core.rl_module.rl_module import RLModuleSpec  # noqa: E402
from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv  # noqa: E402
from ray.rllib.examples.rl_modules.classes.action_masking_rlm import ActionMaskingTorchRLModule  # noqa: E402
from ray.tune.registry import register_env  # noqa: E402

from containergym_marl import container_agents_v0  # noqa: E402

ENV_KWARGS = dict(observation_mode="dict", reward_mode="team", episode_length_steps=50)


class ContainerActionMasking(ActionMaskingTorchRLModule):
    """RLlib's masking PPO module on ``{"observation", "action_mask"}`` observations."""

    def __init__(self, *, observation_space=None, **kwargs):
        if isinstance(observation_space, gym.spaces.Dict) and "observation" in observation_space.spaces:
            observation_space = gym.spaces.Dict({"action_mask": observation_space["action_mask"],
                                                 "observations": observation_space["observation"]})
        super().__init__(observation_space=observation_space, **kwargs)

    def _preprocess_batch(self, batch, **kwargs):
        if "observation" in batch[Columns.OBS]:
            batch[Columns.OBS]["observations"] = batch[Columns.OBS].pop("observation")
        return super()._preprocess_batch(batch, **kwargs)


@pytest.fixture
def local_ray():
    ray.init(include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def test_ppo_shared_policy_with_masks_one_iteration(local_ray):
    register_env("containergym_n5", lambda _: ParallelPettingZooEnv(
        container_agents_v0.parallel_env("n5_m2_dt120", **ENV_KWARGS)))
    module = RLModuleSpec(module_class=ContainerActionMasking, model_config={"fcnet_hiddens": [32, 32]})
    config = (PPOConfig().environment("containergym_n5")
              .multi_agent(policies={"shared"}, policy_mapping_fn=lambda agent_id, *args, **kwargs: "shared")
              .rl_module(rl_module_spec=MultiRLModuleSpec(rl_module_specs={"shared": module}))
              .env_runners(num_env_runners=0, rollout_fragment_length=100)
              .learners(num_learners=0)
              .training(train_batch_size_per_learner=200, minibatch_size=100, num_epochs=1)
              .debugging(seed=0))
    algo = config.build_algo()
    try:
        result = algo.train()
        runners = result["env_runners"]
        n = 5
        assert runners["num_env_steps_sampled"] == 200 and runners["num_episodes"] >= 3
        assert set(runners["num_agent_steps_sampled"].values()) == {200}  # every agent acts each step
        # team rewards: RLlib's episode return sums the agents' returns, n × the plant return
        agent_returns = list(runners["agent_episode_returns_mean"].values())
        assert np.allclose(agent_returns, agent_returns[0])
        assert runners["episode_return_mean"] == pytest.approx(n * agent_returns[0])
        # the shared module masks requests while no PU is free
        shared = algo.get_module("shared")
        obs = container_agents_v0.parallel_env("n5_m2_dt120", **ENV_KWARGS).observation_space("C1-20").sample()
        features = torch.as_tensor(np.stack([obs["observation"]] * 2))
        mask = torch.tensor([[1, 0], [1, 1]], dtype=torch.int8)
        out = shared.forward_inference({Columns.OBS: {"observation": features, "action_mask": mask}})
        logits = out[Columns.ACTION_DIST_INPUTS]
        assert logits[0, 1] < -1e30 and logits[1, 1] > -1e30
    finally:
        algo.stop()
