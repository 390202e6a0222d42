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

Observation variants (``observation=`` of the container-agent views, :data:`OBSERVATIONS`): what an
agent sees besides the table above, for the ablation of what the imitation of the planner lacks
(``studies/coordination_ablation.py``), and one of a size that does not depend on the plant, for
transfer between plants. Every variant but ``"portable"`` starts with the F₀ = 12 + m + n entries
above, unchanged (``"local"``, the default, is exactly them); execution stays decentralised: an
agent acts on its own row, which holds only what it was allowed to receive. Built in one place,
:class:`AgentObservations`, for the PettingZoo views, the vectorised env and the batched evaluator.

* ``"local"``: the table above, nothing more (F = F₀).
* ``"global"``: plus the normalised global state, the same for every agent (an *oracle*: the upper
  bound of what imitation can reach with this network; F = F₀ + n + m). The timers repeat
  entries 12+j, so that the block is the whole global state ``[v / v_max, p / max PU time]``:

  ======  =========================  =============================================  ==========
  idx     name                       meaning                                        bounds
  ======  =========================  =============================================  ==========
  F₀+k    global_volume_frac[k]      container k's volume v_k / v_max,k, k < n      [0, 2]
  F₀+n+j  global_pu_timer_frac[j]    PU j's timer / largest possible PU time, j < m [0, 1]
  ======  =========================  =============================================  ==========

* ``"history4"``: plus the agent's observations of the last 3 steps (4 stacked frames, newest
  first; F = 4 F₀). Before the episode's start the earlier frames are 0 (inside every entry's
  bounds), so the first observation of an episode is ``[o_0, 0, 0, 0]``:

  ======  =========================  =============================================  ==========
  idx     name                       meaning                                        bounds
  ======  =========================  =============================================  ==========
  s·F₀+e  <name of entry e>@t-s      entry e of the agent's observation s steps     entry e's
                                     ago, s = 1, 2, 3; 0 before the episode         bounds
  ======  =========================  =============================================  ==========

* ``"broadcast"``: plus one public signal the plant broadcasts after every step, the same for
  every agent: which containers requested a PU in the last step and which were granted one
  (emptied); both 0 at the start of an episode (F = F₀ + 2n). Entry 9 is its share of requests:

  ======  =========================  =============================================  ==========
  idx     name                       meaning                                        bounds
  ======  =========================  =============================================  ==========
  F₀+k    requested_last_step[k]     1 if container k requested in the last step    [0, 1]
  F₀+n+k  granted_last_step[k]       1 if container k was emptied in the last step  [0, 1]
  ======  =========================  =============================================  ==========

* ``"portable"``: the same size on every plant, for one network that acts on plants of any n and m
  (a policy trained on one plant, evaluated on another): entries 0–11 of the table above, then the
  PU timers summarised instead of listed, and no one-hot (the container is identified by its physics,
  entries 1 and 3–6). It does *not* start with the F₀ entries; F = 14:

  ======  =========================  =============================================  ==========
  idx     name                       meaning                                        bounds
  ======  =========================  =============================================  ==========
  0–11    (entries 0–11 above)       as above                                       as above
  12      next_pu_free_frac          smallest PU timer / largest possible PU time   [0, 1]
                                     (0 while a PU is free)
  13      mean_pu_timer_frac         mean PU timer / largest possible PU time       [0, 1]
  ======  =========================  =============================================  ==========
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


#: The container agents' observation variants (the module docstring); the first is the default.
OBSERVATIONS = ("local", "global", "history4", "broadcast", "portable")
#: The ``"portable"`` observation's summary of the PU timers (after the scalar entries).
PORTABLE_PU_FEATURES = ("next_pu_free_frac", "mean_pu_timer_frac")
DEFAULT_OBSERVATION = OBSERVATIONS[0]
#: Frames of the ``"history4"`` observation: the current one and the 3 before it.
HISTORY_FRAMES = 4


def check_observation(value, where: str = "observation") -> str:
    """``value`` if it names an observation variant; a ValueError naming ``where`` and the choices."""
    if not isinstance(value, str) or value not in OBSERVATIONS:
        raise ValueError(f"{where}: unknown observation {value!r}; choose one of {OBSERVATIONS}")
    return value


def agent_observation_size(n_containers: int, n_pus: int, observation: str = DEFAULT_OBSERVATION) -> int:
    """F, the entries of a container agent's observation in variant ``observation``."""
    if check_observation(observation) == "portable":
        return N_SCALAR_FEATURES + len(PORTABLE_PU_FEATURES)
    local = N_SCALAR_FEATURES + n_pus + n_containers
    extra = {"local": 0, "global": n_containers + n_pus, "history4": (HISTORY_FRAMES - 1) * local,
             "broadcast": 2 * n_containers}
    return local + extra[observation]


