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

from functools import lru_cache
from types import SimpleNamespace
from typing import NamedTuple

import numpy as np

from containergym_marl.core.params import PlantParams

ARBITRATION_RULES = ("fullest", "random", "index", "best_reward")


class PlantState(NamedTuple):
    """State of B simulations: the paper's s_t = (v, p) plus the step counter.

    Immutable fields (a named tuple: cheaper to build than a frozen dataclass, which matters when
    a single simulation steps in a few microseconds); the arrays are never modified in place.
    """

    volumes: np.ndarray  # (B, n) volume units
    pu_timers_s: np.ndarray  # (B, m) seconds until each PU is free
    step_count: np.ndarray  # (B,) steps taken in the current episode

    @property
    def batch_size(self) -> int:
        return self.volumes.shape[0]

    def select(self, sims: np.ndarray) -> "PlantState":
        return PlantState(self.volumes[sims], self.pu_timers_s[sims], self.step_count[sims])


class StepOutcome(NamedTuple):
    """What happened in one step of B simulations (arrays shaped (B, n) or (B,)); immutable."""

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


#: exp(x) is exactly 0.0 below this; numpy's exp takes a very slow path on such arguments, which
#: narrow reward peaks produce for most volumes, so :func:`_exp_in_place` keeps them out of it.
_EXP_ZERO_BELOW = -746.0


def _exp_in_place(x: np.ndarray) -> np.ndarray:
    """``np.exp(x)`` into ``x``, exactly: arguments below -746 (whose exp is 0.0) are set to -0.0
    before (exp = 1) and their results multiplied by 0 after."""
    keep = x >= _EXP_ZERO_BELOW
    np.multiply(x, keep, out=x)
    np.exp(x, out=x)
    np.multiply(x, keep, out=x)
    return x


#: Up to this many terms, ``np.sum`` over a contiguous axis adds sequentially (numpy switches to
#: pairwise summation at 8 terms), so an explicit left-to-right sum of the columns gives the same
#: bits while avoiding numpy's slow per-row reduction over a short axis.
_SEQUENTIAL_SUM_MAX_TERMS = 7


def sum_last_axis(x: np.ndarray) -> np.ndarray:
    """``np.sum(x, axis=-1)`` with identical results, faster for a short last axis."""
    k = x.shape[-1]
    if k == 0 or k > _SEQUENTIAL_SUM_MAX_TERMS or x.size <= 64 * k:  # small: one call is cheaper
        return np.sum(x, axis=-1)
    out = x[..., 0].copy()
    for j in range(1, k):
        out += x[..., j]
    return out


#: From this batch size on, per-container constants are used as (B, n) tiles and row reductions
#: are done column by column: numpy's inner loop over a broadcast (n,) operand or a short row is
#: only n long, which costs several times a flat pass over B·n entries.
_LARGE_BATCH = 64


@lru_cache(maxsize=32)  # params are immutable and hashed by identity
def _constants(params: PlantParams, rows: int) -> SimpleNamespace:
    names = ("fill_mean_per_step", "fill_std_per_step", "max_volume", "target_volume")
    arrays = {k: getattr(params, k) for k in names}
    # reward peak k of every container: peak, 2w², h − r_pen, as (n,) columns
    for k in range(params.reward_peaks.shape[1]):
        arrays[f"peak{k}"] = np.ascontiguousarray(params.reward_peaks[:, k])
        arrays[f"two_w_sq{k}"] = np.ascontiguousarray(params.reward_two_width_sq[:, k])
        arrays[f"coef{k}"] = np.ascontiguousarray(params.reward_coef[:, k])
    if rows:
        arrays = {k: np.tile(a, (rows, 1)) for k, a in arrays.items()}
    for a in arrays.values():
        a.setflags(write=False)
    return SimpleNamespace(**arrays)


def per_entry(params: PlantParams, bsz: int) -> SimpleNamespace:
    """Per-container constants shaped for a batch of ``bsz``: (B, n) read-only tiles for large
    batches (cut from a cached tile of the next power of two), the (n,) arrays otherwise.
    Elementwise results are the same either way."""
    if bsz < _LARGE_BATCH:
        return _constants(params, 0)
    cap = 1 << (bsz - 1).bit_length()
    tiles = _constants(params, cap)
    if cap == bsz:
        return tiles
    return SimpleNamespace(**{k: a[:bsz] for k, a in vars(tiles).items()})


