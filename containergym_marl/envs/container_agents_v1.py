"""Decentralised view, version 1: ``container_agents_v0`` with the PettingZoo ecosystem's defaults.

Use ``parallel_env(...)`` for the parallel API and ``env(...)`` for the AEC API, as with v0; both
take the arguments of :class:`ContainerAgentsV1ParallelEnv`. New work should use v1; v0 stays, with
its behaviour unchanged, because the published runs were made with it.
"""

from __future__ import annotations

from typing import Any

from pettingzoo import ParallelEnv
from pettingzoo.utils import wrappers

from containergym_marl.config import PlantConfig
from containergym_marl.envs.edge import is_integer
from containergym_marl.envs.container_agents_v0 import ContainerAgentsAECEnv, ContainerAgentsParallelEnv


class ContainerAgentsV1ParallelEnv(ContainerAgentsParallelEnv, ParallelEnv):
    """ContainerGym, decentralised, version 1: the plant, physics, spaces, rewards, state, masks,
    arbitration, infos and rendering of ``container_agents_v0``
    (:class:`~containergym_marl.envs.container_agents_v0.ContainerAgentsParallelEnv`, whose card
    describes them all) under the defaults and argument names that PettingZoo's tests and the MARL
    libraries expect. Only the differences are listed here.

    ## Agents
    ``possible_agents`` are ``"container_0"`` … ``"container_{n-1}"`` by default
    (``agent_names="indexed"``), agent i acting for container i. This is the
    ``<descriptor>_<number>`` form that PettingZoo's ``api_test`` recommends (v0's container names
    make it warn) and by which TorchRL's ``PettingZooWrapper`` and AgileRL group agents: all agents
    fall into one group ``"container"``, so one policy is shared, with no ``group_map`` or
    ``agent_names`` option needed. The plant's own names (``"C1-20"``, …) stay in
    ``container_names`` (``container_names[i]`` for agent i) and in ``agent_container`` (agent →
    container name); ``agent_names="containers"`` restores v0's naming.

    The names are not repeated in the per-step infos: TorchRL's ``PettingZooWrapper`` and BenchMARL
    turn every info value into a tensor (``torch.as_tensor``), which a string breaks.

    ## Episode length (``max_cycles=``)
    ``max_cycles`` is PettingZoo's name for the number of steps before truncation, the same number
    as the config's ``episode_length_steps`` (T), which it overrides (after ``protocol``). Passing
    both with different values is an error. ``env.max_cycles`` holds the episode length in force
    (the config's T when ``max_cycles`` is not given).

    ## Class
    ``ParallelEnv`` is named again among the direct bases (the method resolution order is
    unchanged): skrl's ``wrap_env`` recognises a PettingZoo environment by its class's direct
    bases only.

    ## Arguments
    As v0, with ``agent_names`` defaulting to ``"indexed"``, plus ``max_cycles`` (int ≥ 1 or None).

    ## Version history
    * v1: indexed agent names by default, ``max_cycles``, ``agent_container``; PettingZoo's
      ``api_test``, ``parallel_api_test``, ``seed_test``, ``parallel_seed_test``,
      ``max_cycles_test``, ``render_test`` and ``performance_benchmark`` pass without warnings.
    * v0: first release (agents named after their containers), kept unchanged for the published
      runs.
    """

    metadata = {**ContainerAgentsParallelEnv.metadata, "name": "container_agents_v1"}

    def __init__(
        self,
        config: str | PlantConfig = "n5_m2_dt120",
        *,
        agent_names: str = "indexed",
        max_cycles: int | None = None,
        **kwargs: Any,
    ):
        if max_cycles is not None:
            if not is_integer(max_cycles) or max_cycles < 1:
                raise ValueError(f"max_cycles: expected None or a positive integer, got {max_cycles!r}")
            length = kwargs.get("episode_length_steps", max_cycles)
            if length != max_cycles:
                raise ValueError(f"max_cycles={max_cycles!r} and episode_length_steps={length!r} disagree; "
                                 "they name the same episode length: pass one of them")
            kwargs["episode_length_steps"] = int(max_cycles)
        super().__init__(config, agent_names=agent_names, **kwargs)
        #: steps before truncation (the config's ``episode_length_steps``)
        self.max_cycles: int = self.config.episode_length_steps
        #: agent → the name of its container in the plant's configuration
        self.agent_container: dict[str, str] = dict(zip(self.possible_agents, self.container_names, strict=True))


def parallel_env(config: str | PlantConfig = "n5_m2_dt120", **kwargs: Any) -> ContainerAgentsV1ParallelEnv:
    """The parallel-API environment; ``config`` may be given by position."""
    return ContainerAgentsV1ParallelEnv(config, **kwargs)


def raw_env(config: str | PlantConfig = "n5_m2_dt120", **kwargs: Any) -> ContainerAgentsAECEnv:
    """The AEC-API environment without PettingZoo's order-enforcing wrapper (``parallel_to_aec`` of
    the parallel env, checking each action at its agent's turn, as v0's)."""
    return ContainerAgentsAECEnv(parallel_env(config, **kwargs))


def env(config: str | PlantConfig = "n5_m2_dt120", **kwargs: Any):
    """The AEC-API environment with PettingZoo's order-enforcing wrapper."""
    return wrappers.OrderEnforcingWrapper(raw_env(config, **kwargs))
