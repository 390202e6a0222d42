"""The time a container-agent policy takes to decide, per plant step (the studies' decision-time columns)."""

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