def row_any(mask: np.ndarray) -> np.ndarray:
    """``mask.any(axis=1)`` of a 2-D boolean array (column by column for large batches)."""
    if mask.shape[0] < _LARGE_BATCH or mask.shape[1] > 64:
        return mask.any(axis=1)
    out = mask[:, 0].copy()
    for j in range(1, mask.shape[1]):
        out |= mask[:, j]
    return out


def row_count(mask: np.ndarray) -> np.ndarray:
    """``mask.sum(axis=1)`` (int64) of a 2-D boolean array; integer sums are exact in any order,
    so large batches add columns (numpy's row-wise reduction over a short axis is slow)."""
    if mask.shape[0] < _LARGE_BATCH or mask.shape[1] > 64:
        return mask.sum(axis=1)
    out = mask[:, 0].astype(np.int64)
    for j in range(1, mask.shape[1]):
        out += mask[:, j]
    return out


def emptying_reward(volumes: np.ndarray, params: PlantParams, containers=None) -> np.ndarray:
    """Reward of emptying each container at ``volumes`` (..., n), given a free PU (paper eq. 5).

    ``r_pen + Σ_k (h_k − r_pen)·exp(−(v − v*_k)² / (2 w_k²))``, and ``r_pen`` for an empty container.
    With ``containers`` (integer indices), ``volumes`` is 1-D and entry j belongs to container
    ``containers[j]``; the values are exactly those of the full form at those entries.
    """
    v = np.asarray(volumes, dtype=np.float64)
    n_peaks = params.reward_peaks.shape[1]
    if n_peaks <= _SEQUENTIAL_SUM_MAX_TERMS and (containers is not None or v.ndim == 2):
        # Peak by peak on (B, n) or (k,) arrays: the same operations and the same (sequential)
        # order of the sum over peaks as the (..., n, K) form below, without its inner loop of K.
        if containers is None:
            cols = per_entry(params, v.shape[0])
            column = lambda name, k: getattr(cols, f"{name}{k}")  # noqa: E731
        else:
            cols = per_entry(params, 1)
            column = lambda name, k: np.take(getattr(cols, f"{name}{k}"), containers)  # noqa: E731
        reward = None
        for k in range(n_peaks):
            term = np.subtract(v, column("peak", k))
            np.multiply(term, term, out=term)
            np.negative(term, out=term)
            np.divide(term, column("two_w_sq", k), out=term)
            _exp_in_place(term)
            np.multiply(column("coef", k), term, out=term)
            if reward is None:
                reward = term
            else:
                reward += term
    else:
        if containers is None:  # (..., n) volumes
            peaks, two_w_sq, coef = params.reward_peaks, params.reward_two_width_sq, params.reward_coef
        else:
            peaks = np.take(params.reward_peaks, containers, axis=0)
            two_w_sq = np.take(params.reward_two_width_sq, containers, axis=0)
            coef = np.take(params.reward_coef, containers, axis=0)
        # r_pen + sum(coef * exp(-(diff * diff) / 2w²)), computed in place (same operations, same bits)
        diff = np.subtract(v[..., None], peaks)
        np.multiply(diff, diff, out=diff)
        np.negative(diff, out=diff)
        np.divide(diff, two_w_sq, out=diff)
        _exp_in_place(diff)
        np.multiply(coef, diff, out=diff)
        reward = sum_last_axis(diff)
    reward = np.add(params.penalty_reward, reward, out=reward)
    empty = v == 0.0
    if empty.any():
        reward[empty] = params.penalty_reward
    return reward


def pu_busy_time_s(volumes: np.ndarray, params: PlantParams, containers=slice(None)) -> np.ndarray:
    """g_i(v) = β_i + λ_i·⌊v / b_i⌋: seconds a PU is busy after emptying (paper eq. 2).

    ``volumes`` is (…, n), or matches ``containers`` (indices of the containers it belongs to).
    """
    if isinstance(containers, slice):
        beta, lam, size = (params.pu_offset_s[containers], params.pu_time_per_product_s[containers],
                           params.product_size[containers])
    else:
        beta, lam, size = (np.take(params.pu_offset_s, containers), np.take(params.pu_time_per_product_s, containers),
                           np.take(params.product_size, containers))
    return beta + lam * np.floor(volumes / size)


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
    rule: str, volumes: np.ndarray, uniforms: np.ndarray | None, params: PlantParams
) -> np.ndarray:
    """Arbitration priority of each container, (B, n); larger wins, ties go to the lower index."""
    if rule == "fullest":
        return volumes / params.max_volume
    if rule == "random":
        if uniforms is None:
            raise ValueError("the 'random' arbitration needs the step's uniforms")
        return uniforms
    if rule == "index":
        return np.broadcast_to(-np.arange(params.n_containers, dtype=np.float64), volumes.shape)
    if rule == "best_reward":
        return emptying_reward(volumes, params)
    raise ValueError(f"arbitration: unknown rule {rule!r}; choose one of {ARBITRATION_RULES}")


