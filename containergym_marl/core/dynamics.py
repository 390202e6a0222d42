"""The ContainerGym MDP (paper, section 5) as pure, batched numpy functions.

Shapes: B simulations, n containers, m processing units (PUs). The action input of :func:`step` is a
``(B, n)`` boolean *request* matrix: ``requests[b, i]`` asks to empty container i of simulation b.
The centralised controller makes at most one request per step; container agents may make many, and
:func:`arbitrate` grants at most as many as there are free PUs.

One step, for each simulation (all quantities at time t unless marked):

1. PU j is free iff its timer is 0. Requests are ranked by the arbitration rule and the first
   ``f`` (number of free PUs) are *granted*; the rest are *denied*.
2. Rewards per container: granted → Gaussian emptying reward of v_i (r_pen if v_i = 0, the PU is
   still used); denied → r_pen (the paper's "no free PU"); no request → 0.
3. Volumes at t+1: granted containers are 0; every other container gets
   ``max(0, v + N(μδ, σ²δ))`` (one normal draw per container).
4. Timers at t+1: the PU taken by granted container i is set to g_i(v_i) = β_i + λ_i⌊v_i / b_i⌋
   (the paper's equation; the earlier reference code also subtracted δ in the same step); every
   other timer becomes ``max(0, p − δ)``. The granted containers, in container-index order, take
   the free PUs in PU-index order (PUs are identical, so this choice does not change dynamics).
5. Overflow: if any v_j(t+1) ≥ v_max,j the plant reward is r_min (replacing the step's reward) and
   the episode terminates. Otherwise it is truncated when the step count reaches T.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from containergym_marl.core.params import PlantParams

ARBITRATION_RULES = ("fullest", "random", "index", "best_reward")


@dataclass(frozen=True, eq=False)
class PlantState:
    """State of B simulations: the paper's s_t = (v, p) plus the step counter."""

    volumes: np.ndarray  # (B, n) volume units
    pu_timers_s: np.ndarray  # (B, m) seconds until each PU is free
    step_count: np.ndarray  # (B,) steps taken in the current episode

    @property
    def batch_size(self) -> int:
        return self.volumes.shape[0]

    def select(self, sims: np.ndarray) -> "PlantState":
        return PlantState(self.volumes[sims], self.pu_timers_s[sims], self.step_count[sims])


@dataclass(frozen=True, eq=False)
class StepOutcome:
    """What happened in one step of B simulations (arrays shaped (B, n) or (B,))."""

    requested: np.ndarray  # (B, n) bool
    granted: np.ndarray  # (B, n) bool: emptied this step
    denied: np.ndarray  # (B, n) bool: requested but no free PU was left
    pu_index: np.ndarray  # (B, n) int: PU used by a granted container, -1 otherwise
    emptied_volume: np.ndarray  # (B, n): v_i(t) of granted containers, 0 otherwise
    container_reward: np.ndarray  # (B, n): emptying reward / r_pen / 0, before overflow
    overflowed: np.ndarray  # (B, n) bool: v_i(t+1) >= v_max,i
    individual_reward: np.ndarray  # (B, n): container_reward, r_min for overflowing containers
    plant_reward: np.ndarray  # (B,): sum of container_reward, replaced by r_min on overflow
    free_pus_before: np.ndarray  # (B,) int: free PUs at time t
    terminated: np.ndarray  # (B,) bool: a container overflowed
    truncated: np.ndarray  # (B,) bool: the time limit T was reached without overflow


def emptying_reward(volumes: np.ndarray, params: PlantParams) -> np.ndarray:
    """Reward of emptying each container at ``volumes`` (..., n), given a free PU (paper eq. 5).

    ``r_pen + Σ_k (h_k − r_pen)·exp(−(v − v*_k)² / (2 w_k²))``, and ``r_pen`` for an empty container.
    """
    v = np.asarray(volumes, dtype=np.float64)
    diff = v[..., None] - params.reward_peaks
    gauss = np.exp(-(diff * diff) / params.reward_two_width_sq)
    reward = params.penalty_reward + np.sum(params.reward_coef * gauss, axis=-1)
    return np.where(v == 0.0, params.penalty_reward, reward)


def pu_busy_time_s(volumes: np.ndarray, params: PlantParams, containers=slice(None)) -> np.ndarray:
    """g_i(v) = β_i + λ_i·⌊v / b_i⌋: seconds a PU is busy after emptying (paper eq. 2).

    ``volumes`` is (…, n), or matches ``containers`` (indices of the containers it belongs to).
    """
    return (params.pu_offset_s[containers]
            + params.pu_time_per_product_s[containers] * np.floor(volumes / params.product_size[containers]))


def reset_state(params: PlantParams, uniforms: np.ndarray) -> PlantState:
    """Initial state from one row of uniforms per simulation: v ~ U[v0_min, v0_max], p = 0."""
    b = uniforms.shape[0]
    lo, hi = params.initial_volume_min, params.initial_volume_max
    return PlantState(
        volumes=lo + (hi - lo) * uniforms,
        pu_timers_s=np.zeros((b, params.n_pus)),
        step_count=np.zeros(b, dtype=np.int64),
    )


