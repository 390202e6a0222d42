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

from functools import lru_cache

import numpy as np

from containergym_marl.core.dynamics import PlantState, emptying_reward, per_entry, row_count
from containergym_marl.core.params import PlantParams

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


def agent_feature_names(params: PlantParams) -> list[str]:
    return (
        list(SCALAR_FEATURES)
        + [f"pu_timer_frac[{j}]" for j in range(params.n_pus)]
        + [f"container_one_hot[{i}]" for i in range(params.n_containers)]
    )


def _read_only(*arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    for a in arrays:
        a.setflags(write=False)
    return arrays


@lru_cache(maxsize=64)  # params are immutable and hashed by identity
def global_state_bounds(params: PlantParams) -> tuple[np.ndarray, np.ndarray]:
    low = np.zeros(params.n_containers + params.n_pus, dtype=np.float32)
    high = np.concatenate(
        [VOLUME_BOUND_FACTOR * params.max_volume, np.full(params.n_pus, params.max_pu_time_s)]
    ).astype(np.float32)
    return _read_only(low, high)


def global_state(state: PlantState, params: PlantParams) -> np.ndarray:
    """(B, n + m) float32 ``[v, p]``, clipped into :func:`global_state_bounds`."""
    low, high = global_state_bounds(params)
    # cast to float32, then clipped in float32 (as astype + clip); the array method skips
    # np.clip's Python-level dispatch, a third of this function's time for one simulation
    out = np.concatenate((state.volumes, state.pu_timers_s), axis=1, dtype=np.float32)
    return out.clip(low, high, out=out)


@lru_cache(maxsize=64)
def agent_observation_bounds(params: PlantParams) -> tuple[np.ndarray, np.ndarray]:
    n, m = params.n_containers, params.n_pus
    low = np.zeros(len(SCALAR_FEATURES) + m + n, dtype=np.float32)
    high = np.ones_like(low)
    high[0] = VOLUME_BOUND_FACTOR
    low[2] = -VOLUME_BOUND_FACTOR
    low[7] = params.penalty_reward
    return _read_only(low, high)


@lru_cache(maxsize=64)
def _agent_observation_template(params: PlantParams) -> np.ndarray:
    """(n, F) float32: the entries that never change (1, 3–6 and the one-hot), clipped; the
    others are filled by :func:`agent_observations`."""
    n, m = params.n_containers, params.n_pus
    vmax = params.max_volume
    t = np.zeros((n, len(SCALAR_FEATURES) + m + n))
    t[:, 1] = params.target_volume / vmax
    t[:, 3] = vmax / vmax.max()
    t[:, 4] = params.fill_mean_per_step / vmax
    t[:, 5] = params.fill_std_per_step / vmax
    t[:, 6] = params.product_size / vmax
    t[:, len(SCALAR_FEATURES) + m:] = np.eye(n)
    low, high = agent_observation_bounds(params)
    return _read_only(np.clip(t.astype(np.float32), low, high))[0]


def _count_greater(x: np.ndarray) -> np.ndarray:
    """(B, n) int64: for each entry, how many entries of its row are strictly larger."""
    b, n = x.shape
    if b < 64:
        return (x[:, None, :] > x[:, :, None]).sum(axis=2)
    xt = np.ascontiguousarray(x.T)  # (n, B): each comparison below runs over B contiguous entries
    out = np.zeros((n, b), dtype=np.int64)
    for j in range(n):  # a loop over containers, not simulations
        out += xt[j] > xt
    return out.T


def agent_observations(
    state: PlantState, params: PlantParams, previous_requests: np.ndarray
) -> np.ndarray:
    """(B, n, F) float32 observations of every container agent; see the module docstring.

    Every entry is computed in float64, cast to float32 and clipped into
    :func:`agent_observation_bounds`.
    """
    v, p = state.volumes, state.pu_timers_s
    bsz, n = v.shape
    m = params.n_pus
    const = per_entry(params, bsz)  # (B, n) tiles of the per-container constants if B is large
    vmax = const.max_volume
    others = max(n - 1, 1)  # with one container the "others" shares are 0
    ns = len(SCALAR_FEATURES)

    def per_sim(x: np.ndarray) -> np.ndarray:  # (B,) -> (B, n), flat for cheap assignment
        return np.repeat(x, n).reshape(bsz, n)

    low, high = agent_observation_bounds(params)

    def clipped(x: np.ndarray, col: int) -> np.ndarray:
        # Clipping the float64 values into the float32-representable bounds, then casting, gives
        # exactly the float32 cast clipped in float32 (rounding is monotonic); and it is cheap here,
        # on contiguous arrays, instead of on the output's strided columns.
        return np.clip(x, float(low[col]), float(high[col]), out=x)

    out = np.empty((bsz, n, ns + m + n), dtype=np.float32)
    out.reshape(bsz, -1)[...] = _agent_observation_template(params).reshape(-1)  # entries 1, 3–6, one-hot
    vol_frac = v / vmax
    out[..., 0] = clipped(vol_frac.copy(), 0)
    out[..., 2] = clipped((const.target_volume - v) / vmax, 2)
    out[..., 7] = clipped(emptying_reward(v, params), 7)
    out[..., 8] = per_sim(clipped(row_count(p == 0.0) / m, 8))
    prev = np.asarray(previous_requests, dtype=bool)
    out[..., 9] = clipped((per_sim(row_count(prev)) - prev) / others, 9)
    ready = v >= const.target_volume - READY_MARGIN
    out[..., 10] = clipped((per_sim(row_count(ready)) - ready) / others, 10)
    # Containers fuller than each one: they win the default "fullest" arbitration.
    out[..., 11] = clipped(_count_greater(vol_frac) / others, 11)
    timers = p / params.max_pu_time_s
    for j in range(m):
        out[..., ns + j] = per_sim(clipped(timers[:, j].copy(), ns + j))
    return out
