"""Thin environment views over the shared core."""

from containergym_marl.envs import container_agents_v0, container_agents_v1
from containergym_marl.envs.centralised import ContainerGymEnv
from containergym_marl.envs.container_agents_v0 import ContainerAgentsParallelEnv
from containergym_marl.envs.container_agents_v1 import ContainerAgentsV1ParallelEnv

__all__ = ["ContainerGymEnv", "ContainerAgentsParallelEnv", "ContainerAgentsV1ParallelEnv",
           "container_agents_v0", "container_agents_v1"]
