"""TorchRL's ``PettingZooWrapper`` over ``container_agents_v0``: specs check out and rollouts run.

Needs torchrl (not a dependency of the package: skipped without it) and is marked ``slow``, so the
default run leaves it out. Run with ``pytest -m slow tests/test_clients_torchrl.py`` in an
environment with torchrl installed (checked with torch 2.13.0, torchrl 0.14.1, tensordict 0.14.3).
"""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.slow

torchrl_pettingzoo = pytest.importorskip("torchrl.envs.libs.pettingzoo")
torchrl_utils = pytest.importorskip("torchrl.envs.utils")

from containergym_marl import container_agents_v0  # noqa: E402

CASES = [
    {},
    {"action_masking": True},
    {"observation_mode": "dict"},
    {"agent_names": "indexed", "observation_mode": "dict", "state_mode": "normalised", "reward_mode": "team"},
    {"agent_names": "indexed", "action_masking": True, "episode_length_steps": 7},
]


@pytest.mark.parametrize("parallel", [True, False], ids=["parallel", "aec"])
@pytest.mark.parametrize("kwargs", CASES, ids=lambda k: ",".join(k) or "default")
def test_pettingzoo_wrapper_specs_and_rollout(parallel, kwargs):
    make = container_agents_v0.parallel_env if parallel else container_agents_v0.env
    env = torchrl_pettingzoo.PettingZooWrapper(make("n5_m2_dt120", **kwargs), return_state=True,
                                               use_mask=not parallel, seed=0, categorical_actions=True,
                                               done_on_any=True)
    torchrl_utils.check_env_specs(env, seed=0)
    td = env.rollout(60, break_when_any_done=False)
    assert td.batch_size == (60,) and td["state"].shape == (60, 7)
    masked = "action_masking" in kwargs or kwargs.get("observation_mode") == "dict"
    assert all(env.has_action_mask[g] == masked for g in env.group_map)
    if parallel and kwargs.get("agent_names") == "indexed":
        assert env.group_map == {"container": [f"container_{i}" for i in range(5)]}
    else:
        assert len(env.group_map) == 5  # one group per agent (TorchRL's default for these names)
