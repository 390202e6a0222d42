"""The edge of the views: what every environment view checks and returns around the shared core,
written once for the PettingZoo, Gymnasium, vector and TorchRL views.

* arguments: :func:`discrete_action` (one action), :func:`check_seed`, :func:`check_batch_size`
  (B simulations), :func:`check_reward_mode`;
* the container agents' rewards: :data:`REWARD_MODES` and :func:`agent_rewards`;
* the infos: the container agents' (:data:`AGENT_INFO_NEUTRAL`, :func:`agent_step_infos`,
  :func:`agent_info_arrays`) and the centralised view's (:class:`CentralisedInfo`, one dict per
  simulation or one array per key for B simulations);
* the normalised global state: :class:`NormalisedState`.

Rendering, shared by both views, is in :mod:`containergym_marl.render`.
"""

from __future__ import annotations

import numbers
from types import MappingProxyType
from typing import Any, Mapping, Sequence

import numpy as np

from containergym_marl.config import MAX_SIMS
from containergym_marl.core.dynamics import StepOutcome
from containergym_marl.core.observations import VOLUME_BOUND_FACTOR


# ---- actions ----------------------------------------------------------------------------------------
def discrete_action(action, n_actions: int, who: str) -> int:
    """``action`` as a Python int in ``[0, n_actions)``; a clear error for anything else.

    Accepts Python and numpy integers and integer arrays holding one value (shape ``()`` as SB3's
    ``predict`` returns for one observation, or ``(1,)``). Floats and bools are rejected rather
    than silently truncated or cast.
    """
    if type(action) is int and 0 <= action < n_actions:  # the common case, checked cheaply
        return action
    value = action
    if isinstance(value, np.ndarray):
        if value.shape not in ((), (1,)):
            raise ValueError(f"{who}: expected a single integer action, got an array of shape {value.shape}")
        value = value.reshape(()).item() if np.issubdtype(value.dtype, np.integer) else value
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{who}: expected an integer action in [0, {n_actions - 1}], got {action!r} "
                        f"({type(action).__name__})")
    value = int(value)
    if not 0 <= value < n_actions:
        raise ValueError(f"{who}: action {value} out of range [0, {n_actions - 1}]")
    return value


# ---- seeds and batch sizes --------------------------------------------------------------------------
def is_integer(value) -> bool:
    """A Python or numpy integer, not a bool."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def check_seed(value, name: str = "seed") -> int | None:
    """None or a non-negative integer (Python or numpy) as a Python int, for every view alike;
    anything else (``2.7``, ``"5"``, True, -1) is refused with a ValueError rather than cast."""
    if value is None:
        return None
    if not is_integer(value) or value < 0:
        raise ValueError(f"{name}: expected None or a non-negative integer, got {value!r} "
                         f"({type(value).__name__})")
    return int(value)


def check_batch_size(value, name: str) -> int:
    """A number of simulations B (``num_envs``, ``num_sims``) as a Python int: an integer in
    [1, ``MAX_SIMS``]; floats (``3.0``), bools and strings are refused with a ValueError naming
    ``name`` rather than cast."""
    if not is_integer(value) or not 1 <= value <= MAX_SIMS:
        raise ValueError(f"{name}: expected an integer in [1, {MAX_SIMS}], got {value!r}")
    return int(value)


# ---- the container agents' rewards ------------------------------------------------------------------
#: The container agents' reward modes: ``"individual"``, each agent its own container's reward
#: (emptying reward or r_pen, r_min if its container overflowed); ``"team"``, every agent the
#: plant reward (the centralised view's reward).
REWARD_MODES: tuple[str, ...] = ("individual", "team")


def check_reward_mode(value) -> str:
    """``value`` if it is one of :data:`REWARD_MODES`; a ValueError naming ``reward_mode`` otherwise."""
    if not isinstance(value, str) or value not in REWARD_MODES:
        raise ValueError(f"reward_mode: unknown mode {value!r}; choose one of {REWARD_MODES}")
    return value


def agent_rewards(out: StepOutcome, reward_mode: str, dtype=np.float64) -> np.ndarray:
    """The (B, n) rewards of the container agents of B simulations in ``reward_mode``, a new array
    of ``dtype``: the plant reward of simulation b for each of its agents ("team"), or each
    container's own reward ("individual")."""
    if reward_mode == "team":
        return np.broadcast_to(out.plant_reward[:, None], out.individual_reward.shape).astype(dtype)
    return out.individual_reward.astype(dtype)


