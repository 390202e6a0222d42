"""Immutable array form of a plant config: what the pure physics functions read."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _frozen(a) -> np.ndarray:
    out = np.array(a, dtype=np.float64)
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class PlantParams:
    """Per-container arrays (shape ``(n,)`` or ``(n, K)``) and plant scalars.

    Reward peaks are padded to the largest number of peaks ``K``; padded entries have a zero
    coefficient ``h - r_pen`` so they add nothing to the reward.
    """

    n_containers: int
    n_pus: int
    timestep_s: float
    episode_length_steps: int
    initial_volume_min: float
    initial_volume_max: float
    overflow_reward: float  # r_min
    penalty_reward: float  # r_pen
    fill_mean_per_step: np.ndarray  # μ·δ
    fill_std_per_step: np.ndarray  # σ·√δ
    max_volume: np.ndarray
    product_size: np.ndarray
    pu_offset_s: np.ndarray  # β
    pu_time_per_product_s: np.ndarray  # λ
    reward_peaks: np.ndarray  # (n, K)
    reward_coef: np.ndarray  # (n, K): h - r_pen, 0 for padding
    reward_two_width_sq: np.ndarray  # (n, K): 2 w², 1 for padding
    target_volume: np.ndarray  # global optimum per container
    max_pu_time_s: float  # largest g_i(v) for v < v_max: an upper bound of every PU timer

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
        c_arr = lambda attr: np.array([getattr(c, attr) for c in cfg.containers], dtype=np.float64)  # noqa: E731
        vmax = c_arr("max_volume")
        b = c_arr("product_size")
        beta = c_arr("pu_offset_s")
        lam = c_arr("pu_time_per_product_s")
        # A container is only emptied while v < v_max (reaching v_max ends the episode), so
        # g(v) <= β + λ·⌊v_max / b⌋ bounds every timer.
        max_pu_time = float(np.max(beta + lam * np.floor(vmax / b)))
        dt = float(cfg.timestep_s)
        return cls(
            n_containers=n,
            n_pus=int(cfg.num_processing_units),
            timestep_s=dt,
            episode_length_steps=int(cfg.episode_length_steps),
            initial_volume_min=float(cfg.initial_volume_min),
            initial_volume_max=float(cfg.initial_volume_max),
            overflow_reward=float(cfg.overflow_reward),
            penalty_reward=float(cfg.penalty_reward),
            fill_mean_per_step=_frozen(c_arr("fill_rate_per_s") * dt),
            fill_std_per_step=_frozen(c_arr("fill_noise_per_sqrt_s") * np.sqrt(dt)),
            max_volume=_frozen(vmax),
            product_size=_frozen(b),
            pu_offset_s=_frozen(beta),
            pu_time_per_product_s=_frozen(lam),
            reward_peaks=_frozen(peaks),
            reward_coef=_frozen(coef),
            reward_two_width_sq=_frozen(two_w_sq),
            target_volume=_frozen([c.target_volume for c in cfg.containers]),
            max_pu_time_s=max_pu_time,
        )
