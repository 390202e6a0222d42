"""What happened in an episode, step by step: the raw material of statistics and figures.

An :class:`EpisodeRecord` is read off the shared simulator after every step, so it is the same for
the centralised and the decentralised view.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from containergym_marl.core.dynamics import overflow_probabilities
from containergym_marl.core.simulator import PlantSimulator

_ARRAYS = ("volumes", "pu_timers_s", "requested", "granted", "denied", "pu_index",
           "emptied_volume", "container_reward", "plant_reward", "overflow_probability")


@dataclass
class EpisodeRecord:
    """One episode of one simulation. T = number of steps taken.

    Arrays: ``volumes`` (T+1, n) and ``pu_timers_s`` (T+1, m) hold the state after the reset and
    after every step; ``requested``/``granted``/``denied`` (T, n) bool, ``pu_index`` (T, n) int
    (-1 = none), ``emptied_volume`` and ``container_reward`` (T, n) and ``plant_reward`` (T,) hold
    what each step did; ``overflow_probability`` (T,) is each step's probability of an overflow given
    the state before it and its emptyings (NaN in files written without it). ``container_reward`` is
    the emptying reward or penalty before any overflow replacement; ``plant_reward`` is the reward the
    centralised view returns (r_min on overflow).
    ``overflowed_containers`` names the containers whose overflow ended the episode (empty if none).
    """

    config_name: str
    container_names: tuple[str, ...]
    view: str
    policy: str
    seed: int | None
    timestep_s: float
    volumes: np.ndarray
    pu_timers_s: np.ndarray
    requested: np.ndarray
    granted: np.ndarray
    denied: np.ndarray
    pu_index: np.ndarray
    emptied_volume: np.ndarray
    container_reward: np.ndarray
    plant_reward: np.ndarray
    overflow_probability: np.ndarray
    terminated: bool
    truncated: bool
    meta: dict = field(default_factory=dict)
    overflowed_containers: tuple[str, ...] = ()

    @property
    def steps(self) -> int:
        return int(self.plant_reward.shape[0])

    @property
    def cumulative_reward(self) -> float:
        """Sum of all rewards, the final step's included."""
        return float(self.plant_reward.sum())

    def emptying_volumes(self, container: int | None = None) -> np.ndarray:
        """Volumes at which containers were emptied (all containers, or one index)."""
        g = self.granted if container is None else self.granted[:, container]
        v = self.emptied_volume if container is None else self.emptied_volume[:, container]
        return v[g]

    def emptying_rewards(self) -> np.ndarray:
        """Reward of every emptying that was carried out (granted requests)."""
        return self.container_reward[self.granted]

    def emptying_action_rewards(self) -> np.ndarray:
        """Reward of every emptying *action*: granted ones and those denied for lack of a free PU
        (r_pen), as in the paper's Figure 4 and its "share of negative rewards"."""
        return self.container_reward[self.requested]

    def save_npz(self, path: str | Path) -> None:
        meta = {k: v for k, v in asdict(self).items() if k not in _ARRAYS}
        from containergym_marl.files import atomic_write

        def write(tmp: Path) -> None:
            with open(tmp, "wb") as f:  # a file object: numpy would otherwise append ".npz" to the name
                np.savez_compressed(f, meta=json.dumps(meta), **{k: getattr(self, k) for k in _ARRAYS})

        atomic_write(path, write)

    @classmethod
    def load_npz(cls, path: str | Path) -> "EpisodeRecord":
        with np.load(path) as data:
            meta = json.loads(str(data["meta"]))
            meta["container_names"] = tuple(meta["container_names"])
            meta["overflowed_containers"] = tuple(meta.get("overflowed_containers", ()))  # absent in older files
            arrays = {k: data[k] for k in _ARRAYS if k in data.files}
            # absent in older files: unknown
            arrays.setdefault("overflow_probability", np.full(arrays["plant_reward"].shape, np.nan))
            return cls(**meta, **arrays)


class EpisodeRecorder:
    """Collects an :class:`EpisodeRecord` from simulation ``index`` of a simulator.

    Call :meth:`start` right after the environment's reset and :meth:`add` after every step.
    """

    def __init__(self, sim: PlantSimulator, *, view: str, policy: str, seed: int | None, index: int = 0):
        self.sim, self.index = sim, index
        self.view, self.policy, self.seed = view, policy, seed
        self._rows: dict[str, list] = {}

    def start(self) -> None:
        s = self.sim.state
        self._rows = {k: [] for k in _ARRAYS}
        self._rows["volumes"].append(s.volumes[self.index].copy())
        self._rows["pu_timers_s"].append(s.pu_timers_s[self.index].copy())
        self._terminated = self._truncated = False
        self._overflowed: tuple[str, ...] = ()

    def add(self) -> None:
        out, s, b = self.sim.last_outcome, self.sim.state, self.index
        before = self._rows["volumes"][-1]
        self._rows["overflow_probability"].append(
            float(overflow_probabilities(before[None], out.granted[b][None], self.sim.params)[0]))
        self._rows["volumes"].append(s.volumes[b].copy())
        self._rows["pu_timers_s"].append(s.pu_timers_s[b].copy())
        for key in ("requested", "granted", "denied", "pu_index", "emptied_volume", "container_reward"):
            self._rows[key].append(getattr(out, key)[b].copy())
        self._rows["plant_reward"].append(float(out.plant_reward[b]))
        self._terminated, self._truncated = bool(out.terminated[b]), bool(out.truncated[b])
        if self._terminated:
            names = self.sim.config.container_names
            self._overflowed = tuple(names[i] for i in np.flatnonzero(out.overflowed[b]))

    def finish(self, **meta) -> EpisodeRecord:
        n, m = self.sim.params.n_containers, self.sim.params.n_pus
        empty = {"requested": (0, n), "granted": (0, n), "denied": (0, n), "pu_index": (0, n),
                 "emptied_volume": (0, n), "container_reward": (0, n)}
        arrays = {}
        for key in _ARRAYS:
            rows = self._rows[key]
            arrays[key] = np.array(rows) if rows else np.zeros(empty.get(key, (0,)))
        arrays["pu_timers_s"] = arrays["pu_timers_s"].reshape(-1, m)
        return EpisodeRecord(
            config_name=self.sim.config.name,
            container_names=self.sim.config.container_names,
            view=self.view,
            policy=self.policy,
            seed=self.seed,
            timestep_s=self.sim.params.timestep_s,
            terminated=self._terminated,
            truncated=self._truncated,
            meta=dict(meta),
            overflowed_containers=self._overflowed,
            **arrays,
        )
