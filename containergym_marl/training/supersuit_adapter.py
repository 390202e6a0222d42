"""A thin adapter that makes SuperSuit's parameter-sharing stack correct under SB3.

The stack ``pettingzoo_env_to_vec_env_v1`` → ``concat_vec_envs_v1`` turns K copies of a PettingZoo
parallel env into one vector env whose slots are all copies' agents. With SuperSuit 3.11 and SB3 2.9
it has four problems, measured on this project (each has a test in ``tests/training/test_supersuit_adapter.py``):

1. ``ConcatVecEnv`` / ``ProcConcatVec`` have no ``seed()``, ``get_attr`` or ``env_method``, so
   ``PPO(..., seed=s)`` raises ``AttributeError``.
2. ``concat_vec_envs_v1`` deep-copies one env: copies of an env that already owns a generator
   share its RNG state and replay the same episode; with ``num_cpus > 1`` worker w seeds its copies
   ``seed + w + j``, so copies of different workers overlap (copies 1 and 2 identical).
3. SuperSuit's SB3 wrapper merges ``terminated`` and ``truncated`` into ``dones`` without
   ``TimeLimit.truncated``, so SB3 treats time-limit cuts as terminal (no bootstrapping).
4. With ``num_cpus > 1`` the interpreter hangs at exit unless the vec env is closed.

:class:`SuperSuitVecEnv` builds the stack itself from distinct, individually seeded copies (copy k
gets ``seed + k`` at its first reset and then continues its own stream, exactly like the native
:class:`~containergym_marl.envs.vector.ContainerAgentsVecEnv` simulation k), is an SB3 ``VecEnv``
with ``seed``/``get_attr``/``env_method``, restores ``TimeLimit.truncated`` from the separate flags
that SuperSuit's gymnasium-level vector env still has, and closes itself at exit.
"""

from __future__ import annotations

import atexit
import weakref
from typing import Any

import numpy as np
from pettingzoo.utils.wrappers import BaseParallelWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from containergym_marl.envs.container_agents_v0 import parallel_env


class _SeedFirstReset(BaseParallelWrapper):
    """Passes ``seed`` to the first ``reset`` only; later resets continue the env's own stream."""

    def __init__(self, env, seed: int | None):
        super().__init__(env)
        self._pending_seed = seed

    def reset(self, seed=None, options=None):
        if seed is None and self._pending_seed is not None:
            seed = self._pending_seed
        self._pending_seed = None
        return self.env.reset(seed=seed, options=options)

    def state(self):
        return self.env.state()


class _CopyFactory:
    """Picklable factory of copy k (SuperSuit's worker processes call it)."""

    def __init__(self, env_kwargs: dict, seed: int | None):
        self.env_kwargs, self.seed = env_kwargs, seed

    def __call__(self):
        import supersuit

        return supersuit.pettingzoo_env_to_vec_env_v1(_SeedFirstReset(parallel_env(**self.env_kwargs), self.seed))


def _close_quietly(venv) -> None:
    try:
        venv.close()
    except Exception:  # noqa: BLE001 - closing at exit must never raise
        pass


