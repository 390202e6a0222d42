"""Tianshou 2 on ``container_agents_v0``: its ``PettingZooEnv`` over the AEC env with Dict
observations hands the action masks to the policy, and a collector over a vector of such envs
runs whole episodes with one policy shared by all container agents.

Needs tianshou (skipped without it; the ``clients`` extra installs it).
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("tianshou")
from tianshou.algorithm.algorithm_base import Policy  # noqa: E402
from tianshou.algorithm.multiagent.marl import MultiAgentPolicy  # noqa: E402
from tianshou.data import Batch, Collector, VectorReplayBuffer  # noqa: E402
from tianshou.env import DummyVectorEnv, PettingZooEnv  # noqa: E402

from containergym_marl import container_agents_v0  # noqa: E402

T = 30


def _env():
    return PettingZooEnv(container_agents_v0.env("n5_m2_dt120", observation_mode="dict", reward_mode="team",
                                                 episode_length_steps=T))


class RequestWhenAllowed(Policy):
    """Requests emptying whenever the mask allows it; records the observations and masks it saw."""

    def __init__(self, action_space, observation_space):
        super().__init__(action_space=action_space, observation_space=observation_space)
        self.seen: list[tuple[np.ndarray, np.ndarray]] = []

    def forward(self, batch, state=None, **kwargs):
        mask = np.asarray(batch.obs.mask, dtype=bool)
        self.seen.append((np.asarray(batch.obs.obs), mask))
        return Batch(act=mask[:, 1].astype(np.int64))


def test_collector_with_masks_and_one_shared_policy():
    probe = _env()
    shared = RequestWhenAllowed(probe.action_space, probe.observation_space)
    policy = MultiAgentPolicy({agent: shared for agent in probe.agents})
    envs = DummyVectorEnv([_env, _env])
    collector = Collector(policy, envs, VectorReplayBuffer(4000, 2))
    envs.seed([0, 1])  # Tianshou's PettingZooEnv seeds by a reset with the seed
    collector.reset()
    stats = collector.collect(n_episode=2)
    n = 5
    assert stats.n_collected_episodes == 2
    # the episodes of this policy run to the time limit: every agent acts once per plant step
    assert stats.n_collected_steps == 2 * T * n
    # team rewards: every agent's return is the plant return
    assert stats.returns.shape == (2, n) and np.allclose(stats.returns, stats.returns[:, :1])
    obs = np.concatenate([o for o, _ in shared.seen])
    mask = np.concatenate([m for _, m in shared.seen])
    assert mask[:, 0].all()
    # the mask the policy gets allows a request exactly when a PU is free (observation entry 8)
    np.testing.assert_array_equal(mask[:, 1], obs[:, 8] > 0)
    assert 0 < mask[:, 1].mean() < 1  # both cases occurred
