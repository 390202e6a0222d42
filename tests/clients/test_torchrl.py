"""TorchRL's ``PettingZooWrapper`` over ``container_agents_v0``: specs check out and rollouts run.

Needs torchrl (the ``clients`` extra; skipped without it). The case a TorchRL user is advised to
take (parallel API, indexed names, Dict observations with masks, normalised state) is in the
default run, the other combinations are ``slow``. Checked with torch 2.13.0 and torchrl 0.11.1 /
tensordict 0.11.0 (what the extra resolves to with BenchMARL) and torchrl 0.14.1 / tensordict 0.14.3.
The batched native env is tested in ``test_clients_torchrl_env.py``.
"""

from __future__ import annotations

import pytest

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


ADVISED = CASES[3]
COMBINATIONS = [
    pytest.param(parallel, kwargs, id=f"{','.join(kwargs) or 'default'}-{'parallel' if parallel else 'aec'}",
                 marks=() if (parallel and kwargs is ADVISED) else pytest.mark.slow)
    for kwargs in CASES for parallel in (True, False)
]


@pytest.mark.parametrize("parallel, kwargs", COMBINATIONS)
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
