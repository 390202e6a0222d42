"""Native vectorised environments: B simulations stepped by one core call, with autoreset.

* :class:`ContainerGymVecEnv` — SB3 ``VecEnv`` of the centralised view (B slots).
* :class:`ContainerAgentsVecEnv` — SB3 ``VecEnv`` for parameter sharing: its B × n slots are the
  container agents of B simulations (slot ``b * n + i`` is agent i of simulation b), the layout that
  SuperSuit's ``pettingzoo_env_to_vec_env_v1`` + ``concat_vec_envs_v1`` produce, without Python
  loops over environments.
* :class:`ContainerGymVectorEnv` — Gymnasium ``VectorEnv`` of the centralised view, registered as
  the ``vector_entry_point`` of ``containergym_marl/ContainerGym-v0``.

Seeding: simulation b is seeded with ``seed + b`` (``VecEnv.seed(seed)`` then ``reset()``, or
``reset(seed=seed)`` for the Gymnasium one), exactly as a single environment ``reset(seed=seed + b)``;
after an episode ends it is reset automatically and continues its own random stream, as a single
environment's ``reset()`` without a seed would. So B vectorised simulations equal B single
environments with those seeds. A seed is None or a non-negative integer (Python or numpy);
anything else (``2.7``, ``"5"``, True) is refused with a ValueError rather than cast. The Gymnasium
env's ``reset(seed=...)`` also takes B seeds, one per simulation, as a list, tuple or 1-D integer
array (``reset(seed=np.arange(B))`` seeds simulation b with b).

Sizes: ``num_envs`` / ``num_sims`` must be integers in [1, ``MAX_SIMS``] (2**24); floats are
refused (:func:`~containergym_marl.envs.edge.check_batch_size`, shared with the TorchRL env).

Autoreset: when simulation b ends, the returned observation is the first of its next episode; the
last observation of the finished episode is in ``infos[k]["terminal_observation"]`` (SB3) or
``infos["final_obs"]`` (Gymnasium, ``SAME_STEP`` mode), and SB3's ``infos[k]["TimeLimit.truncated"]``
tells a time-limit cut (bootstrap) from an overflow (terminal).

The two SB3 VecEnvs need stable-baselines3 (the ``train`` extra); without it this module still
imports, and constructing them raises an ImportError that names the extra to install.

Cost: one step is one core call for all B simulations plus work proportional to the number of
episode ends; there is no Python loop over simulations or slots. In the SB3 envs, the info of a
slot with nothing to report is one shared, read-only empty dict (:data:`NO_INFO`; writing to it
raises, ``.copy()`` gives a plain dict): SB3 and its wrappers only write to the infos of finished
slots, which are always fresh dicts.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from containergym_marl.config import PlantConfig, load_config
from containergym_marl.core.dynamics import DEFAULT_ARBITRATION, StepOutcome
from containergym_marl.core.observations import (
    DEFAULT_OBSERVATION,
    AgentObservations,
    check_observation,
    global_state_bounds,
)
from containergym_marl.core.params import PlantParams
from containergym_marl.core.simulator import PlantSimulator
from containergym_marl.envs.edge import (
    CentralisedInfo,
    agent_rewards,
    check_batch_size,
    check_reward_mode,
    check_seed,
    is_integer,
)
from containergym_marl.extras import missing_extra

#: How to get the SB3 VecEnvs' optional dependency; named by the error raised without it.

try:  # SB3 is an optional (training) dependency
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv
except ImportError as _sb3_error:  # exercised in a subprocess by the tests
    _SB3_IMPORT_ERROR: ImportError | None = _sb3_error

    class VecEnv:  # type: ignore[no-redef]
        """Stand-in base class, so that this module (and its Gymnasium vector env) imports
        without SB3; the SB3 VecEnvs refuse to be constructed."""
else:
    _SB3_IMPORT_ERROR = None


def _require_sb3(cls_name: str) -> None:
    if _SB3_IMPORT_ERROR is not None:
        raise missing_extra(f"{cls_name} is a stable-baselines3 VecEnv and", "train",
                            _SB3_IMPORT_ERROR) from _SB3_IMPORT_ERROR


class _ReadOnlyEmptyInfo(dict):
    """An empty info dict that refuses writes, shared by every slot with nothing to report."""

    __slots__ = ()

    def _refuse(self, *args, **kwargs):
        raise TypeError("this slot's info is the shared read-only NO_INFO; copy it (info.copy()) "
                        "before adding keys")

    __setitem__ = __delitem__ = __ior__ = setdefault = update = pop = popitem = clear = _refuse

    def __reduce__(self):  # pickles (e.g. to a subprocess) as a plain empty dict
        return (dict, ())


#: The info of every SB3 slot whose episode did not end this step.
NO_INFO: dict = _ReadOnlyEmptyInfo()


class _AutoresetBatch:
    """B simulations with per-simulation seeds and automatic reset (shared by all vector envs)."""

    def __init__(self, config: PlantConfig, num_sims: int, arbitration: str = DEFAULT_ARBITRATION):
        self.sim = PlantSimulator(config, num_sims=num_sims, arbitration=arbitration)
        self.params = self.sim.params
        self.num_sims = num_sims

    def reset_all(self, seeds: Sequence[int | None]) -> None:
        self.sim.reset(generators=[seeding.np_random(s)[0] for s in seeds])

    def step(self, requests: np.ndarray) -> tuple[StepOutcome, np.ndarray, np.ndarray, Any]:
        """Step all simulations; reset the finished ones. Returns the outcome, the (B,) done mask,
        the indices of the finished simulations and their final state, previous requests and
        previous grants (before the reset; None if none finished)."""
        out = self.sim.step(requests)
        done_mask = out.terminated | out.truncated
        if not done_mask.any():
            return out, done_mask, _NO_SIMS, (None, None, None)
        done = np.flatnonzero(done_mask)
        final_state = self.sim.state.select(done)
        final_previous = self.sim.previous_requests[done]
        final_granted = self.sim.previous_granted[done]
        self.sim.reset(sims=done)
        return out, done_mask, done, (final_state, final_previous, final_granted)


_NO_SIMS = np.zeros(0, dtype=np.int64)


def _seed_list(seed, count: int) -> list[int | None]:
    """The per-simulation seeds of ``seed``: None → all None; an integer s → s, s+1, …; a list,
    tuple or 1-D integer array of ``count`` seeds → those."""
    if seed is None:
        return [None] * count
    if isinstance(seed, (list, tuple)) or (isinstance(seed, np.ndarray) and seed.ndim == 1):
        if isinstance(seed, np.ndarray) and not np.issubdtype(seed.dtype, np.integer):
            raise ValueError(f"seed: an array of seeds must hold integers, got dtype {seed.dtype}")
        if len(seed) != count:
            raise ValueError(f"seed: expected {count} seeds (one per simulation), got {len(seed)}")
        return [check_seed(s, f"seed[{b}]") for b, s in enumerate(seed)]
    base = check_seed(seed, "seed")
    return [base + b for b in range(count)]


def _integer_actions(actions, expected: int, what: str) -> np.ndarray:
    a = np.asarray(actions)
    if a.shape != (expected,) and a.size == expected:
        a = a.reshape(-1)
    if a.shape != (expected,) or not np.issubdtype(a.dtype, np.integer):
        raise ValueError(f"actions: expected {expected} integer actions ({what}), got {np.asarray(actions)!r}")
    return a


def _centralised_requests(actions: np.ndarray, num_sims: int, n: int) -> np.ndarray:
    a = _integer_actions(actions, num_sims, f"0 wait, 1..{n} empty that container")
    if a.min() < 0 or a.max() > n:
        bad = int(np.flatnonzero((a < 0) | (a > n))[0])
        raise ValueError(f"actions: env {bad} has action {int(a[bad])} outside [0, {n}]")
    requests = np.zeros((num_sims, n), dtype=bool)
    rows = np.flatnonzero(a)
    requests.reshape(-1)[rows * n + (a[rows] - 1)] = True
    return requests


def _agent_requests(actions: np.ndarray, num_sims: int, n: int) -> np.ndarray:
    a = _integer_actions(actions, num_sims * n, "0 wait, 1 request")
    if a.min() < 0 or a.max() > 1:
        bad = int(np.flatnonzero((a != 0) & (a != 1))[0])
        raise ValueError(f"actions: slot {bad} (simulation {bad // n}, agent "
                         f"{bad % n}) has action {int(a[bad])}, expected 0 or 1")
    return (a == 1).reshape(num_sims, n)


class _SB3Base(VecEnv):
    """SB3 VecEnv plumbing shared by both SB3 vector envs."""

    render_mode = None

    def _init_sb3(self, config, num_sims, arbitration, num_slots, obs_space, act_space):
        self.config = config
        self._batch = _AutoresetBatch(self.config, num_sims, arbitration)
        self.num_sims = num_sims
        self._sim_seeds: list[int | None] = [None] * num_sims
        self._actions: np.ndarray | None = None
        VecEnv.__init__(self, num_slots, obs_space, act_space)

    @property
    def simulator(self) -> PlantSimulator:
        return self._batch.sim

    def last_plant_step(self) -> tuple[np.ndarray, np.ndarray]:
        """(num_sims,) plant reward and episode end (terminated or truncated) of every simulation in
        the last step: what training monitors need whatever the agents' rewards are (the same
        method exists on the SuperSuit adapter). New arrays: the simulator reuses its own."""
        out = self._batch.sim.last_outcome
        if out is None:
            raise RuntimeError("last_plant_step: no step has been taken yet")
        return out.plant_reward.copy(), out.terminated | out.truncated

    def overflow_slots(self) -> np.ndarray:
        """(num_envs,) bool, new: the slots whose reward in the last step is the plant's r_min because a
        container overflowed (a trainer that weighs overflows its own way rescales those rewards)."""
        raise NotImplementedError

    def seed(self, seed: int | None = None) -> list[int | None]:
        """Simulation b gets ``seed + b`` at the next ``reset()``."""
        base = check_seed(seed, "seed")
        self._sim_seeds = [None if base is None else base + b for b in range(self.num_sims)]
        return list(self._sim_seeds)

    def reset(self):
        self._batch.reset_all(self._sim_seeds)
        self._sim_seeds = [None] * self.num_sims
        self._reset_seeds()
        self._reset_options()
        return self._first_observations()

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def close(self) -> None:
        pass

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        return [getattr(self, attr_name)] * len(self._indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        raise AttributeError(f"{type(self).__name__} does not support set_attr({attr_name!r})")

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        if method_name == "action_masks":
            return list(self.action_masks()[self._indices(indices)])
        raise AttributeError(f"{type(self).__name__} has no per-environment method {method_name!r}")

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False] * len(self._indices(indices))

    def _indices(self, indices) -> np.ndarray:
        if indices is None:
            return np.arange(self.num_envs)
        return np.atleast_1d(np.arange(self.num_envs)[indices])


class ContainerGymVecEnv(_SB3Base):
    """SB3 VecEnv of B centralised controllers (one slot per simulation).

    Observations, actions and rewards are those of :class:`~containergym_marl.envs.ContainerGymEnv`.
    ``action_masks()`` returns the (B, n + 1) masks for MaskablePPO.
    """

    def __init__(self, config: str | PlantConfig = "n5_m2_dt120", num_envs: int = 8, *,
                 protocol: str | None = None, **overrides: Any):
        num_envs = check_batch_size(num_envs, "num_envs")
        _require_sb3(type(self).__name__)
        cfg = load_config(config, protocol=protocol, **overrides)
        low, high = global_state_bounds(PlantParams.from_config(cfg))
        self._init_sb3(cfg, num_envs, DEFAULT_ARBITRATION, num_envs,
                       spaces.Box(low, high, dtype=np.float32), spaces.Discrete(cfg.n_containers + 1))

    def _first_observations(self) -> np.ndarray:
        return self._batch.sim.global_state()

    def step_wait(self):
        n = self._batch.params.n_containers
        requests = _centralised_requests(self._actions, self.num_sims, n)
        out, dones, done, (final_state, _, _) = self._batch.step(requests)
        obs = self._batch.sim.global_state()
        infos: list[dict] = [NO_INFO] * self.num_envs
        if done.size:
            final_obs = self._batch.sim.global_state(final_state)
            truncated = out.truncated[done].tolist()
            for k, b in enumerate(done.tolist()):
                infos[b] = {"terminal_observation": final_obs[k], "TimeLimit.truncated": truncated[k]}
        return obs, out.plant_reward.astype(np.float32), dones, infos

    def overflow_slots(self) -> np.ndarray:
        # the controller's reward is the plant's: r_min in a step that overflows
        return self._batch.sim.last_outcome.terminated.copy()

    def action_masks(self) -> np.ndarray:
        free = self._batch.sim.free_pu_count() > 0
        masks = np.ones((self.num_sims, self._batch.params.n_containers + 1), dtype=bool)
        masks[:, 1:] = free[:, None]
        return masks


class ContainerAgentsVecEnv(_SB3Base):
    """SB3 VecEnv whose B × n slots are the container agents of B simulations (parameter sharing).

    Slot ``b * n + i`` is agent i (``config.container_names[i]``) of simulation b, with the
    observation, ``Discrete(2)`` action and reward of the PettingZoo view
    (:class:`~containergym_marl.envs.ContainerAgentsParallelEnv`). All n slots of a simulation end
    together and are reset together. ``observation`` chooses what each agent sees, as the
    PettingZoo view's argument of that name (:data:`~containergym_marl.core.observations.OBSERVATIONS`;
    the default ``"local"`` is the view's usual observation); a ``"history4"`` agent's terminal
    observation stacks the frames of the episode that ended, its first next one only its own.
    """

    def __init__(self, config: str | PlantConfig = "n5_m2_dt120", num_sims: int = 8, *,
                 arbitration: str = DEFAULT_ARBITRATION, reward_mode: str = "individual",
                 observation: str = DEFAULT_OBSERVATION, protocol: str | None = None, **overrides: Any):
        check_reward_mode(reward_mode)
        check_observation(observation)
        num_sims = check_batch_size(num_sims, "num_sims")
        _require_sb3(type(self).__name__)
        cfg = load_config(config, protocol=protocol, **overrides)
        self.reward_mode = reward_mode
        self.n_agents = cfg.n_containers
        self._agent_obs = AgentObservations(PlantParams.from_config(cfg), observation, num_sims)
        self.observation = self._agent_obs.observation
        self._init_sb3(cfg, num_sims, arbitration, num_sims * cfg.n_containers,
                       spaces.Box(self._agent_obs.low, self._agent_obs.high, dtype=np.float32), spaces.Discrete(2))

    def _first_observations(self) -> np.ndarray:
        sim = self._batch.sim
        self._agent_obs.reset()
        return self._agent_obs(sim.state, sim.previous_requests, sim.previous_granted).reshape(self.num_envs, -1)

    def step_wait(self):
        n = self.n_agents
        requests = _agent_requests(self._actions, self.num_sims, n)
        out, done_mask, done, (final_state, final_prev, final_granted) = self._batch.step(requests)
        if done.size:  # the ended episodes' last observations, before their memory is cleared
            final_obs = self._agent_obs.final(final_state, final_prev, final_granted, done)
            self._agent_obs.reset(done)
        sim = self._batch.sim
        obs = self._agent_obs(sim.state, sim.previous_requests, sim.previous_granted).reshape(self.num_envs, -1)
        rewards = agent_rewards(out, self.reward_mode, np.float32).reshape(-1)
        dones = np.repeat(done_mask, n)
        infos: list[dict] = [NO_INFO] * self.num_envs
        if done.size:
            truncated = out.truncated[done].tolist()
            for k, b in enumerate(done.tolist()):
                for i in range(n):
                    infos[b * n + i] = {"terminal_observation": final_obs[k, i],
                                        "TimeLimit.truncated": truncated[k]}
        return obs, rewards, dones, infos

    def overflow_slots(self) -> np.ndarray:
        # an overflowing container's own reward is r_min; the team reward of its plant's every agent
        out = self._batch.sim.last_outcome
        if self.reward_mode == "team":
            return np.repeat(out.terminated, self.n_agents)
        return out.overflowed.reshape(-1).copy()

    def action_masks(self) -> np.ndarray:
        free = np.repeat(self._batch.sim.free_pu_count() > 0, self.n_agents)
        return np.stack([np.ones_like(free), free], axis=1)


class ContainerGymVectorEnv(VectorEnv):
    """Gymnasium VectorEnv of the centralised view (autoreset mode ``SAME_STEP``).

    Created by ``gym.make_vec("containergym_marl/ContainerGym-v0", num_envs=B,
    vectorization_mode="vector_entry_point", config=...)``.

    Infos are those that ``gym.make_vec(..., vectorization_mode="sync")`` in ``SAME_STEP`` mode
    builds from the single environments' infos, computed for all B simulations at once: at reset
    and at every step, each key of :class:`~containergym_marl.envs.ContainerGymEnv`'s info as a
    (B,) array (int64, float64, bool, or object for the names) with its ``_key`` mask (all True;
    one shared read-only array).
    A simulation that ended this step shows its new episode's reset info there, and, as in
    Gymnasium, ``final_obs`` / ``_final_obs`` and ``final_info`` (a dict of such arrays, holding the
    last step's info where ``_final_info`` is True) appear in the steps where some simulation ended.
    ``final_obs`` is a (B, n + m) float32 array (rows of unfinished simulations are 0) rather than
    Gymnasium's object array; ``infos["final_obs"][b]`` reads the same in both.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(self, config: str | PlantConfig = "n5_m2_dt120", num_envs: int = 8, *,
                 protocol: str | None = None, render_mode: str | None = None,
                 **overrides: Any):
        if is_integer(config):
            # the order of every other batched env of the package: (config, size)
            raise TypeError(f"config: expected a config name, path or PlantConfig, got {config!r}; "
                            "the arguments are (config, num_envs)")
        if render_mode is not None:
            raise ValueError("render_mode: the vector env does not render; render a single env instead")
        self.config = load_config(config, protocol=protocol, **overrides)
        self.num_envs = check_batch_size(num_envs, "num_envs")
        self._batch = _AutoresetBatch(self.config, self.num_envs)
        params = self._batch.params
        low, high = global_state_bounds(params)
        self.single_observation_space = spaces.Box(low, high, dtype=np.float32)
        self.single_action_space = spaces.Discrete(params.n_containers + 1)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.render_mode = None
        self._started = False
        self._info = CentralisedInfo(self.config.container_names)
        self._all_true = np.ones(self.num_envs, dtype=bool)
        self._all_true.setflags(write=False)

    @property
    def simulator(self) -> PlantSimulator:
        return self._batch.sim

    def reset(self, *, seed: int | Sequence[int | None] | np.ndarray | None = None, options: dict | None = None):
        seeds = _seed_list(seed, self.num_envs)  # checked before anything changes
        if seed is None and self._started:
            self._batch.sim.reset()  # continue every simulation's own stream
        else:
            self._batch.reset_all(seeds)
        self._started = True
        return self._batch.sim.global_state(), self._with_masks(self._reset_info(slice(None)))

    def step(self, actions):
        if not self._started:
            raise RuntimeError("call reset() before step()")
        n = self._batch.params.n_containers
        requests = _centralised_requests(actions, self.num_envs, n)
        out, done_mask, done, (final_state, _, _) = self._batch.step(requests)
        obs = self._batch.sim.global_state()
        step_count = self._batch.sim.state.step_count
        if done.size:  # the finished episodes' step counts, before their reset
            step_count = step_count.copy()
            step_count[done] = final_state.step_count
        info = self._info.step_arrays(np.asarray(actions).reshape(-1), out, step_count)
        if not done.size:
            return obs, out.plant_reward.copy(), out.terminated.copy(), out.truncated.copy(), self._with_masks(info)
        final = np.zeros_like(obs)
        final[done] = self._batch.sim.global_state(final_state)
        # the finished step's infos of the ended simulations, blank elsewhere (as Gymnasium's
        # _add_info leaves them: 0, False, or None for object entries)
        final_info = {}
        for key, value in info.items():
            blank = np.full(self.num_envs, None, dtype=object) if value.dtype == object else np.zeros_like(value)
            blank[done] = value[done]
            final_info[key] = blank
            final_info[f"_{key}"] = done_mask.copy()
        # the ended simulations start a new episode: their info is the reset info
        for key, value in self._reset_info(done).items():
            info[key][done] = value
        infos = self._with_masks(info)
        infos.update({"final_obs": final, "_final_obs": done_mask.copy(),
                      "final_info": final_info, "_final_info": done_mask.copy()})
        return obs, out.plant_reward.copy(), out.terminated.copy(), out.truncated.copy(), infos

    def _reset_info(self, sims) -> dict[str, np.ndarray]:
        """The single environment's reset info for ``sims`` (indices or a slice), one array per key."""
        return self._info.reset_arrays(self._batch.sim.free_pu_count()[sims])

    def _with_masks(self, info: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Gymnasium's batched info layout: every key with its ``_key`` mask (all True: every
        simulation reports every key). The masks are one shared read-only array."""
        out: dict[str, np.ndarray] = {}
        for key, value in info.items():
            out[key] = value
            out[f"_{key}"] = self._all_true
        return out