def arbitrate(requests: np.ndarray, free_count: np.ndarray, keys: np.ndarray,
              request_count: np.ndarray | None = None) -> np.ndarray:
    """Grant the ``free_count[b]`` highest-priority requests of each simulation, (B, n) bool.

    Requests are taken in decreasing key order, ties to the lower index (the order of a stable
    sort of ``-keys``); keys must be finite. Done as ``max(free_count)`` rounds of a row-wise
    argmax (at most m rounds), which is much cheaper than sorting every row. ``request_count``
    (requests per row) may be passed if already known.
    """
    requests = np.asarray(requests, dtype=bool)
    b, n = requests.shape
    granted = np.zeros((b, n), dtype=bool)
    if request_count is None:
        request_count = row_count(requests)
    free_count = np.minimum(np.asarray(free_count), request_count)
    rounds = int(free_count.max()) if b else 0
    if rounds <= 0:
        return granted
    rows = np.arange(b)
    masked = np.where(requests, keys, -np.inf)
    for k in range(rounds):
        best = masked.argmax(axis=1)
        take = free_count > k  # such a row still has an ungranted request (free_count <= requests)
        granted[rows[take], best[take]] = True
        masked[rows, best] = -np.inf
    return granted


def _k_th_free_pu(free: np.ndarray, sims: np.ndarray, position: np.ndarray) -> np.ndarray:
    """Index of the ``position[j]``-th (0-based) free PU of simulation ``sims[j]``."""
    m = free.shape[1]
    seen = np.zeros(sims.size, dtype=np.int64)  # free PUs before PU j
    pu = np.zeros(sims.size, dtype=np.int64)
    for j in range(m):  # m is small; a loop over PUs, not over simulations
        pu += seen <= position  # PU j comes at or before the wanted one
        seen += free[sims, j]
    return pu - 1


def check_step_inputs(bsz: int, n: int, requests: np.ndarray, normals, uniforms, arbitration: str) -> None:
    """The input checks of :func:`step` (and of the compiled backend's): a clear error naming the
    offending input. Random rows are one per simulation, never broadcast."""
    if requests.shape != (bsz, n):
        raise ValueError(f"requests: expected shape {(bsz, n)}, got {requests.shape}")
    if arbitration not in ARBITRATION_RULES:
        raise ValueError(f"arbitration: unknown rule {arbitration!r}; choose one of {ARBITRATION_RULES}")
    if uniforms is None:
        if arbitration == "random":  # needed whenever requests compete
            raise ValueError("the 'random' arbitration needs the step's uniforms")
    elif np.shape(uniforms) != (bsz, n):
        raise ValueError(f"uniforms: expected shape {(bsz, n)}, got {np.shape(uniforms)}")
    if np.shape(normals) != (bsz, n):
        raise ValueError(f"normals: expected shape {(bsz, n)}, got {np.shape(normals)}")


