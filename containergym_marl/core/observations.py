"""Observations built from the state: the global state and the container agents' view.

Global state (the centralised observation and ``state()`` of the decentralised view):
``[v_1..v_n, p_1..p_m]`` in physical units (volume units, seconds), float32. Volumes are bounded
by 2·v_max for the space's sake; only the terminal observation of an overflow can exceed v_max.

Container-agent observation: one float32 vector per container, the same layout and bounds for every
agent so that one shared policy can act for all of them. Entries (F = 12 + m + n):

====  =======================  ===================================================  ==============
idx   name                     meaning                                              bounds
====  =======================  ===================================================  ==============
0     volume_frac              own volume v / v_max                                 [0, 2]
1     target_frac              own global-optimum volume v* / v_max                 [0, 1]
2     gap_to_target_frac       (v* − v) / v_max; 0 at the target, < 0 past it       [-2, 1]
3     max_volume_frac          own v_max / largest v_max of the plant               [0, 1]
4     fill_rate_frac           expected inflow per step μδ / v_max                  [0, 1]
5     fill_noise_frac          inflow noise per step σ√δ / v_max                    [0, 1]
6     product_size_frac        product size b / v_max                               [0, 1]
7     reward_if_emptied        reward of emptying now, given a free PU              [r_pen, 1]
8     free_pu_frac             free PUs / m                                         [0, 1]
9     others_requested_frac    share of the other agents that requested last step   [0, 1]
10    others_ready_frac        share of the others within 1 volume unit of their    [0, 1]
                               target or past it (the rule-based controller's cue)
11    others_fuller_frac       share of the others with a larger v / v_max (who     [0, 1]
                               win the default "fullest" arbitration)
12+j  pu_timer_frac[j]         PU j's timer / largest possible PU time, j < m       [0, 1]
12+m  container_one_hot[i]     1 for the agent's own container index, i < n         [0, 1]
====  =======================  ===================================================  ==============

Entries 1 and 3–6 identify the container by its physics; the one-hot makes identity explicit.
"""

from __future__ import annotations

import numpy as np

from containergym_marl.core.dynamics import PlantState, emptying_reward
from containergym_marl.config.pu_time import jit
from containergym_marl.core.params import PlantParams, unpack_params

#: The rule-based controller's margin (paper, section 6.2), also used by ``others_ready_frac``.
READY_MARGIN = 1.0  # v >= v* − margin counts as ready
VOLUME_BOUND_FACTOR = 2.0

SCALAR_FEATURES = (
    "volume_frac",
    "target_frac",
    "gap_to_target_frac",
    "max_volume_frac",
    "fill_rate_frac",
    "fill_noise_frac",
    "product_size_frac",
    "reward_if_emptied",
    "free_pu_frac",
    "others_requested_frac",
    "others_ready_frac",
    "others_fuller_frac",
)
N_SCALAR_FEATURES = len(SCALAR_FEATURES)


def agent_feature_names(params: PlantParams) -> list[str]:
    return (
        list(SCALAR_FEATURES)
        + [f"pu_timer_frac[{j}]" for j in range(params.n_pus)]
        + [f"container_one_hot[{i}]" for i in range(params.n_containers)]
    )


def global_state_bounds(params: PlantParams) -> tuple[np.ndarray, np.ndarray]:
    """float32 bounds of the global state ``[v, p]``: volumes in [0, 2·v_max], timers in
    [0, largest PU time]."""
    low = np.zeros(params.n_containers + params.n_pus, dtype=np.float32)
    high = np.concatenate(
        [VOLUME_BOUND_FACTOR * params.max_volume, np.full(params.n_pus, params.max_pu_time_s)]
    ).astype(np.float32)
    return low, high


def agent_observation_bounds(params: PlantParams) -> tuple[np.ndarray, np.ndarray]:
    """float32 bounds of a container agent's observation (the table in the module docstring)."""
    n, m = params.n_containers, params.n_pus
    low = np.zeros(len(SCALAR_FEATURES) + m + n, dtype=np.float32)
    high = np.ones_like(low)
    high[0] = VOLUME_BOUND_FACTOR
    low[2] = -VOLUME_BOUND_FACTOR
    low[7] = params.penalty_reward
    return low, high


