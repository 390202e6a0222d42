"""containergym-marl: the ContainerGym benchmark with centralised and decentralised views.

Quick start::

    import gymnasium as gym
    import containergym_marl  # registers the Gymnasium id

    env = gym.make("containergym_marl/ContainerGym-v0", config="n5_m2_dt120")
    par = containergym_marl.container_agents_v1.parallel_env("n5_m2_dt120")  # agents container_0, ...

``container_agents_v1`` is the decentralised view for new work; ``container_agents_v0`` (agents
named after their containers) is the one the published runs used.
"""

from gymnasium.envs.registration import register, registry

from containergym_marl.config import (
    PAPER_TEST_PROTOCOL,
    ConfigError,
    ContainerSpec,
    PlantConfig,
    list_configs,
    load_config,
)
from containergym_marl import container_agents_v0, container_agents_v1  # PettingZoo-style modules: env, parallel_env, raw_env
from containergym_marl.envs import ContainerAgentsParallelEnv, ContainerAgentsV1ParallelEnv, ContainerGymEnv

__version__ = "0.1.0"

ENV_ID = "containergym_marl/ContainerGym-v0"
if ENV_ID not in registry:
    # No max_episode_steps: the environment truncates itself at the config's T.
    register(
        id=ENV_ID,
        entry_point="containergym_marl.envs.centralised:ContainerGymEnv",
        vector_entry_point="containergym_marl.envs.vector:ContainerGymVectorEnv",
    )

__all__ = [
    "ENV_ID",
    "PAPER_TEST_PROTOCOL",
    "ConfigError",
    "ContainerAgentsParallelEnv",
    "ContainerAgentsV1ParallelEnv",
    "ContainerGymEnv",
    "ContainerSpec",
    "PlantConfig",
    "container_agents_v0",
    "container_agents_v1",
    "list_configs",
    "load_config",
]
