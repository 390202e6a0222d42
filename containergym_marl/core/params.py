"""Immutable array form of a plant config: what the compiled physics step reads.

``PlantParams`` is a named tuple of read-only arrays and plain numbers, so numba takes it as one
argument with named fields (gymnax's ``EnvParams``, kept apart from the state). It is derived from a
:class:`~containergym_marl.config.PlantConfig` by :meth:`PlantParams.from_config`; the config knows
nothing about it.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


#: Columns of PlantParams.per_container, in order.
PER_CONTAINER_COLUMNS = ("fill_mean_per_step", "fill_std_per_step", "max_volume", "product_size", "pu_offset_s",
                         "pu_time_per_product_s", "target_volume")
#: Entries of PlantParams.scalars, in order.
SCALARS = ("n_containers", "n_pus", "timestep_s", "episode_length_steps", "initial_volume_min",
           "initial_volume_max", "overflow_reward", "penalty_reward", "max_pu_time_s")


def _frozen(a) -> np.ndarray:
    out = np.array(a, dtype=np.float64)
    out.setflags(write=False)
    return out


class PlantParams(NamedTuple):
    """Per-container arrays (shape ``(n,)`` or ``(n, K)``) and plant scalars.

    Reward peaks are padded to the largest number of peaks ``K``; padded entries have a zero
    coefficient ``h - r_pen`` so they add nothing to the reward.
    """

    n_containers: int
    n_pus: int
    timestep_s: float  # δ
    episode_length_steps: int  # T
    initial_volume_min: float
    initial_volume_max: float
    overflow_reward: float  # r_min
    penalty_reward: float  # r_pen
    fill_mean_per_step: np.ndarray  # μ·δ, volume units per step
    fill_std_per_step: np.ndarray  # σ·√δ
    max_volume: np.ndarray  # v_max
    product_size: np.ndarray  # b, volume units per product
    pu_offset_s: np.ndarray  # β
    pu_time_per_product_s: np.ndarray  # λ
    reward_peaks: np.ndarray  # (n, K) v*_k
    reward_coef: np.ndarray  # (n, K): h_k - r_pen, 0 for padding
    reward_two_width_sq: np.ndarray  # (n, K): 2 w_k², 1 for padding
    target_volume: np.ndarray  # the global optimum v* of each container
    max_pu_time_s: float  # largest g_i(v) for v < v_max: an upper bound of every PU timer
    # The storage of everything above, in three arrays: the per-container arrays are views of
    # ``per_container`` and ``reward_table``. The compiled step takes these three (numba unpacks
    # each argument of a call, so three arrays cost far less than nineteen fields) and rebuilds the
    # named tuple inside (:func:`containergym_marl.core.dynamics.unpack_params`).
    per_container: np.ndarray  # (n, 7): the columns PER_CONTAINER_COLUMNS
    reward_table: np.ndarray  # (3, n, K): reward_peaks, reward_coef, reward_two_width_sq
    scalars: np.ndarray  # (9,): SCALARS

    def kernel_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.per_container, self.reward_table, self.scalars

    @classmethod
    def from_config(cls, cfg) -> "PlantParams":
        n = cfg.n_containers
        k = max(len(c.reward_peaks) for c in cfg.containers)
        peaks = np.zeros((n, k))
        coef = np.zeros((n, k))
        two_w_sq = np.ones((n, k))
        for i, c in enumerate(cfg.containers):
            p = len(c.reward_peaks)
            peaks[i, :p] = c.reward_peaks
            coef[i, :p] = np.asarray(c.reward_heights) - cfg.penalty_reward
            two_w_sq[i, :p] = 2.0 * np.asarray(c.reward_widths) ** 2

        def column(attr: str) -> np.ndarray:
            return np.array([getattr(c, attr) for c in cfg.containers], dtype=np.float64)

        vmax, size = column("max_volume"), column("product_size")
        beta, lam = column("pu_offset_s"), column("pu_time_per_product_s")
        # A container is only emptied while v < v_max (reaching v_max ends the episode), so
        # g(v) <= β + λ·⌊v_max / b⌋ bounds every timer.
        max_pu_time = float(np.max(beta + lam * np.floor(vmax / size)))
        dt = float(cfg.timestep_s)
        columns = {
            "fill_mean_per_step": column("fill_rate_per_s") * dt,
            "fill_std_per_step": column("fill_noise_per_sqrt_s") * np.sqrt(dt),
            "max_volume": vmax,
            "product_size": size,
            "pu_offset_s": beta,
            "pu_time_per_product_s": lam,
            "target_volume": np.array([c.target_volume for c in cfg.containers], dtype=np.float64),
        }
        per_container = _frozen(np.stack([columns[name] for name in PER_CONTAINER_COLUMNS], axis=1))
        reward_table = _frozen(np.stack([peaks, coef, two_w_sq]))
        scalar = {
            "n_containers": n,
            "n_pus": int(cfg.num_processing_units),
            "timestep_s": dt,
            "episode_length_steps": int(cfg.episode_length_steps),
            "initial_volume_min": float(cfg.initial_volume_min),
            "initial_volume_max": float(cfg.initial_volume_max),
            "overflow_reward": float(cfg.overflow_reward),
            "penalty_reward": float(cfg.penalty_reward),
            "max_pu_time_s": max_pu_time,
        }
        views = {name: per_container[:, k] for k, name in enumerate(PER_CONTAINER_COLUMNS)}
        return cls(
            **scalar,
            **views,
            reward_peaks=reward_table[0],
            reward_coef=reward_table[1],
            reward_two_width_sq=reward_table[2],
            per_container=per_container,
            reward_table=reward_table,
            scalars=_frozen([scalar[name] for name in SCALARS]),
        )