class SuperSuitVecEnv(VecEnv):
    """SB3 VecEnv over SuperSuit's concatenated copies of the container-agents env.

    Args:
        num_copies: K simulations (PettingZoo env copies); slots = K × n agents, copy-major.
        num_cpus: SuperSuit worker processes (0 or 1: in-process).
        seed: copy k is seeded ``seed + k``; ``None`` draws fresh entropy per copy.
        **env_kwargs: arguments of ``container_agents_v0.parallel_env`` (config, arbitration…).
    """

    def __init__(self, num_copies: int = 8, num_cpus: int = 0, seed: int | None = None, **env_kwargs: Any):
        self.num_copies, self.num_cpus = int(num_copies), int(num_cpus)
        self.env_kwargs = dict(env_kwargs)
        probe = parallel_env(**self.env_kwargs)
        self.config = probe.config
        self.n_agents = len(probe.possible_agents)
        self.render_mode = None
        self._venv = None
        self._seed = seed
        self._build(seed)
        super().__init__(self.num_copies * self.n_agents, self._venv.observation_space, self._venv.action_space)
        self._finalizer = weakref.finalize(self, _close_quietly, self._venv)
        atexit.register(self._finalizer)  # problem 4: close the workers before interpreter exit
        self._last_plant = (np.zeros(self.num_copies), np.zeros(self.num_copies, dtype=bool))
        self._last_overflow = np.zeros(self.num_envs, dtype=bool)

    def _build(self, seed: int | None) -> None:
        from supersuit.vector.constructors import MakeCPUAsyncConstructor

        if self._venv is not None:
            self._venv.close()
        fns = [_CopyFactory(self.env_kwargs, None if seed is None else seed + k) for k in range(self.num_copies)]
        probe = fns[0]()
        # Build the concatenation from distinct factories instead of deep copies of one env
        # (problem 2); seeds are applied per copy, never through SuperSuit's seed arithmetic.
        self._venv = MakeCPUAsyncConstructor(min(self.num_cpus, self.num_copies))(
            fns, probe.observation_space, probe.action_space)
        self._needs_reset = True

    # ---- VecEnv API ----------------------------------------------------------------------------
    def seed(self, seed: int | None = None) -> list[int | None]:
        """Problem 1: seed copies ``seed + k`` (rebuilds the copies; call before ``reset``)."""
        self._seed = seed
        self._build(seed)
        self._finalizer.detach()
        self._finalizer = weakref.finalize(self, _close_quietly, self._venv)
        atexit.register(self._finalizer)
        return [None if seed is None else seed + k for k in range(self.num_copies)]

    def reset(self):
        obs, infos = self._venv.reset()
        self.reset_infos = list(infos)
        self._reset_seeds()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self):
        obs, rewards, terminations, truncations, infos = self._venv.step(self._actions)
        terminations = np.asarray(terminations, dtype=bool)
        truncations = np.asarray(truncations, dtype=bool)
        dones = terminations | truncations
        infos = list(infos)
        for i in np.flatnonzero(dones):
            # Problem 3: a time-limit cut must be bootstrapped, an overflow must not.
            infos[i] = {**infos[i], "TimeLimit.truncated": bool(truncations[i] and not terminations[i])}
        n = self.n_agents
        plant = np.array([infos[k * n].get("plant_reward", np.nan) for k in range(self.num_copies)])
        self._last_plant = (plant, dones.reshape(self.num_copies, n)[:, 0].copy())
        rewards = np.asarray(rewards, dtype=np.float32)
        # an ended episode's infos are the next one's first: its overflowing agents are those at r_min
        # (below every other reward, r_pen included); in team mode all of them
        self._last_overflow = terminations.copy()
        if self.env_kwargs.get("reward_mode") != "team":
            self._last_overflow &= rewards == np.float32(self.config.overflow_reward)
        return obs, rewards, dones, infos

    def overflow_slots(self) -> np.ndarray:
        """The slots whose last reward is r_min because a container overflowed (ContainerAgentsVecEnv's)."""
        return self._last_overflow.copy()

    def last_plant_step(self) -> tuple[np.ndarray, np.ndarray]:
        """Plant reward and episode end of each copy in the last step (for training monitors)."""
        return self._last_plant

    def close(self) -> None:
        self._finalizer()

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        if not hasattr(self, attr_name):
            raise AttributeError(f"SuperSuitVecEnv has no attribute {attr_name!r}")
        return [getattr(self, attr_name)] * len(self._slot_indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        raise AttributeError(f"SuperSuitVecEnv does not support set_attr({attr_name!r})")

    def env_method(self, method_name: str, *args, indices=None, **kwargs) -> list[Any]:
        raise AttributeError(f"SuperSuitVecEnv cannot call {method_name!r} on individual agent slots")

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False] * len(self._slot_indices(indices))

    def _slot_indices(self, indices) -> np.ndarray:
        if indices is None:
            return np.arange(self.num_envs)
        return np.atleast_1d(np.arange(self.num_envs)[indices])