@jit
def _clipped(x, low, high):
    """float32(x) clipped into [low, high] (float32 bounds)."""
    return min(max(np.float32(x), np.float32(low)), np.float32(high))


@jit
def _global_state_into(volumes, timers, max_volume, max_pu_time_s, out):
    n = volumes.shape[1]
    for b in range(volumes.shape[0]):
        for i in range(n):
            out[b, i] = _clipped(volumes[b, i], 0.0, VOLUME_BOUND_FACTOR * max_volume[i])
        for j in range(timers.shape[1]):
            out[b, n + j] = _clipped(timers[b, j], 0.0, max_pu_time_s)


def global_state(state: PlantState, params: PlantParams) -> np.ndarray:
    """(B, n + m) float32 ``[v, p]``, clipped into :func:`global_state_bounds`."""
    v = state.volumes
    out = np.empty((v.shape[0], v.shape[1] + params.n_pus), np.float32)
    _global_state_into(v, state.pu_timers_s, params.max_volume, params.max_pu_time_s, out)
    return out


@jit
def _agent_observations_into(volumes, timers, previous_requests, out, per_container, reward_table, scalars):
    params = unpack_params(per_container, reward_table, scalars)
    bsz, n = volumes.shape
    m = timers.shape[1]
    others = max(n - 1, 1)  # with one container the "others" shares are 0
    ns = N_SCALAR_FEATURES
    largest_max_volume = params.max_volume.max()
    r_pen, bound = params.penalty_reward, VOLUME_BOUND_FACTOR
    for b in range(bsz):
        v, p = volumes[b], timers[b]
        free = 0
        for j in range(m):
            free += p[j] == 0.0
        requested = 0
        ready = 0
        for i in range(n):
            requested += previous_requests[b, i]
            ready += v[i] >= params.target_volume[i] - READY_MARGIN
        for i in range(n):
            vmax = params.max_volume[i]
            row = out[b, i]
            volume_frac = v[i] / vmax
            fuller = 0
            for k in range(n):
                fuller += v[k] / params.max_volume[k] > volume_frac
            row[0] = _clipped(volume_frac, 0.0, bound)
            row[1] = _clipped(params.target_volume[i] / vmax, 0.0, 1.0)
            row[2] = _clipped((params.target_volume[i] - v[i]) / vmax, -bound, 1.0)
            row[3] = _clipped(vmax / largest_max_volume, 0.0, 1.0)
            row[4] = _clipped(params.fill_mean_per_step[i] / vmax, 0.0, 1.0)
            row[5] = _clipped(params.fill_std_per_step[i] / vmax, 0.0, 1.0)
            row[6] = _clipped(params.product_size[i] / vmax, 0.0, 1.0)
            row[7] = _clipped(emptying_reward(i, v[i], params), r_pen, 1.0)
            row[8] = _clipped(free / m, 0.0, 1.0)
            row[9] = _clipped((requested - previous_requests[b, i]) / others, 0.0, 1.0)
            row[10] = _clipped((ready - (v[i] >= params.target_volume[i] - READY_MARGIN)) / others, 0.0, 1.0)
            row[11] = _clipped(fuller / others, 0.0, 1.0)
            for j in range(m):
                row[ns + j] = _clipped(p[j] / params.max_pu_time_s, 0.0, 1.0)
            for k in range(n):
                row[ns + m + k] = 1.0 if k == i else 0.0


def agent_observations(
    state: PlantState, params: PlantParams, previous_requests: np.ndarray
) -> np.ndarray:
    """(B, n, F) float32 observations of every container agent; see the module docstring.

    Every entry is computed in float64, cast to float32 and clipped into
    :func:`agent_observation_bounds`.
    """
    v = state.volumes
    bsz, n = v.shape
    previous_requests = np.ascontiguousarray(previous_requests, dtype=bool)
    if previous_requests.shape != (bsz, n):
        raise ValueError(f"previous_requests: expected shape {(bsz, n)}, got {previous_requests.shape}")
    out = np.empty((bsz, n, len(SCALAR_FEATURES) + params.n_pus + n), dtype=np.float32)
    _agent_observations_into(v, state.pu_timers_s, previous_requests, out, *params.kernel_arrays())
    return out
