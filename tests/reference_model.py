"""An independent, deliberately naive oracle of one ContainerGym step (tests only).

Written from the paper's equations (section 5) and the arbitration rules in plain Python loops over
scalars, sharing no code with the package's vectorised core. Tests compare the core against it.
"""

from __future__ import annotations

import math


def paper_reward(spec, volume: float, r_pen: float) -> float:
    """Paper eq. 5: r_pen + Σ (h − r_pen)·exp(−(v − v*)²/(2w²)); r_pen for an empty container."""
    if volume == 0.0:
        return r_pen
    total = r_pen
    for peak, height, width in zip(spec.reward_peaks, spec.reward_heights, spec.reward_widths):
        total += (height - r_pen) * math.exp(-((volume - peak) ** 2) / (2.0 * width**2))
    return total


def busy_time(spec, volume: float) -> float:
    """Paper eq. 2: β + λ·⌊v / b⌋."""
    return spec.pu_offset_s + spec.pu_time_per_product_s * math.floor(volume / spec.product_size)


def step_one(cfg, volumes, timers, step_count, requests, normals, uniforms, rule):
    """One step of one simulation. Returns (volumes, timers, step_count, rewards, plant_reward,
    terminated, truncated, granted, pus)."""
    n, dt = cfg.n_containers, cfg.timestep_s
    r_pen = cfg.penalty_reward
    free_pus = [j for j, t in enumerate(timers) if t == 0.0]

    def priority(i):
        spec = cfg.containers[i]
        if rule == "fullest":
            return volumes[i] / spec.max_volume
        if rule == "random":
            return uniforms[i]
        if rule == "index":
            return -i
        if rule == "best_reward":
            return paper_reward(spec, volumes[i], r_pen)
        raise ValueError(rule)

    candidates = [i for i in range(n) if requests[i]]
    # Highest priority first; among equals the lower index (sorted is stable on index order).
    candidates.sort(key=lambda i: -priority(i))
    granted = candidates[: len(free_pus)]
    # granted containers in index order take the free PUs in index order
    pus = {i: free_pus[r] for r, i in enumerate(sorted(granted))}

    rewards = [0.0] * n
    for i in candidates:
        rewards[i] = paper_reward(cfg.containers[i], volumes[i], r_pen) if i in pus else r_pen

    new_volumes = []
    for i, spec in enumerate(cfg.containers):
        if i in pus:
            new_volumes.append(0.0)
        else:
            inc = spec.fill_rate_per_s * dt + spec.fill_noise_per_sqrt_s * math.sqrt(dt) * normals[i]
            new_volumes.append(max(0.0, volumes[i] + inc))
    new_timers = [max(0.0, t - dt) for t in timers]
    for i, j in pus.items():
        new_timers[j] = busy_time(cfg.containers[i], volumes[i])

    step_count += 1
    overflow = [v >= spec.max_volume for v, spec in zip(new_volumes, cfg.containers)]
    terminated = any(overflow)
    truncated = (step_count >= cfg.episode_length_steps) and not terminated
    plant_reward = cfg.overflow_reward if terminated else sum(rewards)
    individual = [cfg.overflow_reward if o else r for o, r in zip(overflow, rewards)]
    return (new_volumes, new_timers, step_count, individual, plant_reward, terminated, truncated,
            granted, pus)
