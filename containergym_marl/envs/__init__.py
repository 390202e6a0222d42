"""Thin environment views over the shared core."""

from containergym_marl.envs import container_agents_v0
from containergym_marl.envs.centralised import ContainerGymEnv
from containergym_marl.envs.container_agents_v0 import ContainerAgentsParallelEnv

__all__ = ["ContainerGymEnv", "ContainerAgentsParallelEnv", "container_agents_v0"]