# ---- the container agents' infos --------------------------------------------------------------------
# Every key of a container agent's info, in order: its value at reset and when nothing happened to
# the agent (its type is the key's type), and the StepOutcome field (B, n) it reads, if per container.
_AGENT_INFO = (
    ("requested", False, "requested"),
    ("granted", False, "granted"),
    ("denied", False, "denied"),
    ("pu_index", -1, "pu_index"),
    ("emptied_volume", 0.0, "emptied_volume"),
    ("emptying_reward", 0.0, "container_reward"),  # the agent's reward before any overflow replacement
    ("overflowed", False, "overflowed"),
    ("plant_reward", 0.0, None),  # the step's plant reward, the "team" reward
    ("free_pus", 0, None),  # free PUs before the step (at reset: now)
    ("step", 0, None),  # steps taken in the episode
)
#: Every key of a container agent's info, in order, with its value at reset and when nothing
#: happened to the agent (``free_pus`` and ``step`` are always set).
AGENT_INFO_NEUTRAL: Mapping[str, Any] = MappingProxyType({key: neutral for key, neutral, _ in _AGENT_INFO})
_AGENT_INFO_FIELDS = MappingProxyType({key: field for key, _, field in _AGENT_INFO if field is not None})
# the key order of agent_step_infos' values: the per-container ones, then those shared by the plant
_AGENT_STEP_KEYS = (*_AGENT_INFO_FIELDS, "plant_reward", "free_pus", "step")
# the keys of agent_info_arrays: those a step outcome holds for every agent
_AGENT_ARRAY_KEYS = (*_AGENT_INFO_FIELDS, "plant_reward")


def agent_reset_info(free_pus: int) -> dict[str, Any]:
    """One container agent's info at reset (a new dict): every key at its neutral value."""
    info = AGENT_INFO_NEUTRAL.copy()  # a plain dict (dict(proxy) would be ten times slower)
    info["free_pus"] = int(free_pus)
    return info


def agent_step_infos(out: StepOutcome, sim: int, step_count: int) -> list[dict[str, Any]]:
    """The infos of the n container agents of simulation ``sim`` after a step, as Python numbers
    (agent i's at index i); ``step_count`` is the steps that simulation has taken."""
    # each per-container row as Python numbers once (reading n entries one by one costs n times more)
    columns = [getattr(out, field)[sim].tolist() for field in _AGENT_INFO_FIELDS.values()]
    shared = (float(out.plant_reward[sim]), int(out.free_pus_before[sim]), int(step_count))
    return [dict(zip(_AGENT_STEP_KEYS, (*row, *shared))) for row in zip(*columns)]


def agent_info_arrays(out: StepOutcome | None, keys: Sequence[str], shape: tuple[int, int]) -> dict[str, np.ndarray]:
    """The container agents' infos of B simulations as one new ``shape`` (B, n) array per key of
    ``keys`` (bool, float32 or int64 after the key's neutral value; what TorchRL stacks): after the
    step ``out``, or at reset (``out`` None: the neutral values). Only the keys that a step outcome
    holds per agent are taken (not ``free_pus``, ``step``)."""
    arrays = {}
    for key in keys:
        if key not in _AGENT_ARRAY_KEYS:
            raise ValueError(f"keys: {key!r} is not a per-agent info key of a step; choose from {_AGENT_ARRAY_KEYS}")
        neutral = AGENT_INFO_NEUTRAL[key]
        dtype = bool if isinstance(neutral, bool) else np.float32 if isinstance(neutral, float) else np.int64
        if out is None:
            arrays[key] = np.full(shape, neutral, dtype=dtype)
        elif key == "plant_reward":
            arrays[key] = np.broadcast_to(out.plant_reward[:, None], shape).astype(dtype)
        else:
            arrays[key] = getattr(out, _AGENT_INFO_FIELDS[key]).astype(dtype)
    return arrays


