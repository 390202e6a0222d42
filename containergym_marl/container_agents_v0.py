"""The decentralised ContainerGym environment, importable as PettingZoo environment modules are::

    from containergym_marl import container_agents_v0
    import containergym_marl.container_agents_v0 as container_agents_v0

    env = container_agents_v0.parallel_env("n5_m2_dt120")  # parallel API
    aec = container_agents_v0.env("n5_m2_dt120")           # AEC API, order-enforcing
    raw = container_agents_v0.raw_env("n5_m2_dt120")       # AEC API, no wrapper

The implementation is :mod:`containergym_marl.envs.container_agents_v0`; its class docstring
(:class:`ContainerAgentsParallelEnv`) is the environment's card.
"""

from containergym_marl.envs.container_agents_v0 import (
    AGENT_NAMES,
    INDEXED_AGENT_PREFIX,
    OBSERVATION_MODES,
    STATE_MODES,
    ContainerAgentsParallelEnv,
    env,
    parallel_env,
    raw_env,
)
from containergym_marl.envs.edge import REWARD_MODES

__all__ = [
    "AGENT_NAMES",
    "INDEXED_AGENT_PREFIX",
    "OBSERVATION_MODES",
    "REWARD_MODES",
    "STATE_MODES",
    "ContainerAgentsParallelEnv",
    "env",
    "parallel_env",
    "raw_env",
]
