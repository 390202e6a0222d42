"""The time a policy takes to decide, per plant step (the studies' decision-time columns)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np


def decision_times_ms(policy: Any, env: Any, steps: int, seed: int) -> np.ndarray:
    """Wall milliseconds of ``policy.act(observations, env)`` over ``steps`` steps of the parallel
    ``env``, reset with ``seed``; an episode that ends early is followed by the next one."""
    observations, _ = env.reset(seed=seed)
    times = np.empty(steps)
    for k in range(steps):
        if not env.agents:
            observations, _ = env.reset()
        t0 = time.perf_counter()
        actions = policy.act(observations, env)
        times[k] = time.perf_counter() - t0
        observations, *_ = env.step(actions)
    return 1e3 * times


def _centralised_times_ms(policy: Any, env: Any, steps: int, seed: int) -> np.ndarray:
    """:func:`decision_times_ms` through the Gymnasium env of the centralised view."""
    observation, _ = env.reset(seed=seed)
    times = np.empty(steps)
    for k in range(steps):
        t0 = time.perf_counter()
        action = policy.act(observation, env)
        times[k] = time.perf_counter() - t0
        observation, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            observation, _ = env.reset()
    return 1e3 * times


def decision_time(policy: Any, plant: Any, steps: int, seed: int) -> dict:
    """Wall time of ``policy.act`` per plant step through the policy's own view (all agents at once for
    the container agents), one torch thread, over ``steps`` steps of ``plant`` (a PlantConfig) from the
    episode of ``seed`` on: median, mean and 99th percentile in milliseconds."""
    import torch

    from containergym_marl.envs.centralised import ContainerGymEnv
    from containergym_marl.envs.container_agents_v0 import parallel_env
    from containergym_marl.evaluation.protocol import policy_observation

    torch.set_num_threads(1)
    if hasattr(policy, "reset"):
        policy.reset(seed=seed)
    if policy.view == "centralised":
        ms = _centralised_times_ms(policy, ContainerGymEnv(plant), steps, seed)
    else:
        env = parallel_env(plant, action_masking=True, observation=policy_observation(policy))
        ms = decision_times_ms(policy, env, steps, seed)
    return {"steps": len(ms), "ms_median": float(np.median(ms)), "ms_mean": float(ms.mean()),
            "ms_p99": float(np.quantile(ms, 0.99))}