def agent_feature_names(params: PlantParams, observation: str = DEFAULT_OBSERVATION) -> list[str]:
    """The names of a container agent's observation entries in variant ``observation``, in order."""
    n, m = params.n_containers, params.n_pus
    local = (
        list(SCALAR_FEATURES)
        + [f"pu_timer_frac[{j}]" for j in range(m)]
        + [f"container_one_hot[{i}]" for i in range(n)]
    )
    observation = check_observation(observation)
    if observation == "portable":
        return list(SCALAR_FEATURES) + list(PORTABLE_PU_FEATURES)
    if observation == "global":
        return local + [f"global_volume_frac[{k}]" for k in range(n)] + [f"global_pu_timer_frac[{j}]" for j in range(m)]
    if observation == "history4":
        return local + [f"{name}@t-{s}" for s in range(1, HISTORY_FRAMES) for name in local]
    if observation == "broadcast":
        return local + [f"requested_last_step[{k}]" for k in range(n)] + [f"granted_last_step[{k}]" for k in range(n)]
    return local


def global_state_bounds(params: PlantParams) -> tuple[np.ndarray, np.ndarray]:
    """float32 bounds of the global state ``[v, p]``: volumes in [0, 2·v_max], timers in
    [0, largest PU time]."""
    low = np.zeros(params.n_containers + params.n_pus, dtype=np.float32)
    high = np.concatenate(
        [VOLUME_BOUND_FACTOR * params.max_volume, np.full(params.n_pus, params.max_pu_time_s)]
    ).astype(np.float32)
    return low, high


def agent_observation_bounds(params: PlantParams, observation: str = DEFAULT_OBSERVATION
                             ) -> tuple[np.ndarray, np.ndarray]:
    """float32 bounds of a container agent's observation in variant ``observation`` (the tables in
    the module docstring)."""
    n, m = params.n_containers, params.n_pus
    low = np.zeros(len(SCALAR_FEATURES) + m + n, dtype=np.float32)
    high = np.ones_like(low)
    high[0] = VOLUME_BOUND_FACTOR
    low[2] = -VOLUME_BOUND_FACTOR
    low[7] = params.penalty_reward
    observation = check_observation(observation)
    if observation == "portable":
        summary = len(PORTABLE_PU_FEATURES)
        return (np.concatenate([low[:N_SCALAR_FEATURES], np.zeros(summary, np.float32)]),
                np.concatenate([high[:N_SCALAR_FEATURES], np.ones(summary, np.float32)]))
    if observation == "global":
        extra_high = np.ones(n + m, dtype=np.float32)
        extra_high[:n] = VOLUME_BOUND_FACTOR
        return np.concatenate([low, np.zeros(n + m, np.float32)]), np.concatenate([high, extra_high])
    if observation == "history4":
        return np.tile(low, HISTORY_FRAMES), np.tile(high, HISTORY_FRAMES)
    if observation == "broadcast":
        return np.concatenate([low, np.zeros(2 * n, np.float32)]), np.concatenate([high, np.ones(2 * n, np.float32)])
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
def _agent_observations_into(volumes, timers, previous_requests, portable, out, per_container, reward_table, scalars):
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
            if portable:  # the timers summarised: the smallest and the mean of the clipped shares
                smallest, total = np.float32(1.0), np.float32(0.0)
                for j in range(m):
                    share = _clipped(p[j] / params.max_pu_time_s, 0.0, 1.0)
                    smallest = min(smallest, share)
                    total += share
                row[ns] = smallest
                row[ns + 1] = _clipped(total / m, 0.0, 1.0)
                continue
            for j in range(m):
                row[ns + j] = _clipped(p[j] / params.max_pu_time_s, 0.0, 1.0)
            for k in range(n):
                row[ns + m + k] = 1.0 if k == i else 0.0


def agent_observations(
    state: PlantState, params: PlantParams, previous_requests: np.ndarray, portable: bool = False
) -> np.ndarray:
    """(B, n, F) float32 observations of every container agent; see the module docstring (with
    ``portable``: the ``"portable"`` variant's 14 entries instead).

    Every entry is computed in float64, cast to float32 and clipped into
    :func:`agent_observation_bounds`.
    """
    v = state.volumes
    bsz, n = v.shape
    previous_requests = np.ascontiguousarray(previous_requests, dtype=bool)
    if previous_requests.shape != (bsz, n):
        raise ValueError(f"previous_requests: expected shape {(bsz, n)}, got {previous_requests.shape}")
    width = N_SCALAR_FEATURES + (len(PORTABLE_PU_FEATURES) if portable else params.n_pus + n)
    out = np.empty((bsz, n, width), dtype=np.float32)
    _agent_observations_into(v, state.pu_timers_s, previous_requests, bool(portable), out, *params.kernel_arrays())
    return out