def step(
    state: PlantState,
    requests: np.ndarray,
    params: PlantParams,
    normals: np.ndarray,
    uniforms: np.ndarray | None,
    arbitration: str = "fullest",
) -> tuple[PlantState, StepOutcome]:
    """Advance B simulations by one step of δ seconds. Pure: ``state`` is not modified.

    Args:
        state: the current state (B simulations).
        requests: (B, n) bool, which containers ask to be emptied.
        params: the plant.
        normals, uniforms: (B, n) one random row per simulation (see :mod:`.rng`); ``uniforms``
            is only read by the ``"random"`` arbitration and may be None otherwise.
        arbitration: rule ranking competing requests, one of :data:`ARBITRATION_RULES`.

    The work is proportional to the number of requests, not to B·n, wherever that is possible:
    the fill is dense, the decisions are computed only at the requested entries.
    """
    v, p = state.volumes, state.pu_timers_s
    bsz, n = v.shape
    requests = np.asarray(requests, dtype=bool)
    check_step_inputs(bsz, n, requests, normals, uniforms, arbitration)

    const = per_entry(params, bsz)
    free = p == 0.0
    free_count = row_count(free)
    # v(t+1) before emptying: max(0, (v + μδ) + σ√δ·ε), in place on fresh arrays
    v_next = np.add(v, const.fill_mean_per_step)
    v_next += np.multiply(const.fill_std_per_step, normals)
    np.maximum(0.0, v_next, out=v_next)
    p_next = np.subtract(p, params.timestep_s)
    np.maximum(0.0, p_next, out=p_next)

    container_reward = np.zeros((bsz, n))
    emptied_volume = np.zeros((bsz, n))
    pu_index = np.empty((bsz, n), dtype=np.int64)
    pu_index.fill(-1)
    flat_req = np.flatnonzero(requests)
    if flat_req.size:
        req_sim = flat_req // n
        req_count = np.bincount(req_sim, minlength=bsz)
        # Ranking is only needed where requests outnumber free PUs; elsewhere all are granted.
        contested = req_count > free_count
        if contested.any():
            c = np.flatnonzero(contested)
            vc = np.take(v, c, axis=0)
            if arbitration == "fullest" and const.max_volume.ndim == 2:
                keys = vc / const.max_volume[:c.size]  # the same values as priority_keys
            else:
                keys = priority_keys(arbitration, vc, None if uniforms is None else np.take(uniforms, c, axis=0),
                                     params)
            granted = requests.copy()
            granted[c] = arbitrate(np.take(requests, c, axis=0), np.take(free_count, c), keys,
                                   np.take(req_count, c))
            req_granted = granted.reshape(-1)[flat_req]
            flat_g = flat_req[req_granted]
            flat_denied = flat_req[~req_granted]
        else:
            granted = requests
            flat_g, flat_denied = flat_req, flat_req[:0]
        if flat_g.size:
            sim_g = flat_g // n
            cont_g = flat_g - sim_g * n
            vol_g = np.take(v.reshape(-1), flat_g) if v.flags.c_contiguous else v[sim_g, cont_g]
            # Rewards of this step's decisions, from the volumes before this step's inflow.
            container_reward.reshape(-1)[flat_g] = emptying_reward(vol_g, params, cont_g)
            emptied_volume.reshape(-1)[flat_g] = vol_g
            v_next[sim_g, cont_g] = 0.0
            # The k-th granted container (index order) takes the k-th free PU (index order).
            # flat_g is sorted, so a simulation's grants are consecutive: k = j - (first j of it).
            if flat_g.size == 1 or free.shape[1] == 1:  # one grant: the first free PU
                pus = np.argmax(np.take(free, sim_g, axis=0), axis=1)
            else:
                first = np.ones(flat_g.size, dtype=bool)
                first[1:] = sim_g[1:] != sim_g[:-1]
                j = np.arange(flat_g.size)
                position = j - np.maximum.accumulate(np.where(first, j, 0))
                pus = _k_th_free_pu(free, sim_g, position)
            pu_index.reshape(-1)[flat_g] = pus
            p_next[sim_g, pus] = pu_busy_time_s(vol_g, params, cont_g)
        if flat_denied.size:
            container_reward.reshape(-1)[flat_denied] = params.penalty_reward
        denied = requests & ~granted if flat_denied.size else np.zeros((bsz, n), dtype=bool)
        # The plant reward is the row sum; a row with one request sums to that entry exactly.
        plant_reward = np.zeros(bsz)
        single = req_count[req_sim] == 1
        plant_reward[req_sim[single]] = container_reward.reshape(-1)[flat_req[single]]
        multi = np.flatnonzero(req_count > 1) if flat_req.size > 1 else flat_req[:0]
        if multi.size * 4 > bsz:  # most rows: sum them all (a lone entry sums to itself)
            plant_reward = container_reward.sum(axis=1)
        elif multi.size:
            plant_reward[multi] = container_reward[multi].sum(axis=1)
    else:
        granted = denied = requests
        plant_reward = np.zeros(bsz)

    step_count = state.step_count + 1
    overflowed = v_next >= const.max_volume
    individual_reward = container_reward.copy()
    if overflowed.any():
        terminated = row_any(overflowed)
        individual_reward[overflowed] = params.overflow_reward
        plant_reward[terminated] = params.overflow_reward
    else:
        terminated = np.zeros(bsz, dtype=bool)
    truncated = step_count >= params.episode_length_steps
    truncated &= ~terminated

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