# ---- the centralised view's info --------------------------------------------------------------------
#: Every key of the centralised view's info, in order, with its value at reset and in a step that
#: emptied nothing (its type is the key's type; ``free_pus``, free PUs before the step, at reset
#: now, and ``step``, steps taken, are always set).
CENTRALISED_INFO_NEUTRAL: Mapping[str, Any] = MappingProxyType({
    "step": 0,
    "emptied_container": "",
    "emptied_index": -1,
    "emptied_volume": 0.0,
    "emptying_reward": 0.0,
    "pu_index": -1,
    "no_free_pu": False,
    "overflowed_containers": (),
    "free_pus": 0,
})
#: The dtype of each key's (B,) array in the batched info: what Gymnasium's sync vector env
#: builds from the single environments' values (object for the names).
CENTRALISED_INFO_DTYPES: Mapping[str, np.dtype] = MappingProxyType({
    key: np.dtype(object if isinstance(v, (str, tuple)) else bool if isinstance(v, bool)
                  else np.float64 if isinstance(v, float) else np.int64)
    for key, v in CENTRALISED_INFO_NEUTRAL.items()
})


class CentralisedInfo:
    """The centralised view's info for a plant with containers ``names``: one dict of Python
    values for one simulation (:meth:`reset`, :meth:`step`; the single environment) or one (B,)
    array per key for B simulations (:meth:`reset_arrays`, :meth:`step_arrays`; the Gymnasium
    vector env), the same values either way.

    Both read a step's entries at column ``action - 1`` of its outcome: a simulation's action
    requests that container only. The one-simulation path reads Python scalars, as the single
    environment's step (a few microseconds) would be several times slower through arrays.
    """

    def __init__(self, names: Sequence[str]):
        self.names = tuple(names)
        # container names by index, with "" at index -1 (nothing emptied)
        self._name_table = np.array([*self.names, ""], dtype=object)
        self._one_overflowed = np.empty(len(self.names), dtype=object)  # ("C1-10",), ... one tuple a container
        for j, name in enumerate(self.names):
            self._one_overflowed[j] = (name,)

    # ---- one simulation (row 0 of the outcome) --------------------------------------------------------
    @staticmethod
    def reset(free_pus: int) -> dict[str, Any]:
        """The info of a reset (and the base of a step's): every key at its neutral value."""
        info = CENTRALISED_INFO_NEUTRAL.copy()  # a plain dict (dict(proxy) would be ten times slower)
        info["free_pus"] = int(free_pus)
        return info

    def step(self, action: int, out: StepOutcome, step_count: int) -> dict[str, Any]:
        """The info after action ``action`` (0 waits, i empties container i) of simulation 0."""
        info = CENTRALISED_INFO_NEUTRAL.copy()
        info["free_pus"] = out.free_pus_before.item(0)
        info["step"] = int(step_count)
        i = action - 1  # ``.item(k)`` reads entry k of the (one-simulation) arrays as a Python number
        if action > 0:
            info["emptying_reward"] = float(out.container_reward.item(i))
            if out.granted.item(i):
                info["emptied_container"] = self.names[i]
                info["emptied_index"] = i
                info["emptied_volume"] = float(out.emptied_volume.item(i))
                info["pu_index"] = int(out.pu_index.item(i))
            else:
                info["no_free_pu"] = True
        if out.terminated.item(0):
            info["overflowed_containers"] = tuple(self.names[j] for j in np.flatnonzero(out.overflowed[0]))
        return info

    # ---- B simulations -----------------------------------------------------------------------------
    @staticmethod
    def reset_arrays(free_pus: np.ndarray) -> dict[str, np.ndarray]:
        """The reset infos of the simulations with ``free_pus`` (one entry each), one new array per key."""
        arrays = {}
        for key, value in CENTRALISED_INFO_NEUTRAL.items():
            array = np.empty(len(free_pus), dtype=CENTRALISED_INFO_DTYPES[key])
            array.fill(value)  # fill, not np.full: a () for every object entry, not an empty shape
            arrays[key] = array
        arrays["free_pus"][:] = free_pus
        return arrays

    def step_arrays(self, actions: np.ndarray, out: StepOutcome, step_count: np.ndarray) -> dict[str, np.ndarray]:
        """The infos after the (B,) integer ``actions``, one new (B,) array per key; ``step_count``
        holds each simulation's steps taken in the episode of this step.

        A waiting simulation (action 0) reads column -1, whose entries are the "nothing happened"
        values (-1, 0.0, False) since nothing was requested in its row."""
        rows, col = np.arange(len(actions)), actions - 1
        pu_index = out.pu_index[rows, col].astype(np.int64)
        emptied_index = np.where(pu_index >= 0, col, -1)
        overflowed = np.empty(len(actions), dtype=object)
        overflowed.fill(())
        ended = np.flatnonzero(out.terminated)
        if ended.size:  # mostly one container overflows: its names' tuple picked for all such rows at once
            ended_rows = out.overflowed[ended]
            one = np.count_nonzero(ended_rows, axis=1) == 1
            overflowed[ended[one]] = self._one_overflowed[ended_rows[one].argmax(axis=1)]
            for b in ended[~one].tolist():
                overflowed[b] = tuple(self._name_table[np.flatnonzero(out.overflowed[b])].tolist())
        return {
            "step": np.asarray(step_count).astype(np.int64),
            "emptied_container": self._name_table[emptied_index],
            "emptied_index": emptied_index.astype(np.int64),
            "emptied_volume": out.emptied_volume[rows, col],
            "emptying_reward": out.container_reward[rows, col],
            "pu_index": pu_index,
            "no_free_pu": out.denied[rows, col],
            "overflowed_containers": overflowed,
            "free_pus": out.free_pus_before.astype(np.int64),
        }


