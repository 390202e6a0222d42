"""Adapters that let :func:`~containergym_marl.evaluation.evaluate` run trained SB3 models."""

from __future__ import annotations

from typing import Any

import numpy as np


class CentralisedModelPolicy:
    """A centralised SB3 / sb3-contrib model acting on the Gymnasium view.

    MaskablePPO models get the environment's ``action_masks()``.
    """

    view = "centralised"

    def __init__(self, model: Any, name: str = "model", deterministic: bool = True):
        self.model, self.name, self.deterministic = model, name, deterministic
        self.observation_space = model.observation_space
        self._masked = type(model).__name__ == "MaskablePPO"

    def act(self, observation: np.ndarray, env: Any) -> int:
        if self._masked:
            action, _ = self.model.predict(observation, deterministic=self.deterministic,
                                           action_masks=env.action_masks())
        else:
            action, _ = self.model.predict(observation, deterministic=self.deterministic)
        return int(action)

    def act_batch(self, observations: np.ndarray, masks: np.ndarray) -> np.ndarray:
        """The actions of B controllers at once (B, F) -> (B,), masks (B, n + 1) for MaskablePPO."""
        extra = {"action_masks": masks} if self._masked else {}
        actions, _ = self.model.predict(observations, deterministic=self.deterministic, **extra)
        return np.asarray(actions, dtype=np.int64).reshape(-1)


class SharedModelPolicy:
    """One SB3 policy shared by all container agents: every agent's observation goes through a
    single batched ``predict`` call."""

    view = "decentralised"

    def __init__(self, model: Any, name: str = "shared_model", deterministic: bool = True):
        self.model, self.name, self.deterministic = model, name, deterministic
        self.observation_space = model.observation_space

    def act(self, observations: dict[str, np.ndarray], env: Any = None) -> dict[str, int]:
        agents = list(observations)
        actions, _ = self.model.predict(np.stack([observations[a] for a in agents]),
                                        deterministic=self.deterministic)
        return {a: int(x) for a, x in zip(agents, actions)}

    def act_batch(self, observations: np.ndarray, masks: np.ndarray | None = None) -> np.ndarray:
        """The actions of any number of agents at once (N, F) -> (N,); its models take no masks."""
        actions, _ = self.model.predict(observations, deterministic=self.deterministic)
        return np.asarray(actions, dtype=np.int64).reshape(-1)
