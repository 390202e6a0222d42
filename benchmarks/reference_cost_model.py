"""A timing baseline: the *cost model* of the earlier ContainerGym reference implementation.

This is not part of the package and not a physics reference (the package's physics differs from
the earlier code in documented ways, see README "Differences from the earlier reference
implementation"). It re-creates, in a small self-contained class, what the earlier ``step`` paid
for per call, so that speed-ups are ratios measured in the same run on the same machine:

* ``math.floor`` of the emptied container's volume over its product size (number of bales);
* the fill: ``δ`` per-second normal draws per container, ``normal(loc=μ, scale=σ, size=(δ, n))``
  summed over the seconds, then ``np.clip(..., 0, None)`` — the dominant cost;
* a Python list comprehension over the PUs to find the free ones and ``choice`` among them;
* a press-model method call computing the PU time;
* ``np.clip(press_times - δ, 0, None)`` for the timers;
* a reward method with a Python loop over the reward peaks (``np.exp`` per peak);
* ``(volumes < max_volumes).all()`` for the overflow check;
* the observation as a dict of arrays ``{"Volumes": ..., "Time presses will be free": ...}`` and
  ``info = {"press_indices": idx}``.

``rng="generator"`` draws from a ``np.random.Generator`` (ziggurat normals, as the package does);
``rng="global"`` uses the legacy global ``np.random`` functions as the earlier code did (polar
Box–Muller normals, slower). Both are timed by the benchmark; the package itself never touches the
global random state.
"""

from __future__ import annotations

import math

import numpy as np


class _PressModel:
    def __init__(self, offsets, slopes):
        self.offsets = list(offsets)
        self.slopes = list(slopes)

    def pressing_time(self, time_prev_pressing_done, container_idx, n_bales):
        if 0.0 > time_prev_pressing_done or not self.slopes[container_idx]:
            return None
        return self.slopes[container_idx] * n_bales + self.offsets[container_idx]


class _RewardEvaluator:
    def __init__(self, peaks, heights, widths, min_reward):
        self.peaks, self.heights, self.widths = peaks, heights, widths
        self.min_reward = min_reward

    def reward(self, action, volume, press_is_free, container_idx):
        reward = 0.0
        if action > 0:
            if volume == 0.0 or not press_is_free:
                return self.min_reward
            peaks = self.peaks[container_idx]
            for k in range(len(peaks)):
                peak, height, width = peaks[k], self.heights[container_idx][k], self.widths[container_idx][k]
                reward += (height - self.min_reward) * np.exp(
                    -(volume - peak) * (volume - peak) / (2.0 * width * width))
            reward += self.min_reward
        return reward


class ReferenceCostModelEnv:
    """The earlier implementation's per-step work for one plant (gym 0.21-style 4-tuple API)."""

    def __init__(self, config, rng: str = "generator", seed: int = 0):
        if rng not in ("generator", "global"):
            raise ValueError(f"rng: expected 'generator' or 'global', got {rng!r}")
        self.n = config.n_containers
        self.n_presses = config.num_processing_units
        self.timestep = int(round(config.timestep_s))
        self.max_episode_length = config.episode_length_steps
        self.min_v0, self.max_v0 = config.initial_volume_min, config.initial_volume_max
        self.failure_penalty = config.overflow_reward
        cs = config.containers
        self.mus = np.array([c.fill_rate_per_s for c in cs])
        self.sigmas = np.array([c.fill_noise_per_sqrt_s for c in cs])
        self.max_volumes = np.array([c.max_volume for c in cs])
        self.bale_sizes = np.array([c.product_size for c in cs])
        self.press_model = _PressModel([c.pu_offset_s for c in cs], [c.pu_time_per_product_s for c in cs])
        self.reward_evaluator = _RewardEvaluator(
            [list(c.reward_peaks) for c in cs], [list(c.reward_heights) for c in cs],
            [list(c.reward_widths) for c in cs], config.penalty_reward)
        if rng == "generator":
            gen = np.random.default_rng(seed)
            self._normal, self._choice, self._uniform = gen.normal, gen.choice, gen.uniform
        else:
            np.random.seed(seed)  # noqa: NPY002 - the earlier code's global state, on purpose
            self._normal, self._choice, self._uniform = np.random.normal, np.random.choice, np.random.uniform  # noqa: NPY002
        self.volumes = np.zeros(self.n)
        self.press_times = np.zeros(self.n_presses)
        self.episode_length = 0

    def reset(self):
        self.volumes = self._uniform(self.min_v0, self.max_v0, size=self.n)
        self.press_times = np.zeros(self.n_presses)
        self.episode_length = 0
        return {"Volumes": self.volumes, "Time presses will be free": self.press_times}

    def _future_volume(self, volumes):
        walk = self._normal(loc=self.mus, scale=self.sigmas, size=(self.timestep, len(volumes)))
        return np.clip(volumes + walk.sum(axis=0), a_min=0, a_max=None)

    def step(self, action):
        press_is_free = False
        emptied_volume = 0
        container_idx = -1
        press_idx = 0
        n_bales = 0
        if action != 0:
            container_idx = (action - 1) % self.n
            n_bales = math.floor(self.volumes[container_idx] / self.bale_sizes[container_idx])
            emptied_volume = self.volumes[container_idx]
        self.volumes = self._future_volume(self.volumes)
        if action > 0:
            free_presses = [idx for idx, t in enumerate(self.press_times) if t == 0]
            if free_presses:
                press_idx = self._choice(free_presses)
                ends = self.press_model.pressing_time(self.press_times[press_idx], container_idx, n_bales)
                if ends is not None:
                    press_is_free = True
                    self.volumes[container_idx] = 0
                    self.press_times[press_idx] = ends
        self.press_times = np.clip(self.press_times - self.timestep, a_min=0, a_max=None)
        self.episode_length += 1
        reward = self.reward_evaluator.reward(action, emptied_volume, press_is_free, container_idx)
        done = False
        if not (self.volumes < self.max_volumes).all():
            done = True
            reward = self.failure_penalty
        if self.episode_length == self.max_episode_length:
            done = True
        info = {"press_indices": press_idx}
        obs = {"Volumes": self.volumes, "Time presses will be free": self.press_times}
        return obs, reward, done, info