# ---- the normalised global state --------------------------------------------------------------------
class NormalisedState:
    """The global state ``[v, p]`` of a plant with ``params`` in normalised units, for centralised
    critics: volumes / v_max,i in [0, 2] (above 1 only in the terminal state of an overflow) and PU
    timers / the largest possible PU time in [0, 1] (divided by 1 where that is 0, a plant whose
    PUs take no time). ``low``, ``high`` (float32, (n + m,)) are its bounds, ``scale`` the divisors."""

    def __init__(self, params):
        pu_time_s = float(params.max_pu_time_s) or 1.0
        self.scale = np.concatenate([np.asarray(params.max_volume, dtype=np.float64),
                                     np.full(params.n_pus, pu_time_s)]).astype(np.float32)
        self.low = np.zeros(params.n_containers + params.n_pus, dtype=np.float32)
        self.high = np.ones_like(self.low)
        self.high[: params.n_containers] = VOLUME_BOUND_FACTOR
        self.scale.setflags(write=False)

    def __call__(self, state: np.ndarray) -> np.ndarray:
        """The physical float32 state (any leading batch shape) divided by ``scale``, clipped into
        [low, high] (a no-op for states within the physical bounds: the quotient of a bound by its
        scale is exact in float32), a new float32 array."""
        out = np.divide(state, self.scale, dtype=np.float32)
        return np.clip(out, self.low, self.high, out=out)
