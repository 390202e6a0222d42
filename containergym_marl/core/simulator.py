"""A batch of B plant simulations: the pure core plus the per-simulation random streams.

Both environment views (and the vectorised environments) hold one :class:`PlantSimulator`; none of
them computes physics itself.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from containergym_marl.config import PlantConfig
from containergym_marl.core import dynamics
from containergym_marl.core.dynamics import ARBITRATION_RULES, PlantState, StepOutcome
from containergym_marl.core.rng import NoiseStreams


class EpisodeFinishedError(RuntimeError):
    """Raised when stepping a simulation whose episode has ended (call reset first)."""


class PlantSimulator:
    """B simulations of one plant, stepped together by one core call.

    Args:
        config: the plant.
        batch_size: number of simulations B.
        arbitration: how competing requests are ranked (see :data:`ARBITRATION_RULES`).
    """

    def __init__(self, config: PlantConfig, batch_size: int = 1, arbitration: str = "fullest"):
        if arbitration not in ARBITRATION_RULES:
            raise ValueError(
                f"arbitration: unknown rule {arbitration!r}; choose one of {ARBITRATION_RULES}"
            )
        if int(batch_size) < 1:
            raise ValueError(f"batch_size: must be >= 1, got {batch_size!r}")
        self.config = config
        self.params = config.params()
        self.arbitration = arbitration
        self.batch_size = int(batch_size)
        n, m = self.params.n_containers, self.params.n_pus
        self._streams: NoiseStreams | None = None
        self.state = PlantState(
            np.zeros((self.batch_size, n)),
            np.zeros((self.batch_size, m)),
            np.zeros(self.batch_size, dtype=np.int64),
        )
        self.previous_requests = np.zeros((self.batch_size, n), dtype=bool)
        self.finished = np.ones(self.batch_size, dtype=bool)  # nothing to step before a reset
        self.last_outcome: StepOutcome | None = None

    # ---- randomness --------------------------------------------------------------------------
    def generator(self, index: int = 0) -> np.random.Generator | None:
        return None if self._streams is None else self._streams.generator(index)

    def _set_generators(self, sims: np.ndarray, generators: Sequence[np.random.Generator]) -> None:
        if len(generators) != len(sims):
            raise ValueError(f"generators: expected {len(sims)}, got {len(generators)}")
        if self._streams is None:
            if len(sims) != self.batch_size:
                raise ValueError("the first reset must provide a generator for every simulation")
            order = np.argsort(sims)
            self._streams = NoiseStreams([generators[i] for i in order], self.params.n_containers)
            return
        for sim, gen in zip(sims, generators):
            if gen is not self._streams.generator(int(sim)):
                self._streams.set_generator(int(sim), gen)

    # ---- episode control ---------------------------------------------------------------------
    def reset(
        self,
        sims: Sequence[int] | np.ndarray | None = None,
        generators: Sequence[np.random.Generator] | None = None,
    ) -> None:
        """Start new episodes in ``sims`` (default: all), optionally with new generators.

        Without generators each simulation continues its own random stream.
        """
        idx = np.arange(self.batch_size) if sims is None else np.asarray(sims, dtype=np.int64)
        if generators is not None:
            self._set_generators(idx, generators)
        if self._streams is None:
            raise RuntimeError("the first reset needs one np.random.Generator per simulation")
        _, uniforms = self._streams.next_rows(idx, normals=False)
        fresh = dynamics.reset_state(self.params, uniforms)
        if idx.size == self.batch_size and np.array_equal(idx, np.arange(self.batch_size)):
            self.state = fresh
        else:
            vol, tim, cnt = (self.state.volumes.copy(), self.state.pu_timers_s.copy(),
                             self.state.step_count.copy())
            vol[idx], tim[idx], cnt[idx] = fresh.volumes, fresh.pu_timers_s, fresh.step_count
            self.state = PlantState(vol, tim, cnt)
        self.previous_requests[idx] = False
        self.finished[idx] = False

    def step(self, requests: np.ndarray) -> StepOutcome:
        """Step every simulation by one δ with a (B, n) boolean request matrix."""
        if self.finished.any():
            bad = np.flatnonzero(self.finished).tolist()
            raise EpisodeFinishedError(
                f"simulation(s) {bad} finished their episode (overflow or time limit); "
                f"call reset() before stepping again"
            )
        normals, uniforms = self._streams.next_rows(uniforms=self.arbitration == "random")
        self.state, outcome = dynamics.step(
            self.state, requests, self.params, normals, uniforms, self.arbitration
        )
        self.previous_requests = outcome.requested.copy()
        self.finished = outcome.terminated | outcome.truncated
        self.last_outcome = outcome
        return outcome

    # ---- helpers for the views ---------------------------------------------------------------
    def free_pu_count(self) -> np.ndarray:
        return (self.state.pu_timers_s == 0.0).sum(axis=1)