class AgentObservations:
    """The container agents' observations of B simulations in one variant (the module docstring),
    and what the variant remembers between steps (``"history4"``: each agent's last 3 frames).

    Call it once per step with the simulator's state, last requests and last grants: it returns the
    (B, n, F) float32 observations and remembers them. :meth:`reset` forgets simulations whose
    episode starts anew (call it after the simulator's reset, before observing them);
    :meth:`final` gives the last observation of ending episodes without remembering it (an
    autoreset's terminal observation). ``"local"`` is :func:`agent_observations` itself.
    """

    def __init__(self, params: PlantParams, observation: str = DEFAULT_OBSERVATION, num_sims: int = 1):
        self.params = params
        self.observation = check_observation(observation)
        n, m = params.n_containers, params.n_pus
        self.frame_size = N_SCALAR_FEATURES + m + n
        self.size = agent_observation_size(n, m, self.observation)
        self.low, self.high = agent_observation_bounds(params, self.observation)
        # the earlier frames, newest first: (B, n, HISTORY_FRAMES - 1, F0), zeros before an episode starts
        self._earlier = (np.zeros((int(num_sims), n, HISTORY_FRAMES - 1, self.frame_size), np.float32)
                         if self.observation == "history4" else None)
        self._pu_time_s = float(params.max_pu_time_s) or 1.0  # a plant whose PUs take no time: timers are 0

    def feature_names(self) -> list[str]:
        return agent_feature_names(self.params, self.observation)

    def reset(self, sims=None) -> None:
        """Forget the earlier frames of ``sims`` (indices; default: all): their episodes start now."""
        if self._earlier is not None:
            self._earlier[slice(None) if sims is None else sims] = 0.0

    def __call__(self, state: PlantState, previous_requests: np.ndarray, previous_granted: np.ndarray) -> np.ndarray:
        """(B, n, F) observations of every simulation now; remembered as the latest frames."""
        obs = self._build(state, previous_requests, previous_granted, self._earlier)
        if self._earlier is not None:
            bsz, n = obs.shape[:2]
            self._earlier = obs[:, :, : (HISTORY_FRAMES - 1) * self.frame_size].reshape(
                bsz, n, HISTORY_FRAMES - 1, self.frame_size).copy()
        return obs

    def final(self, state: PlantState, previous_requests: np.ndarray, previous_granted: np.ndarray,
              sims) -> np.ndarray:
        """(len(sims), n, F) observations of simulations ``sims`` in ``state`` (their rows only, e.g.
        a finished episode's last state), not remembered."""
        earlier = None if self._earlier is None else self._earlier[sims]
        return self._build(state, previous_requests, previous_granted, earlier)

    def _build(self, state, previous_requests, previous_granted, earlier) -> np.ndarray:
        frame = agent_observations(state, self.params, previous_requests, portable=self.observation == "portable")
        if self.observation in ("local", "portable"):
            return frame
        bsz, n = frame.shape[:2]
        if self.observation == "history4":
            if earlier.shape[0] != bsz:
                raise ValueError(f"state: {bsz} simulations, but {earlier.shape[0]} remembered")
            extra = earlier.reshape(bsz, n, -1)
        else:
            if self.observation == "global":
                block = np.concatenate([np.clip(state.volumes / self.params.max_volume, 0.0, VOLUME_BOUND_FACTOR),
                                        np.clip(state.pu_timers_s / self._pu_time_s, 0.0, 1.0)], axis=1)
            else:  # broadcast
                granted = np.asarray(previous_granted, dtype=bool)
                if granted.shape != (bsz, n):
                    raise ValueError(f"previous_granted: expected shape {(bsz, n)}, got {granted.shape}")
                block = np.concatenate([np.asarray(previous_requests, dtype=bool), granted], axis=1)
            # one public block per simulation, the same in every agent's row
            extra = np.broadcast_to(block.astype(np.float32)[:, None, :], (bsz, n, block.shape[1]))
        return np.concatenate([frame, extra], axis=2)


def check_same_observation(trained: str, given: str, who: str) -> None:
    """Refuse to let a model trained on observation variant ``trained`` act on variant ``given`` (a
    ValueError naming ``who`` and both): two variants can have the same size (``"global"`` and
    ``"broadcast"`` where m = n), so the names are compared, not the shapes."""
    if trained != given:
        raise ValueError(f"{who} was trained on the {trained!r} observation but is given the {given!r} "
                         f"observation; evaluate it on the observation it was trained on ({trained!r})")
