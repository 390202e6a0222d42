"""Centralised view: the paper's single controller as a Gymnasium environment."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from containergym_marl.config import PlantConfig, load_config
from containergym_marl.core.observations import global_state_bounds
from containergym_marl.core.simulator import PlantSimulator
from containergym_marl.envs.edge import CentralisedInfo, check_seed, discrete_action
from containergym_marl.render import RENDER_FPS, RENDER_MODES, EnvRenderer


class ContainerGymEnv(gym.Env):
    """ContainerGym, centralised: one controller decides which container to empty.

    ## Description
    A waste-sorting plant has n containers that fill stochastically (random walk with drift) and
    m ≪ n processing units (PUs). Emptying a container occupies a free PU for β + λ·⌊v/b⌋ seconds
    and earns a reward that peaks at the container's optimal volumes. This is the MDP of the
    ContainerGym paper (section 5), stepped by the shared core of ``containergym_marl.core``.

    ## Action space
    ``Discrete(n + 1)``: 0 does nothing, i ∈ 1..n empties container i (``config.container_names[i-1]``).
    :meth:`action_masks` masks the emptying actions while no PU is free (for sb3-contrib's
    MaskablePPO); unmasked, such an action earns r_pen and empties nothing.

    ## Observation space
    ``Box(float32, shape=(n + m,))``, the paper's state in physical units:

    | index      | entry                          | unit         | bounds              |
    |------------|--------------------------------|--------------|---------------------|
    | 0 … n-1    | volume v_i of container i      | volume units | [0, 2·v_max,i]      |
    | n … n+m-1  | timer p_j of PU j (0 = free)   | seconds      | [0, max_i g_i(v_max,i)] |

    Volumes above v_max occur only in the terminal observation of an overflow.

    ## Rewards
    Emptying container i with a free PU: ``r_pen + Σ_k (h_k − r_pen)·exp(−(v_i − v*_k)²/(2w_k²))``
    of its volume before this step's inflow (r_pen if it was empty; the PU is still used).
    Emptying with no free PU: r_pen. Doing nothing: 0. If any container reaches v_max the step's
    reward is replaced by r_min.

    ## Starting state
    ``v_i ~ U[initial_volume_min, initial_volume_max]`` i.i.d., all PUs free.

    ## Episode end
    ``terminated`` when a container reaches v_max (overflow). ``truncated`` after
    ``episode_length_steps`` (T) steps without overflow. Stepping a finished episode raises
    :class:`~containergym_marl.core.simulator.EpisodeFinishedError`.

    ## Plants
    The built-in plants (``list_configs()``, [Configurations](configurations.md)): the paper's eight
    rows (5 and 11 containers), the whole 16-container plant of its reference data, and plants of 32,
    64 and 128 containers that are *not in the paper*: copies of the 16-container plant with PUs in
    proportion (``n32_m4``, ``n64_m8``, ``n128_m16``) or scarce (``n32_m3``, ``n64_m6``,
    ``n128_m12``), built by ``configs/scaled.py``. At most one container is emptied per step in this
    view, whatever n: on the largest plants that cap, not the PUs, can decide.

    ## Arguments
    ``config``: built-in name, path or :class:`PlantConfig` (default ``"n5_m2_dt120"``);
    ``protocol="paper_test"`` sets the paper's test protocol (δ = 120 s, T = 600); further keyword
    arguments override plant-level config fields (``timestep_s=60``, ``episode_length_steps=600``…);
    ``render_mode``: ``None``, ``"human"`` (a live diagram, drawn at every reset and step; shown in
    a window only when a display is available, otherwise drawn off-screen without blocking),
    ``"rgb_array"`` (that diagram as an ``(H, W, 3)`` uint8 frame) or ``"ansi"`` (text); see
    :mod:`containergym_marl.render`.

    ## Info
    The same keys, with values of the same types, at ``reset`` and at every ``step``, never None
    (Gymnasium's vector envs and TorchRL build their info arrays and specs from the first info
    they see):

    | key                     | type  | meaning; value when nothing happened (and at reset)        |
    |-------------------------|-------|------------------------------------------------------------|
    | ``step``                | int   | steps taken in this episode (0 at reset)                   |
    | ``emptied_container``   | str   | name of the container emptied this step; ``""``            |
    | ``emptied_index``       | int   | its index 0 … n-1 (action − 1); -1                         |
    | ``emptied_volume``      | float | its volume before emptying; 0.0                            |
    | ``emptying_reward``     | float | reward of this step's emptying decision before any         |
    |                         |       | overflow replacement (r_pen if no PU was free); 0.0        |
    | ``pu_index``            | int   | PU that took the container; -1                             |
    | ``no_free_pu``          | bool  | an emptying action found every PU busy; False              |
    | ``overflowed_containers`` | tuple | names of the containers that reached v_max; ``()``       |
    | ``free_pus``            | int   | free PUs before the step (at reset: free PUs now, m)       |

    ## Version history
    * v0: first release. Differences from the earlier reference implementation: the PU timer is
      g(v) at t+1 (the reference also subtracted δ in the emptying step), one normal draw per
      container and step instead of δ per-second draws (same distribution), all randomness from
      the seed given to ``reset``, and time-limit ends are ``truncated`` rather than ``done``.
      Infos have the same keys and value types at reset and every step: an empty step reports
      ``emptied_container=""``, ``emptied_index=-1``, ``pu_index=-1``, ``emptied_volume=0.0``
      (earlier builds of v0 gave None and a reset info with two keys only).
    """

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": RENDER_FPS}

    def __init__(
        self,
        config: str | PlantConfig = "n5_m2_dt120",
        *,
        render_mode: str | None = None,
        protocol: str | None = None,
        **overrides: Any,
    ):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode: {render_mode!r} not supported; choose from {self.metadata['render_modes']}"
            )
        self.config = load_config(config, protocol=protocol, **overrides)
        self.render_mode = render_mode
        self._sim = PlantSimulator(self.config, num_sims=1)
        self._renderer = EnvRenderer(self._sim, render_mode, view="centralised")
        params = self._sim.params
        self.n_containers, self.n_pus = params.n_containers, params.n_pus
        self._info = CentralisedInfo(self.config.container_names)
        self.action_space = spaces.Discrete(self.n_containers + 1)
        # action a -> its (1, n) request row: none for 0, container a - 1 otherwise (the step copies it)
        self._requests_of_action = np.eye(self.n_containers + 1, self.n_containers, k=-1, dtype=bool)[:, None, :]
        low, high = global_state_bounds(params)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)

    @property
    def simulator(self) -> PlantSimulator:
        """The underlying single-simulation core (read it, do not step it directly)."""
        return self._sim

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=check_seed(seed))  # numpy integers as the vector envs take them; no bools
        self._sim.reset(generators=[self.np_random])
        if self.render_mode == "human":
            self.render()
        return self._observation(), self._info.reset(self.n_pus)

    def step(self, action):
        a = discrete_action(action, self.n_containers + 1, "action")
        out = self._sim.step(self._requests_of_action[a])
        info = self._info.step(a, out, self._sim.state.step_count.item(0))
        if self.render_mode == "human":
            self.render()
        return self._observation(), out.plant_reward.item(0), out.terminated.item(0), out.truncated.item(0), info

    def action_masks(self) -> np.ndarray:
        """Valid actions for MaskablePPO: 'do nothing' always; emptying only while a PU is free."""
        any_free = bool(self._sim.free_pu_count()[0] > 0)
        return np.array([True] + [any_free] * self.n_containers, dtype=bool)

    def render(self):
        """The current state in ``render_mode``: text ("ansi"), a frame ("rgb_array") or None."""
        return self._renderer.render()

    def close(self):
        """Close the rendering figure (and its window, if any)."""
        self._renderer.close()

    def _observation(self) -> np.ndarray:
        return self._sim.global_state()[0]
