"""The paper's rule-based controller (section 6.2), centralised and decentralised.

Centralised: empty the lowest-index container whose volume is within ``margin`` (1 volume unit) of
its global optimum, otherwise do nothing. "Within" is one-sided, as in the earlier reference code
(``v* − v <= margin``): a container already past its optimum qualifies too, so an initial volume
above v* + 1 is emptied at once instead of being left to overflow. It does not check for a free PU,
as in the paper, so it can earn r_pen. Decentralised: every container agent requests emptying when it is within the
margin; the environment's arbitration decides who is served.
"""

from __future__ import annotations

import numpy as np

from containergym_marl.core.params import PlantParams


def within_margin(volumes: np.ndarray, params: PlantParams, margin: float) -> np.ndarray:
    """(…, n) bool: v* − v <= margin for every container (the reference code's test)."""
    return params.target_volume - np.asarray(volumes) <= margin


class RuleBasedController:
    """Centralised rule: reads the centralised observation ``[v, p]`` (one or a batch)."""

    name = "rule_based"
    view = "centralised"

    def __init__(self, params: PlantParams, margin: float = 1.0):
        self.params, self.margin = params, float(margin)

    def act(self, observation: np.ndarray, env=None) -> np.ndarray | int:
        obs = np.asarray(observation, dtype=np.float64)
        ready = within_margin(obs[..., : self.params.n_containers], self.params, self.margin)
        action = np.where(ready.any(axis=-1), ready.argmax(axis=-1) + 1, 0)
        return int(action) if action.ndim == 0 else action


class RuleBasedAgents:
    """Decentralised rule: each agent requests when its container is within the margin.

    Reads the agents' observations (``gap_to_target_frac`` and the one-hot index).
    """

    name = "rule_based_agents"
    view = "decentralised"

    def __init__(self, params: PlantParams, margin: float = 1.0):
        self.params, self.margin = params, float(margin)

    def act(self, observations: dict[str, np.ndarray], env=None) -> dict[str, int]:
        names = list(observations)
        obs = np.stack([observations[a] for a in names])
        vmax = self.params.max_volume[np.argmax(obs[:, -self.params.n_containers:], axis=1)]
        gap = obs[:, 2].astype(np.float64) * vmax  # (v* − v) in volume units
        return {a: int(g <= self.margin) for a, g in zip(names, gap)}
