"""A batched TorchRL environment of the container agents: B simulations × n agents in one step.

:class:`ContainerAgentsTorchRLEnv` steps B simulations of one plant with one call of the shared
core (:class:`~containergym_marl.core.simulator.PlantSimulator`) and returns one TensorDict,
following TorchRL's multi-agent conventions as its VMAS environment does: ``batch_size=[B]``, the
n container agents stacked in one group ``"container"`` (so one policy is shared across them and
across simulations), and a global ``"state"`` for centralised critics. It is what BenchMARL runs
(:mod:`containergym_marl.benchmarl_task`); for single environments TorchRL's ``PettingZooWrapper``
over ``container_agents_v0.parallel_env(agent_names="indexed")`` gives the same group and keys
(without the batch), at Python speed.

=====================================  ===================  =====================================
key                                    shape, dtype         meaning
=====================================  ===================  =====================================
``("container", "observation")``       [B, n, F] float32    the agents' observations, as
                                                            :mod:`containergym_marl.core.observations`
                                                            describes (F = 12 + m + n)
``("container", "action_mask")``       [B, n, 2] bool       ``[True, free PU]``: requesting
                                                            while no PU is free is always denied
``"state"``                            [B, n + m] float32   global state ``[v / v_max, p / max PU
                                                            time]`` (``state_mode="normalised"``
                                                            of the PettingZoo view)
``("container", "action")``            [B, n] int64         0 waits, 1 requests emptying
                                                            (``categorical_actions=False``:
                                                            one-hot [B, n, 2])
``("container", "reward")``            [B, n, 1] float32    ``reward_mode`` "individual" or
                                                            "team", as in the PettingZoo view
``("container", "done"|"terminated"    [B, n, 1] bool       all agents of a simulation end
|"truncated")``, and at the root                            together: terminated on overflow,
``"done"|"terminated"|"truncated"``    [B, 1] bool          truncated at the time limit T
``("container", "info", key)``         [B, n]               ``granted``, ``denied``,
                                                            ``overflowed`` (bool),
                                                            ``emptying_reward`` (the agent's
                                                            reward before overflow replacement)
                                                            and ``plant_reward`` (the step's plant
                                                            reward, the team reward) as float32
=====================================  ===================  =====================================

Resets: ``reset()`` starts all B simulations; TorchRL's autoreset (``rollout(...,
break_when_any_done=False)``, collectors) passes ``"_reset"`` masks (root [B, 1] or
``("container", "_reset")`` [B, n, 1]) and only the masked simulations start a new episode.

Seeding: ``set_seed(seed)`` (TorchRL's ``_set_seed``) gives simulation b the generator of seed
``seed + b``, used from its next reset on; without a seed the first reset draws fresh entropy.
As in the other vector environments, B simulations then equal B
``container_agents_v0.parallel_env`` environments reset with seeds ``seed + b``, and a simulation
reset after its episode ended continues its own random stream (a ``reset()`` without seed).

torchrl is not a dependency of the package: this module imports without it, and constructing the
environment raises an ImportError naming the ``clients`` extra. Checked with torch 2.13.0 and
torchrl 0.11.1 (with BenchMARL 1.5.2) and 0.14.1.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.utils import seeding

from containergym_marl.core.dynamics import DEFAULT_ARBITRATION
from containergym_marl.config import PlantConfig, load_config
from containergym_marl.core.observations import agent_observation_bounds, agent_observations
from containergym_marl.core.simulator import PlantSimulator
from containergym_marl.envs.edge import (
    NormalisedState,
    agent_info_arrays,
    agent_rewards,
    check_batch_size,
    check_reward_mode,
    check_seed,
)
from containergym_marl.extras import missing_extra

#: How to get this module's optional dependencies; named by the error raised without them.
#: The group of the container agents (also the group TorchRL's ``PettingZooWrapper`` forms from
#: ``agent_names="indexed"``).
GROUP = "container"
#: The container agents' info keys in ``(GROUP, "info")``, numbers only (TorchRL stacks them).
INFO_KEYS = ("granted", "denied", "overflowed", "emptying_reward", "plant_reward")

try:  # torchrl is an optional dependency (the clients extra)
    import torch
    from tensordict import TensorDict, TensorDictBase
    from torchrl.data import Bounded, Categorical, Composite, OneHot, Unbounded
    from torchrl.envs import EnvBase
except ImportError as _torchrl_error:  # exercised in a subprocess by the tests
    _TORCHRL_IMPORT_ERROR: ImportError | None = _torchrl_error

    class EnvBase:  # type: ignore[no-redef]
        """Stand-in base class, so that this module imports without torchrl; the environment
        refuses to be constructed."""
else:
    _TORCHRL_IMPORT_ERROR = None


def _require_torchrl(cls_name: str) -> None:
    if _TORCHRL_IMPORT_ERROR is not None:
        raise missing_extra(f"{cls_name} is a TorchRL environment and", "clients",
                            _TORCHRL_IMPORT_ERROR) from _TORCHRL_IMPORT_ERROR


class ContainerAgentsTorchRLEnv(EnvBase):
    """B simulations of the container agents in one TensorDict step (see the module docstring).

    Args:
        config: the plant (a built-in config name, a path or a :class:`PlantConfig`).
        num_envs: number of simulations B (an integer in [1, 2**24], as for every batched view), the
            environment's ``batch_size``.
        arbitration: how competing requests are ranked (as in the PettingZoo view).
        reward_mode: ``"individual"`` (each agent's own emptying reward) or ``"team"`` (every agent
            gets the plant reward; a sum over agents is then n × the plant return).
        categorical_actions: actions as indices [B, n] (default, as BenchMARL uses) or one-hot
            [B, n, 2].
        seed: if given, ``set_seed(seed)`` at construction (None or a non-negative integer, as for
            every view).
        device: where the returned tensors live (the simulation itself runs on the CPU).
        protocol, overrides: as for :func:`~containergym_marl.config.load_config`.
    """

    def __init__(
        self,
        config: str | PlantConfig = "n5_m2_dt120",
        num_envs: int = 64,
        *,
        arbitration: str = DEFAULT_ARBITRATION,
        reward_mode: str = "individual",
        categorical_actions: bool = True,
        seed: int | None = None,
        device: Any = "cpu",
        protocol: str | None = None,
        **overrides: Any,
    ):
        # the arguments first, as the other views check them (that needs no torchrl)
        check_reward_mode(reward_mode)
        num_envs = check_batch_size(num_envs, "num_envs")
        check_seed(seed)
        _require_torchrl(type(self).__name__)
        self.config = load_config(config, protocol=protocol, **overrides)
        self.num_envs = num_envs
        self.arbitration = arbitration
        self.reward_mode = reward_mode
        self.categorical_actions = bool(categorical_actions)
        super().__init__(device=device, batch_size=torch.Size([self.num_envs]))
        self._sim = PlantSimulator(self.config, num_sims=self.num_envs, arbitration=arbitration)
        params = self._sim.params
        self.n_agents = params.n_containers
        #: agent names of the group, as TorchRL's multi-agent envs expose them
        self.agent_names = [f"{GROUP}_{i}" for i in range(self.n_agents)]
        self.group_map = {GROUP: list(self.agent_names)}
        self._normalise = NormalisedState(params)
        self._pending_seeds: dict[int, int | None] = {}
        self._started = False
        self._cpu = torch.device(self.device) == torch.device("cpu") if self.device is not None else True
        self._make_specs()
        if seed is not None:
            self.set_seed(seed)

    # ---- specs ---------------------------------------------------------------------------------
    def _make_specs(self) -> None:
        params, n, B = self._sim.params, self.n_agents, self.num_envs
        low, high = agent_observation_bounds(params)
        s_low, s_high = self._normalise.low, self._normalise.high
        flag = lambda shape: Categorical(n=2, shape=shape, dtype=torch.bool)  # noqa: E731
        # one agent's entries, typed as the info arrays are (bool flags, float32 rewards)
        info = Composite(
            {key: flag((n,)) if value.dtype == bool else Unbounded(shape=(n,), dtype=torch.float32)
             for key, value in agent_info_arrays(None, INFO_KEYS, (1, n)).items()},
            shape=(n,),
        )
        observation = Composite(
            {
                GROUP: Composite(
                    {
                        "observation": Bounded(
                            low=torch.as_tensor(np.broadcast_to(low, (n, low.size)).copy()),
                            high=torch.as_tensor(np.broadcast_to(high, (n, high.size)).copy()),
                            shape=(n, low.size),
                            dtype=torch.float32,
                        ),
                        "action_mask": flag((n, 2)),
                        "info": info,
                    },
                    shape=(n,),
                ),
                "state": Bounded(low=torch.as_tensor(s_low), high=torch.as_tensor(s_high),
                                 shape=(s_low.size,), dtype=torch.float32),
            }
        )
        action = OneHot(n=2, shape=(n, 2)) if not self.categorical_actions else Categorical(n=2, shape=(n,))
        actions = Composite({GROUP: Composite({"action": action}, shape=(n,))})
        rewards = Composite({GROUP: Composite({"reward": Unbounded(shape=(n, 1), dtype=torch.float32)},
                                              shape=(n,))})
        ends = {key: flag((1,)) for key in ("done", "terminated", "truncated")}
        group_ends = Composite({key: flag((n, 1)) for key in ends}, shape=(n,))
        dones = Composite({**ends, GROUP: group_ends})
        batched = lambda spec: spec.expand(torch.Size([B]) + spec.shape).to(self.device)  # noqa: E731
        self.full_observation_spec = batched(observation)
        self.full_action_spec = batched(actions)
        self.full_reward_spec = batched(rewards)
        self.full_done_spec = batched(dones)

    # ---- the core, as seen from TorchRL --------------------------------------------------------
    @property
    def simulator(self) -> PlantSimulator:
        return self._sim

    def _set_seed(self, seed: int | None) -> None:
        # used from each simulation's next reset on (a reset consumes one row of its stream)
        seed = check_seed(seed)
        self._pending_seeds = {b: (None if seed is None else seed + b) for b in range(self.num_envs)}

    def _reset_sims(self, tensordict: TensorDictBase | None) -> np.ndarray | None:
        """The simulations a reset asks for: None (all) or an index array."""
        if tensordict is None:
            return None
        mask = None
        for key in ("_reset", (GROUP, "_reset")):
            value = tensordict.get(key, None)
            if value is not None:
                value = value.reshape(self.num_envs, -1).any(-1)
                mask = value if mask is None else mask | value
        if mask is None or bool(mask.all()):
            return None
        return np.flatnonzero(mask.cpu().numpy())

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        sims = self._reset_sims(tensordict) if self._started else None
        everyone = np.arange(self.num_envs) if sims is None else sims
        if not self._started:  # the first reset needs a generator for every simulation
            generators = [seeding.np_random(self._pending_seeds.pop(b, None))[0] for b in everyone]
            self._sim.reset(generators=generators)
            self._started = True
        elif sims is not None and sims.size == 0:
            pass  # nothing to reset (an all-False mask)
        else:
            seeded = [b for b in everyone.tolist() if b in self._pending_seeds]
            generators = None
            if seeded:
                generators = [seeding.np_random(self._pending_seeds.pop(b))[0] if b in seeded
                              else self._sim.generator(b) for b in everyone.tolist()]
            self._sim.reset(sims=sims, generators=generators)
        finished = self._tensor(self._sim.finished[:, None].copy())
        out = self._observe(rewards=None, info=agent_info_arrays(None, INFO_KEYS, (self.num_envs, self.n_agents)))
        self._set_ends(out, finished, finished.clone(), torch.zeros_like(finished))
        return out

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get((GROUP, "action"))
        if not self.categorical_actions:
            action = action.to(torch.uint8).argmax(-1)  # as TorchRL's OneHot.to_categorical
        out = self._sim.step(action.cpu().numpy())
        rewards = agent_rewards(out, self.reward_mode, np.float32)
        info = agent_info_arrays(out, INFO_KEYS, (self.num_envs, self.n_agents))
        result = self._observe(rewards=rewards[..., None], info=info)
        self._set_ends(result, self._tensor(self._sim.finished[:, None].copy()),
                       self._tensor(out.terminated[:, None].copy()), self._tensor(out.truncated[:, None].copy()))
        return result

    # ---- helpers -------------------------------------------------------------------------------
    def _tensor(self, array: np.ndarray) -> torch.Tensor:
        t = torch.from_numpy(array)
        return t if self._cpu else t.to(self.device)

    def _observe(self, rewards: np.ndarray | None, info: dict[str, np.ndarray]) -> TensorDictBase:
        sim, n = self._sim, self.n_agents
        obs = agent_observations(sim.state, sim.params, sim.previous_requests)
        mask = np.ones((self.num_envs, n, 2), dtype=bool)
        mask[:, :, 1] = (sim.free_pu_count() > 0)[:, None]
        state = self._normalise(sim.global_state())
        group = {
            "observation": self._tensor(obs),
            "action_mask": self._tensor(mask),
            "info": TensorDict({k: self._tensor(v) for k, v in info.items()},
                               batch_size=(self.num_envs, n), device=self.device),
        }
        if rewards is not None:
            group["reward"] = self._tensor(rewards)
        return TensorDict(
            {GROUP: TensorDict(group, batch_size=(self.num_envs, n), device=self.device),
             "state": self._tensor(state)},
            batch_size=self.batch_size,
            device=self.device,
        )

    def _set_ends(self, td: TensorDictBase, done, terminated, truncated) -> None:
        n = self.n_agents
        for key, value in (("done", done), ("terminated", terminated), ("truncated", truncated)):
            td.set(key, value)
            td.set((GROUP, key), value[:, None, :].expand(self.num_envs, n, 1).clone())
