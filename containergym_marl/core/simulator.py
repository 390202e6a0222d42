"""A batch of B plant simulations: the pure core plus the per-simulation random streams.

Both environment views (and the vectorised environments) hold one :class:`PlantSimulator`; none of
them computes physics itself.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from containergym_marl.config import MAX_SIMS, PlantConfig
from containergym_marl.core import dynamics
from containergym_marl.core.dynamics import DEFAULT_ARBITRATION, PlantState, StepOutcome, StepOutputs, get_rule
from containergym_marl.core.observations import global_state
from containergym_marl.core.params import PlantParams
from containergym_marl.core.rng import NoiseStreams


class EpisodeFinishedError(RuntimeError):
    """Raised when stepping a simulation whose episode has ended (call reset first)."""


class PlantSimulator:
    """B simulations of one plant, stepped together by one call of the compiled step.

    Like a physics engine's data block (MuJoCo's ``MjData``), the simulator owns the arrays it
    writes: each step writes its :class:`StepOutcome` and the next ``state`` into one of two sets of
    arrays, taken in turn. What a step returns stays unchanged until the step after next; copy what
    you keep longer. (The views return fresh observations and Python numbers, and the episode
    recorder copies, so none of this reaches an environment's user; the pure
    :func:`containergym_marl.core.dynamics.step` allocates new arrays at every call.)

    Args:
        config: the plant.
        num_sims: number of simulations B.
        arbitration: how competing requests are ranked, a name of
            :data:`~containergym_marl.core.dynamics.ARBITRATION_RULES`.
    """

    def __init__(self, config: PlantConfig, num_sims: int = 1, arbitration: str = DEFAULT_ARBITRATION):
        self._rule = get_rule(arbitration)  # validated once, before anything is built
        if (isinstance(num_sims, bool) or not isinstance(num_sims, (int, np.integer))
                or not 1 <= num_sims <= MAX_SIMS):
            raise ValueError(f"num_sims: expected an integer in [1, {MAX_SIMS}], got {num_sims!r}")
        self.config = config
        self.params = PlantParams.from_config(config)
        self.arbitration = arbitration
        self.num_sims = int(num_sims)
        n, m = self.params.n_containers, self.params.n_pus
        self._streams: NoiseStreams | None = None
        self.state = PlantState(
            np.zeros((self.num_sims, n)),
            np.zeros((self.num_sims, m)),
            np.zeros(self.num_sims, dtype=np.int64),
        )
        self.previous_requests = np.zeros((self.num_sims, n), dtype=bool)
        # the last step's grants (emptied containers), as the plant could broadcast them; 0 after a reset
        self.previous_granted = np.zeros((self.num_sims, n), dtype=bool)
        self.finished = np.ones(self.num_sims, dtype=bool)  # nothing to step before a reset
        self._any_finished = True
        self.last_outcome: StepOutcome | None = None
        # The step writes into these two in turn (see step()).
        self._outputs = (StepOutputs(self.num_sims, n, m), StepOutputs(self.num_sims, n, m))
        self._zero_uniforms = np.zeros((self.num_sims, n))
        self._next_outputs = 0

    # ---- randomness --------------------------------------------------------------------------
    def generator(self, index: int = 0) -> np.random.Generator | None:
        return None if self._streams is None else self._streams.generator(index)

    def _set_generators(self, sims: np.ndarray, generators: Sequence[np.random.Generator]) -> None:
        if len(generators) != len(sims):
            raise ValueError(f"generators: expected {len(sims)}, got {len(generators)}")
        if self._streams is None:
            if len(sims) != self.num_sims:
                raise ValueError("the first reset must provide a generator for every simulation")
            order = np.argsort(sims)
            self._streams = NoiseStreams([generators[i] for i in order], self.params.n_containers)
            return
        for sim, gen in zip(sims, generators):
            if gen is not self._streams.generator(int(sim)):
                self._streams.set_generator(int(sim), gen)

    # ---- what-if copies ----------------------------------------------------------------------
    def branch(self, sim: int, generators: Sequence[np.random.Generator]) -> "PlantSimulator":
        """A new simulator of ``len(generators)`` simulations, each a copy of simulation ``sim`` now
        (volumes, PU timers, step count, last requests and grants, finished flag), each drawing its noise from
        its own generator.

        Nothing of this simulator is touched, its random stream included: stepping the copies (a
        planner's look-ahead) leaves the original trajectory bit-identical to one run without them.
        Copies built from generators with the same seeds see the same noise (common random numbers,
        for comparing decisions). :func:`containergym_marl.core.whatif.simulate_futures` is the
        allocation-free form a planner uses: K copies × C first decisions in one batch.
        """
        if not 0 <= int(sim) < self.num_sims:
            raise IndexError(f"sim: {sim} out of range for a batch of {self.num_sims}")
        copies = len(generators)
        new = PlantSimulator(self.config, num_sims=copies, arbitration=self.arbitration)
        rows = np.full(copies, int(sim))
        new.state = self.state.select(rows)  # fancy indexing: new arrays
        new.previous_requests = self.previous_requests[rows]
        new.previous_granted = self.previous_granted[rows]
        new.finished = self.finished[rows]
        new._any_finished = bool(new.finished.any())
        new._streams = NoiseStreams(list(generators), self.params.n_containers)
        return new

    # ---- episode control ---------------------------------------------------------------------
    def reset(
        self,
        sims: Sequence[int] | np.ndarray | None = None,
        generators: Sequence[np.random.Generator] | None = None,
    ) -> None:
        """Start new episodes in ``sims`` (default: all), optionally with new generators.

        Without generators each simulation continues its own random stream.
        """
        idx = np.arange(self.num_sims) if sims is None else np.asarray(sims, dtype=np.int64)
        if generators is not None:
            self._set_generators(idx, generators)
        if self._streams is None:
            raise RuntimeError("the first reset needs one np.random.Generator per simulation")
        everyone = sims is None or (idx.size == self.num_sims
                                    and np.array_equal(idx, np.arange(self.num_sims)))
        _, uniforms = self._streams.next_rows(None if everyone else idx, normals=False)
        fresh = dynamics.reset_state(self.params, uniforms)
        # New arrays, never writes into old ones: the previous requests are the last outcome's
        # ``requested``, which the caller may still hold.
        if everyone:
            self.state = fresh
            self.previous_requests = np.zeros_like(self.previous_requests)
            self.previous_granted = np.zeros_like(self.previous_granted)
            self.finished = np.zeros_like(self.finished)
            self._any_finished = False
        else:
            vol, tim, cnt = (self.state.volumes.copy(), self.state.pu_timers_s.copy(),
                             self.state.step_count.copy())
            vol[idx], tim[idx], cnt[idx] = fresh.volumes, fresh.pu_timers_s, fresh.step_count
            self.state = PlantState(vol, tim, cnt)
            previous, finished = self.previous_requests.copy(), self.finished.copy()
            granted = self.previous_granted.copy()
            previous[idx] = finished[idx] = granted[idx] = False
            self.previous_requests, self.previous_granted, self.finished = previous, granted, finished
            self._any_finished = bool(finished.any())

    def step(self, requests: np.ndarray) -> StepOutcome:
        """Step every simulation by one δ with a (B, n) boolean request matrix."""
        if self._any_finished:
            bad = np.flatnonzero(self.finished).tolist()
            raise EpisodeFinishedError(
                f"simulation(s) {bad} finished their episode (overflow or time limit); "
                f"call reset() before stepping again"
            )
        requests = dynamics.check_requests(requests, self.state.volumes.shape)  # before a random row is used
        normals, uniforms = self._streams.next_rows(uniforms=self._rule.reads_uniform)
        if uniforms is None:  # a rule that never reads them: zeros, not a copy of rows nobody reads
            uniforms = self._zero_uniforms
        # Written into the outputs of the step before last: the state (this step's input) lies in
        # the last step's outputs or in arrays of a reset, never in these.
        outputs = self._outputs[self._next_outputs]
        self._next_outputs ^= 1
        self.state, outcome = dynamics.step_checked(self.state, requests, self.params, normals, uniforms, self._rule,
                                                    outputs)
        self.previous_requests = outcome.requested  # shared with the outcome; reset() replaces it, never writes it
        self.previous_granted = outcome.granted  # the same
        finished = self.finished = outcome.terminated | outcome.truncated
        # a Python bool for the check above (ndarray.any() costs ~1 µs, a tenth of a small step)
        self._any_finished = finished.item(0) if finished.size == 1 else bool(np.logical_or.reduce(finished))
        self.last_outcome = outcome
        return outcome

    def global_state(self, state: PlantState | None = None) -> np.ndarray:
        """(B, n + m) float32 global state ``[v, p]`` of ``state`` (default: the current one), as
        :func:`.observations.global_state` computes it."""
        return global_state(self.state if state is None else state, self.params)

    # ---- helpers for the views ---------------------------------------------------------------
    def free_pu_count(self) -> np.ndarray:
        return (self.state.pu_timers_s == 0.0).sum(axis=1)
