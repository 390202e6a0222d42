"""The decentralised ContainerGym environment, version 1 (for new work), importable as PettingZoo
environment modules are::

    from containergym_marl import container_agents_v1

    env = container_agents_v1.parallel_env("n5_m2_dt120")                # parallel API
    aec = container_agents_v1.env("n5_m2_dt120", max_cycles=600)         # AEC API, order-enforcing
    raw = container_agents_v1.raw_env("n5_m2_dt120")                     # AEC API, no wrapper

The implementation is :mod:`containergym_marl.envs.container_agents_v1`; its class docstring
(:class:`ContainerAgentsV1ParallelEnv`) is the card of what differs from ``container_agents_v0``.
"""

from containergym_marl.envs.container_agents_v1 import ContainerAgentsV1ParallelEnv, env, parallel_env, raw_env

# The option values (REWARD_MODES, OBSERVATION_MODES, ...) are v0's: containergym_marl.container_agents_v0.
__all__ = ["ContainerAgentsV1ParallelEnv", "env", "parallel_env", "raw_env"]
