"""Decentralised view: every container is an agent (PettingZoo parallel and AEC APIs).

Use ``parallel_env(...)`` for the parallel API (what SuperSuit wraps) and ``env(...)`` for the AEC
API. Both take the same arguments as :class:`ContainerAgentsParallelEnv`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv
from pettingzoo.utils import conversions, wrappers

from containergym_marl.config import PlantConfig, load_config
from containergym_marl.core.dynamics import DEFAULT_ARBITRATION, get_rule
from containergym_marl.core.observations import (
    DEFAULT_OBSERVATION,
    AgentObservations,
    check_observation,
    global_state_bounds,
)
from containergym_marl.core.simulator import EpisodeFinishedError, PlantSimulator
from containergym_marl.envs.edge import (
    NormalisedState,
    agent_reset_info,
    agent_rewards,
    agent_step_infos,
    check_reward_mode,
    check_seed,
    discrete_action,
)
from containergym_marl.render import RENDER_FPS, RENDER_MODES, EnvRenderer

OBSERVATION_MODES = ("box", "dict")
STATE_MODES = ("physical", "normalised")
AGENT_NAMES = ("containers", "indexed")
#: The prefix of the ``agent_names="indexed"`` agents: ``container_0`` … ``container_{n-1}``.
INDEXED_AGENT_PREFIX = "container"


class ContainerAgentsParallelEnv(ParallelEnv):
    """ContainerGym, decentralised: each container asks to be emptied; the plant arbitrates.

    ## Description
    The same plant and physics as :class:`~containergym_marl.envs.centralised.ContainerGymEnv`
    (one shared core), seen by n agents, one per container. Every step each agent may request
    emptying; when k requests compete for f < k free PUs an arbitration rule inside the
    environment grants f of them and denies the rest.

    ## Agents (``agent_names=``)
    ``possible_agents`` is fixed at construction, agent i acting for container i
    (``container_names[i]``, i.e. ``config.container_names[i]``). ``"containers"`` (default): the
    agents are named after their containers (``"C1-20"``, …). ``"indexed"``: ``"container_0"`` …
    ``"container_{n-1}"``, the ``<descriptor>_<number>`` form that PettingZoo's ``api_test``
    recommends and by which TorchRL's ``PettingZooWrapper`` (parallel API) groups agents: all
    agents fall into one group ``"container"``, so one policy is shared and the group's tensors
    are stacked, as parameter sharing needs; with container names every agent is its own group
    unless a ``group_map`` is passed (``MarlGroupMapType.ALL_IN_ONE_GROUP`` does the same for
    any names, also for the AEC API, where TorchRL's default is one group per agent).
    RLlib, Tianshou and SuperSuit do not read names. All agents act every step; all terminate
    together on overflow and truncate together at T, after which ``agents`` is empty.

    ## Action space (per agent)
    ``Discrete(2)``: 0 waits, 1 requests emptying. The action mask is ``[1, 1]`` while a PU is
    free and ``[1, 0]`` while none is (int8): a request then is legal but always denied (r_pen).
    With ``action_masking=True`` each agent's info holds it as ``action_mask``; with
    ``observation_mode="dict"`` it is part of the observation (below).

    ## Observation space (per agent, identical for all agents; ``observation_mode=``)
    ``"box"`` (default): ``Box(float32, shape=(12 + m + n,))`` of normalised, bounded features:
    own volume, target, gap to target, v_max, fill rate and noise, product size, reward if emptied
    now, free-PU share, competing demand (others' requests last step, others ready to be emptied,
    others fuller), the PU timers and a one-hot container index. The table with every entry and
    bound is in :mod:`containergym_marl.core.observations`; names via :meth:`feature_names`.

    What the Box holds (``observation=``, :data:`~containergym_marl.core.observations.OBSERVATIONS`):
    ``"local"`` (default) is the above, F = 12 + m + n entries. The other variants append entries
    after them, each documented entry by entry in :mod:`containergym_marl.core.observations`, for
    the study of what an imitation of the planner lacks (``studies/coordination_ablation.py``):
    ``"global"`` the normalised global state, every container's v / v_max and every PU's timer
    (n + m entries, the same for all agents: an oracle, not a decentralised observation);
    ``"history4"`` the agent's own observations of the last 3 steps (3 (12 + m + n) entries, 0
    before the episode's start); ``"broadcast"`` which containers requested in the last step and
    which were emptied (2n entries of 0/1, 0 at the start), a signal the plant could broadcast to
    every agent. ``"portable"`` has 14 entries on every plant, for one network that acts on plants of
    any size (a shared policy trained on one plant and run on a larger one): entries 0–11 of the
    above, then the PU timers summarised (the smallest and the mean), no one-hot. The space, its
    bounds and dtype are the same at reset and at every step; models record the variant they were
    trained on and refuse to act on another.

    ``"dict"``: ``Dict({"action_mask": Box(0, 1, (2,), int8), "observation": <the Box above>})``,
    the layout of PettingZoo's classic environments, which Tianshou's ``PettingZooEnv`` and
    TorchRL's ``PettingZooWrapper`` read as action masks (TorchRL also reads ``action_mask``
    from the infos), and which RLlib's action-masking modules take after a rename (its examples
    call the features ``"observations"``). SB3 and SuperSuit want the ``"box"`` mode.

    ## State (``state_mode=``)
    ``state()`` returns the global state ``[v_1..v_n, p_1..p_m]`` as float32, with ``state_space``
    its Box (the same object every call). ``"physical"`` (default): volumes in volume units
    (bounds [0, 2·v_max,i]) and PU timers in seconds (bounds [0, max_i g_i(v_max,i)]), equal to
    the centralised view's observation. ``"normalised"``: volumes / v_max,i in [0, 2] (above 1
    only in the terminal state of an overflow) and timers / the largest possible PU time in
    [0, 1], the scales of the agents' observations, for a centralised critic (MAPPO, QMIX).

    ## Arbitration (``arbitration=``)
    ``"fullest"`` (default): highest v / v_max first. ``"random"``: uniformly random order drawn
    from the environment's generator. ``"index"``: fixed priority, lower container index first.
    ``"best_reward"``: highest immediate emptying reward first. Ties go to the lower index.
    Granted containers are emptied on distinct PUs; denied requests earn r_pen, like the paper's
    "no free PU".

    ## Rewards (``reward_mode=``)
    ``"individual"`` (default): each agent gets its own emptying reward, r_pen if denied, 0 if it
    waited; overflowing containers get r_min. ``"team"``: every agent gets the plant reward (sum of
    the step's emptying rewards and penalties, replaced by r_min on overflow), exactly the
    centralised view's reward. A library that reports the sum of all agents' returns (RLlib's
    ``episode_return_mean``) shows n × the plant return in team mode; the plant return is one
    agent's return (or the sum of the ``plant_reward`` infos).

    Every denied request costs r_pen, also in the plant ("team") reward: a step with k denied
    requests and no emptying scores k·r_pen. The decentralised plant return therefore counts each
    denied request exactly as the centralised return does (where a step holds at most one
    request). A consequence: a team/plant step reward can fall below r_min when more than
    |r_min / r_pen| requests are denied in one step (10 in the built-in configs, r_min = -1,
    r_pen = -0.1; e.g. -1.6 when all 16 agents of ``n16_m2_dt120`` request while no PU is free).
    r_min remains the worst *terminal* outcome: an overflow also ends the episode and forfeits
    every later reward, whereas denials do not.

    ## Info (per agent)
    ``requested``, ``granted``, ``denied`` (bool), ``pu_index`` (int, -1 if not emptied),
    ``emptied_volume`` (float, 0.0 if not emptied), ``emptying_reward`` (float, this agent's
    reward before overflow replacement), ``overflowed`` (bool), ``plant_reward`` (float, the
    step's plant reward, as in "team" mode), ``free_pus`` (int, before the step), ``step`` (int);
    and ``action_mask`` (int8 array of shape (2,)) if asked. ``reset`` returns the same keys with
    the same types (False, -1, 0.0; ``free_pus`` = free PUs now, ``step`` = 0), never None: TorchRL
    and BenchMARL build their info specs from the reset infos.

    ## Arguments
    ``config`` (also positional: ``parallel_env("n5_m2_dt120")``; the built-in plants, the larger ones
    not in the paper, as for the centralised view), ``protocol`` and plant-level overrides as for the
    centralised view; ``arbitration``, ``reward_mode``, ``action_masking``,
    ``observation`` (``"local"``/``"global"``/``"history4"``/``"broadcast"``/``"portable"``), ``observation_mode``
    (``"box"``/``"dict"``), ``state_mode`` (``"physical"``/``"normalised"``),
    ``agent_names`` (``"containers"``/``"indexed"``) as above; ``render_mode``: None,
    ``"human"`` (a live diagram drawn at every reset and step, in a window only when a display is
    available, otherwise off-screen without blocking), ``"rgb_array"`` (that diagram as an
    ``(H, W, 3)`` uint8 frame, with the last step's granted and denied requests marked per
    container) or ``"ansi"`` (text); see :mod:`containergym_marl.render`.

    ## Version history
    * v0: first release. Later additions, with defaults that keep the first behaviour:
      ``observation_mode``, ``state_mode``, ``agent_names``, positional ``config``, reset infos
      with every step key, ``observation`` (the variants; default ``"local"``).
    """

    metadata = {
        "name": "container_agents_v0",
        "render_modes": list(RENDER_MODES),
        "is_parallelizable": True,
        "render_fps": RENDER_FPS,
    }

    def __init__(
        self,
        config: str | PlantConfig = "n5_m2_dt120",
        *,
        arbitration: str = DEFAULT_ARBITRATION,
        reward_mode: str = "individual",
        action_masking: bool = False,
        observation: str = DEFAULT_OBSERVATION,
        observation_mode: str = "box",
        state_mode: str = "physical",
        agent_names: str = "containers",
        render_mode: str | None = None,
        protocol: str | None = None,
        **overrides: Any,
    ):
        get_rule(arbitration)  # a clear error for an unknown rule, before anything is built
        check_reward_mode(reward_mode)
        check_observation(observation)
        for name, value, allowed in (("observation_mode", observation_mode, OBSERVATION_MODES),
                                     ("state_mode", state_mode, STATE_MODES),
                                     ("agent_names", agent_names, AGENT_NAMES)):
            if not isinstance(value, str) or value not in allowed:
                raise ValueError(f"{name}: unknown value {value!r}; choose one of {allowed}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode: {render_mode!r} not supported; choose from {self.metadata['render_modes']}"
            )
        self.config = load_config(config, protocol=protocol, **overrides)
        self.arbitration = arbitration
        self.reward_mode = reward_mode
        self.action_masking = bool(action_masking)
        self.observation_mode = observation_mode
        self.state_mode = state_mode
        self.agent_names = agent_names
        self.render_mode = render_mode
        self._sim = PlantSimulator(self.config, num_sims=1, arbitration=arbitration)
        self._renderer = EnvRenderer(self._sim, render_mode, view="decentralised")
        params = self._sim.params
        #: what each agent sees (the Box's variant): one of ``core.observations.OBSERVATIONS``
        self.observation = observation
        self._agent_obs = AgentObservations(params, observation, num_sims=1)

        #: container i's name, for agent i (``possible_agents[i]``)
        self.container_names: tuple[str, ...] = tuple(self.config.container_names)
        if agent_names == "indexed":
            self.possible_agents = [f"{INDEXED_AGENT_PREFIX}_{i}" for i in range(len(self.container_names))]
        else:
            self.possible_agents = list(self.container_names)
        self._agent_index = {a: i for i, a in enumerate(self.possible_agents)}
        self.agents: list[str] = []
        low, high = self._agent_obs.low, self._agent_obs.high
        # One (equal) space object per agent, each returned every time: SuperSuit needs equal
        # spaces, PettingZoo's seeding tests need a cached object per agent.
        self.observation_spaces = {a: self._agent_observation_space(low, high) for a in self.possible_agents}
        self.action_spaces = {a: spaces.Discrete(2) for a in self.possible_agents}
        s_low, s_high = global_state_bounds(params)
        if state_mode == "normalised":
            self._normalise = NormalisedState(params)
            s_low, s_high = self._normalise.low, self._normalise.high
        self.state_space = spaces.Box(s_low, s_high, dtype=np.float32)
        self._np_random: np.random.Generator | None = None

    def _agent_observation_space(self, low: np.ndarray, high: np.ndarray) -> spaces.Space:
        box = spaces.Box(low, high, dtype=np.float32)
        if self.observation_mode == "box":
            return box
        return spaces.Dict({"observation": box, "action_mask": spaces.Box(0, 1, shape=(2,), dtype=np.int8)})

    # ---- spaces ------------------------------------------------------------------------------
    def _check_agent(self, agent: str) -> str:
        if agent not in self._agent_index:
            raise KeyError(f"unknown agent {agent!r}; agents are {self.possible_agents}")
        return agent

    def observation_space(self, agent: str) -> spaces.Space:
        return self.observation_spaces[self._check_agent(agent)]

    def action_space(self, agent: str) -> spaces.Discrete:
        return self.action_spaces[self._check_agent(agent)]

    def feature_names(self) -> list[str]:
        """Names of the observation entries, in order."""
        return self._agent_obs.feature_names()

    @property
    def simulator(self) -> PlantSimulator:
        return self._sim

    @property
    def np_random(self) -> np.random.Generator:
        if self._np_random is None:
            self._np_random, _ = seeding.np_random()
        return self._np_random

    # ---- API ---------------------------------------------------------------------------------
    def reset(self, seed: int | None = None, options: dict | None = None):
        seed = check_seed(seed)  # numpy integers as the vector envs take them; no bools
        if seed is not None:
            self._np_random, _ = seeding.np_random(seed)
        self._sim.reset(generators=[self.np_random])
        self._agent_obs.reset()
        self.agents = self.possible_agents[:]
        observations = self._observations()
        free = int(self._sim.free_pu_count()[0])
        infos = {a: agent_reset_info(free) for a in self.agents}
        if self.action_masking:
            for info in infos.values():
                info["action_mask"] = self._mask(free)
        if self.render_mode == "human":
            self.render()
        return observations, infos

    def step(self, actions: dict[str, Any]):
        if not self.agents:
            raise EpisodeFinishedError(
                "the episode has finished (overflow or time limit) or was never started; call reset()"
            )
        if not isinstance(actions, dict):
            raise TypeError(f"actions: expected a dict from agent name to action, got {type(actions).__name__}")
        unknown = [a for a in actions if a not in self._agent_index]
        if unknown:
            raise KeyError(f"unknown agent(s) {unknown}; agents are {self.agents}")
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise KeyError(f"missing action(s) for agent(s) {missing}; every live agent must act")
        requests = np.zeros((1, len(self.possible_agents)), dtype=bool)
        for agent, action in actions.items():
            requests[0, self._agent_index[agent]] = discrete_action(action, 2, f"agent {agent!r}") == 1

        out = self._sim.step(requests)
        observations = self._observations()
        rewards = dict(zip(self.agents, agent_rewards(out, self.reward_mode)[0].tolist()))
        terminated, truncated = bool(out.terminated[0]), bool(out.truncated[0])
        terminations = {a: terminated for a in self.agents}
        truncations = {a: truncated for a in self.agents}
        infos = dict(zip(self.agents, agent_step_infos(out, 0, self._sim.state.step_count[0])))
        if self.action_masking:
            free_now = int(self._sim.free_pu_count()[0])
            for a in self.agents:
                infos[a]["action_mask"] = self._mask(free_now)
        if terminated or truncated:
            self.agents = []
        if self.render_mode == "human":
            self.render()
        return observations, rewards, terminations, truncations, infos

    def state(self) -> np.ndarray:
        """The global state in ``state_mode`` (see the class docstring), float32, in ``state_space``."""
        state = self._sim.global_state()[0]
        if self.state_mode == "normalised":
            state = self._normalise(state)
        return state

    def render(self):
        """The current state in ``render_mode``: text ("ansi"), a frame ("rgb_array") or None."""
        return self._renderer.render()

    def close(self):
        """Close the rendering figure (and its window, if any)."""
        self._renderer.close()

    # ---- helpers -----------------------------------------------------------------------------
    def _observations(self) -> dict[str, Any]:
        sim = self._sim  # called once per reset and step: a "history4" observation remembers it
        obs = self._agent_obs(sim.state, sim.previous_requests, sim.previous_granted)[0]
        if self.observation_mode == "box":
            return {a: obs[i] for i, a in enumerate(self.possible_agents)}
        free = int(self._sim.free_pu_count()[0])
        # keys in the order of the Dict space (which sorts them)
        return {a: {"action_mask": self._mask(free), "observation": obs[i]}
                for i, a in enumerate(self.possible_agents)}

    @staticmethod
    def _mask(free_pus: int) -> np.ndarray:
        return np.array([1, 1 if free_pus > 0 else 0], dtype=np.int8)


def parallel_env(config: str | PlantConfig = "n5_m2_dt120", **kwargs: Any) -> ContainerAgentsParallelEnv:
    """The parallel-API environment (what SuperSuit and the training code use); ``config`` may be
    given by position, ``parallel_env("n11_m2_dt120")``."""
    return ContainerAgentsParallelEnv(config, **kwargs)


class ContainerAgentsAECEnv(conversions.parallel_to_aec_wrapper):
    """The AEC view: PettingZoo's ``parallel_to_aec`` of the parallel env, with every action
    checked at its own agent's turn.

    PettingZoo's conversion stores each agent's action and hands them all to the parallel env at
    the last agent's turn, so an invalid action used to be accepted at its turn and refused only
    at the last agent's, after which every step failed until ``reset()``. Here an invalid action
    (not an integer 0/1, e.g. 3, None, 0.0 or NaN; or anything but None for a finished agent) is
    refused at once, naming the agent, and changes nothing: the same agent is still to act, with
    the state, stored actions, rewards and random streams as before.
    """

    def step(self, action):
        if not hasattr(self, "_actions"):
            raise EpisodeFinishedError("the environment was never reset; call reset() before step()")
        agent = self.agent_selection
        if self.terminations[agent] or self.truncations[agent]:
            if action is not None:
                raise ValueError(f"agent {agent!r} has finished (terminated or truncated): its action "
                                 f"must be None, got {action!r}")
            return super().step(None)
        return super().step(discrete_action(action, 2, f"agent {agent!r}"))


def raw_env(config: str | PlantConfig = "n5_m2_dt120", **kwargs: Any) -> ContainerAgentsAECEnv:
    """The AEC-API environment without PettingZoo's order-enforcing wrapper
    (``parallel_to_aec`` of the parallel env, checking each action at its agent's turn)."""
    return ContainerAgentsAECEnv(parallel_env(config, **kwargs))


def env(config: str | PlantConfig = "n5_m2_dt120", **kwargs: Any):
    """The AEC-API environment with PettingZoo's order-enforcing wrapper."""
    return wrappers.OrderEnforcingWrapper(raw_env(config, **kwargs))