def priority_keys(
    rule: str, volumes: np.ndarray, uniforms: np.ndarray, params: PlantParams
) -> np.ndarray:
    """Arbitration priority of each container, (B, n); larger wins, ties go to the lower index."""
    if rule == "fullest":
        return volumes / params.max_volume
    if rule == "random":
        return uniforms
    if rule == "index":
        return np.broadcast_to(-np.arange(params.n_containers, dtype=np.float64), volumes.shape)
    if rule == "best_reward":
        return emptying_reward(volumes, params)
    raise ValueError(f"arbitration: unknown rule {rule!r}; choose one of {ARBITRATION_RULES}")


def arbitrate(requests: np.ndarray, free_count: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Grant the ``free_count[b]`` highest-priority requests of each simulation, (B, n) bool."""
    b, n = requests.shape
    sort_key = np.where(requests, -keys, np.inf)
    order = np.argsort(sort_key, axis=1, kind="stable")  # stable: ties go to the lower index
    rank = np.empty((b, n), dtype=np.int64)
    np.put_along_axis(rank, order, np.broadcast_to(np.arange(n), (b, n)), axis=1)
    return requests & (rank < free_count[:, None])


def step(
    state: PlantState,
    requests: np.ndarray,
    params: PlantParams,
    normals: np.ndarray,
    uniforms: np.ndarray,
    arbitration: str = "fullest",
) -> tuple[PlantState, StepOutcome]:
    """Advance B simulations by one step of δ seconds. Pure: ``state`` is not modified.

    Args:
        state: the current state (B simulations).
        requests: (B, n) bool, which containers ask to be emptied.
        params: the plant.
        normals, uniforms: (B, n) one random row per simulation (see :mod:`.rng`).
        arbitration: rule ranking competing requests, one of :data:`ARBITRATION_RULES`.
    """
    v, p = state.volumes, state.pu_timers_s
    bsz, n = v.shape
    requests = np.asarray(requests, dtype=bool)
    if requests.shape != (bsz, n):
        raise ValueError(f"requests: expected shape {(bsz, n)}, got {requests.shape}")
    if arbitration not in ARBITRATION_RULES:
        raise ValueError(f"arbitration: unknown rule {arbitration!r}; choose one of {ARBITRATION_RULES}")

    free = p == 0.0
    free_count = free.sum(axis=1)
    filled = np.maximum(0.0, v + params.fill_mean_per_step + params.fill_std_per_step * normals)
    p_next = np.maximum(0.0, p - params.timestep_s)

    if requests.any():
        # Ranking is only needed where requests outnumber free PUs; elsewhere all are granted.
        contested = requests.sum(axis=1) > free_count
        granted = requests.copy()
        if contested.any():
            c = np.flatnonzero(contested)
            keys = priority_keys(arbitration, v[c], uniforms[c], params)
            granted[c] = arbitrate(requests[c], free_count[c], keys)
        denied = requests & ~granted
        # Rewards of this step's decisions, from the volumes before this step's inflow.
        container_reward = np.where(granted, emptying_reward(v, params), 0.0)
        container_reward[denied] = params.penalty_reward
        v_next = np.where(granted, 0.0, filled)
        # The k-th granted container (index order) takes the k-th free PU (index order).
        pu_index = np.full((bsz, n), -1, dtype=np.int64)
        sim_idx, cont_idx = np.nonzero(granted)
        if sim_idx.size:
            position = (np.cumsum(granted, axis=1) - 1)[sim_idx, cont_idx]
            pus = np.argsort(~free, axis=1, kind="stable")[sim_idx, position]
            pu_index[sim_idx, cont_idx] = pus
            p_next[sim_idx, pus] = pu_busy_time_s(v[sim_idx, cont_idx], params, cont_idx)
        emptied_volume = np.where(granted, v, 0.0)
    else:
        granted = denied = requests
        container_reward = emptied_volume = np.zeros((bsz, n))
        v_next = filled
        pu_index = np.full((bsz, n), -1, dtype=np.int64)

    step_count = state.step_count + 1
    overflowed = v_next >= params.max_volume
    terminated = overflowed.any(axis=1)
    truncated = (step_count >= params.episode_length_steps) & ~terminated
    plant_reward = np.where(terminated, params.overflow_reward, container_reward.sum(axis=1))
    individual_reward = np.where(overflowed, params.overflow_reward, container_reward)

    outcome = StepOutcome(
        requested=requests,
        granted=granted,
        denied=denied,
        pu_index=pu_index,
        emptied_volume=emptied_volume,
        container_reward=container_reward,
        overflowed=overflowed,
        individual_reward=individual_reward,
        plant_reward=plant_reward,
        free_pus_before=free_count,
        terminated=terminated,
        truncated=truncated,
    )
    return PlantState(v_next, p_next, step_count), outcome
