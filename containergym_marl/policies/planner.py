"""A rollout planner: Monte Carlo look-ahead over a base policy (Bertsekas' policy rollout).

At every step where a choice exists, the planner lists candidate decisions for this step, simulates
``futures`` (K) noise streams over ``horizon`` (H) steps for each of them — the candidate first, then
the base policy — and takes the candidate with the best mean look-ahead value. All C candidates × K
futures run as one batch of the compiled core (:func:`~containergym_marl.core.whatif.simulate_futures`),
with the same K noise streams for every candidate (common random numbers). The base policy's own
decision is the first candidate and wins ties, so the planner departs from the base policy only
where the simulated futures say it pays.

**Candidates.** Nothing is planned while no PU is free (emptying would be denied: wait) or while no
container is *eligible* (ready by the base rule, v* − v <= ``margin``, or earning at least
``min_reward`` if emptied now): then the planner waits, at no cost. Otherwise:

* centralised (one emptying per step): wait, and empty i for each eligible i;
* container agents (up to f requests, f = free PUs): the base policy's set S, nothing, S without
  each of its members, and S plus each other eligible container (or, if S already fills the f free
  PUs, S with its least full member swapped for it). Requests never exceed the free PUs, so none is
  denied and the environment's arbitration never has to choose.

**Value of a future.** Its rewards over the horizon (an overflow earns r_min, as in the plant), plus

* a *terminal value* if its episode is still running after H steps: each container is worth
  ``r(v*)·v / v*`` below its optimum (the share of its next full-value emptying it has already
  collected; at steady state this makes emptying at the optimum neither gain nor lose value) and
  ``r(v)`` past it (what emptying it now would still earn);
* minus an *expected overflow cost*: at every simulated step t, the probability that the step
  overflows given the state before it (computed from the fill distribution, not sampled: an
  overflow risk of a few per cent is seen even with few futures) times the rewards the rest of the
  episode would have brought, ``ρ·(T − t)`` with ρ = Σᵢ r(v*ᵢ)·μᵢδ / v*ᵢ, the plant's reward per
  step when every container is emptied at its optimum, plus ``overflow_penalty`` (default 10, the
  reward of ten ideal emptyings): in the plant an overflow is an incident, not merely the end of an
  episode, and the benchmark counts overflowing episodes apart; without it the planner would
  accept a few per cent of overflow risk near the end of an episode, where little reward is left to
  lose. A sampled overflow also ends its future, with r_min, as in the plant.

A time-limit end inside the horizon gets no terminal value: volumes left at the end are worth
nothing, so near the end of an episode the planner empties what still earns something.

**Base policies** (:data:`BASE_POLICIES`): ``"fullest"`` (default), the per-container rule-based
agents with the ``fullest`` arbitration, requesting only what free PUs can grant (ready containers,
fullest v / v_max first, at most one per step in the centralised view); ``"index"``, the same with
the centralised rule's order (lowest index first).

**Cost per decision** (a planned step): H compiled steps of C·K simulations, their overflow
probabilities and H base-policy calls on them, C <= n + 1 candidates. With the defaults (K = 16,
H = 8) that is 8 steps of up to 192 simulations at n = 11, about 1–2 ms of CPU on one core; steps
without a choice (no free PU, nothing eligible) cost nothing. Doubling K doubles the simulated
work (the per-step Python overhead stays); doubling H doubles both. ``studies/planner_rows.py``
measures the time per step on every row (``results/planner/rows.md``). :func:`decide_all` decides
for many simulations at once, one planner each (DAgger's labels): the same decisions, every
look-ahead's futures stepped in one batch, which costs less CPU than one planner at a time
(``benchmarks/labelling.py`` measures both side by side).

**Choosing the settings.** The defaults were chosen on validation episodes (seeds 20000+, not the
test seeds); ``studies/planner_sweep.py`` (``results/planner/sweep_n11_m2_dt120.md``) and
``studies/planner_validation.py`` (``results/planner_validation/validation.md``, 30 episodes per
setting on each test plant, both views) hold the runs:

* K = 16 futures suffice for the return: with common random numbers and the computed overflow
  risk, 64 futures did not raise it on ``n11_m2``.
* Longer horizons *lower* the return on the contended plants (m = 2): for the container agents
  H = 4–8 gave 96.2–96.6 against 92.1–94.1 for H = 16–48 on ``n11_m2``, and 109.5–111.8 against
  88.7–108.1 on ``n16_m2``. A long rollout scores a decision by what the base policy would do for
  many steps, and the base policy copes badly with contention (it empties in order of fullness only
  when a container is ready, and lets the others wait), so long look-aheads are pessimistic and push
  the planner to empty early to hedge against mistakes its own later decisions would not make. A
  short look-ahead with the terminal value above is the better estimate here; on the uncontended
  plants the horizon hardly matters.
* ``margin`` = 1 scores highest of 0, 1, 2 and 4 on the contended plants, in both views; 4 loses
  2–18 points everywhere.
* ``overflow_penalty`` between 0 and 30 moves the validation return by less than its standard
  error on every plant: 10 is kept as the incident cost argued above; at 100 the agents overflow
  once on ``n16_m2``.
* ``min_reward`` = 0 (and 0.25) overflow nowhere; −1 (every container a candidate) overflows on
  ``n11_m2``, 0.5 on ``n16_m2``.

**Not overflow-free.** On 200 fresh episodes per plant (seeds 30000+) neither view overflows on
n = 5 or on ``n11_m11``; on ``n11_m2`` the centralised planner overflows in 2 and the container
agents in 3, on ``n16_m2`` in 5 and 6. Those are mostly the look-ahead's sampling error, not doomed
episodes: replayed with the planner's seed changed (1, 2) or with 64 futures, at most 1 of these 16
episodes overflows again under each change (``results/planner_validation/validation.md``).
``max_futures`` spends more futures where that error decides: on the steps where another candidate
is within ``confidence`` standard errors of the best (``studies/planner_validation.py --parts wide``
measures it on validation episodes).

**Deadline check** (``safety_risk`` = ε, off by default). The overflow cost above is estimated from
the K sampled futures, and near an overflow that estimate is noisy: the risk sits in the few futures
whose fills run high several steps in a row (in an overflowing validation episode of ``n16_m2`` the
16 futures gave a candidate 0.3 % of overflow risk where 4,000 give 5.5 %), which is why more
futures or another seed move the overflows around instead of removing them. With ε set, every
decision must also pass a check that samples nothing (:mod:`~containergym_marl.policies.safety`): from
the fill distribution, each container's deadline (the fills it can wait before its probability of
overflowing passes ε); from the PU timers after the decision, a schedule that empties the containers
due within ``safety_horizon_steps`` (W) earliest deadline first, each as soon as a PU frees. A
decision whose schedule misses a deadline is replaced by the best-valued candidate whose schedule
meets them all (the containers due in the window become candidates too); if there is none, by the
candidate of least total schedule risk. Where the look-ahead's choice passes, the decision (and the
planner's random stream) is that of the planner without the check. ``studies/planner_validation.py
--parts safety`` measures it next to the defaults.

**Randomness.** The planner draws its futures from its own generator, seeded per episode from
``(episode seed, seed)`` by :meth:`reset` (which :func:`~containergym_marl.evaluation.evaluate`
calls with the evaluation seed), so an evaluation is reproducible and the environment's random
stream is never touched. Without a ``reset`` call the seed is derived from the episode's initial
state, itself a function of the environment's seed.

The planner reads the exact (float64) state from ``env.simulator`` and the plant from its params,
so one object works on any plant; the ``params`` it is built with (for the registries that build
every controller from the training config) are not needed.
"""

from __future__ import annotations

import hashlib
import itertools
from typing import Any, Callable, NamedTuple, Sequence

import numpy as np

from containergym_marl.config.pu_time import jit
from containergym_marl.core.dynamics import PlantState, emptying_rewards
from containergym_marl.core.params import PlantParams
from containergym_marl.core.whatif import Futures, simulate_future_groups, simulate_futures
from containergym_marl.policies.rule_based import within_margin
from containergym_marl.policies.safety import DeadlineCheck

#: The earliest-due containers whose every one or two the container agents' shield weighs
SHIELD_POOL = 8
#: Last word of the planner's seed entropy, so its streams differ from the environment's (which
#: are seeded from the episode seed alone).
_STREAM_TAG = 0x706C616E  # "plan"


# ---- base policies: (state, params, max_requests, margin) -> (B, n) bool requests ---------------
@jit
def _grant_by_priority(volumes, pu_timers_s, target, max_volume, margin, by_fullness, max_requests):
    """(B, n) bool: the containers within ``margin`` of their optimum (v* − v <= margin, as
    :func:`~containergym_marl.policies.rule_based.within_margin`) in decreasing priority (v / v_max with
    ``by_fullness``, else the lower index), ties to the lower index, as many as there are free PUs (at
    most ``max_requests``): requests that the plant will all grant. One compiled pass: the look-ahead
    calls its base policy at every simulated step."""
    b_count, n = volumes.shape
    out = np.zeros((b_count, n), dtype=np.bool_)
    ready, key = np.empty(n, dtype=np.bool_), np.empty(n)
    for b in range(b_count):
        limit = min(int((pu_timers_s[b] == 0.0).sum()), max_requests)
        if limit <= 0:
            continue
        for i in range(n):
            ready[i] = target[i] - volumes[b, i] <= margin
            key[i] = volumes[b, i] / max_volume[i] if by_fullness else -float(i)
        for i in range(n):
            if ready[i]:
                rank = 0  # ready containers ahead of i: a higher priority, or the same one at a lower index
                for j in range(n):
                    if ready[j] and (key[j] > key[i] or (key[j] == key[i] and j < i)):
                        rank += 1
                out[b, i] = rank < limit
    return out


def fullest_base(state: PlantState, params: PlantParams, max_requests: int, margin: float = 1.0) -> np.ndarray:
    """Rule-based agents with the ``fullest`` arbitration: ready containers, fullest v / v_max
    first, as many as free PUs allow."""
    return _grant_by_priority(state.volumes, state.pu_timers_s, params.target_volume, params.max_volume,
                              float(margin), True, int(max_requests))


def index_base(state: PlantState, params: PlantParams, max_requests: int, margin: float = 1.0) -> np.ndarray:
    """The centralised rule's order: ready containers, lowest index first, as many as free PUs allow."""
    return _grant_by_priority(state.volumes, state.pu_timers_s, params.target_volume, params.max_volume,
                              float(margin), False, int(max_requests))


#: name -> base policy of the look-ahead.
BASE_POLICIES: dict[str, Callable[..., np.ndarray]] = {"fullest": fullest_base, "index": index_base}


def _unique_rows(rows: list[np.ndarray]) -> np.ndarray:
    """(C, n) bool: the distinct request sets of ``rows`` (each (n,) bool), in their first order."""
    unique = dict.fromkeys(r.tobytes() for r in rows)
    return np.frombuffer(b"".join(unique), dtype=bool).reshape(len(unique), rows[0].size)


class RolloutPlanner:
    """Rollout planner for the centralised view (at most one emptying per step).

    Args:
        params: the plant (optional; the plant is read from the environment at every step).
        futures: K, noise streams simulated per candidate.
        horizon: H, look-ahead steps per future (the first is the candidate's).
        base: the base policy of the look-ahead, a name of :data:`BASE_POLICIES`.
        margin: the base rule's margin (volume units below the optimum at which it empties).
        min_reward: containers earning at least this if emptied now are candidates too.
        overflow_penalty: cost of an overflow on top of r_min and the estimated rest-of-episode reward.
        seed: combined with each episode's seed to seed the planner's generator.
        max_futures: futures of an *uncertain* decision (default: ``futures``, never more). When a
            candidate's mean value is within ``confidence`` standard errors of the best one's (on the
            same futures: the paired differences), the planner draws ``max_futures − futures`` more
            futures and decides on all of them, so the look-ahead's sampling error is small where it
            decides, at the cost of more simulations on those steps only.
        confidence: the standard errors of that test.
        safety_risk: ε, probability (per container, no unit); ``None`` (default): no check. With it set,
            the planner's decision must leave a schedule of the PUs, earliest deadline first, that
            empties every container before its overflow probability passes ε (the deadline check of
            :mod:`~containergym_marl.policies.safety`); a decision that does not is replaced by the
            best-valued one that does.
        safety_horizon_steps: W, the window of that check (steps): containers that can wait W fills
            with an overflow probability <= ε are not scheduled.
    """

    name = "planner"
    view = "centralised"
    max_requests: int | None = 1  # per step; None: as many as free PUs (container agents)
    shield_by_default = False  # the deadline check on unless told otherwise (the shielded planners below)

    def __init__(self, params: PlantParams | None = None, *, futures: int = 16, horizon: int = 8,
                 base: str = "fullest", margin: float = 1.0, min_reward: float = 0.0,
                 overflow_penalty: float = 10.0, seed: int = 0, max_futures: int | None = None,
                 confidence: float = 2.0, safety_risk: float | None = None, safety_horizon_steps: int = 24):
        if base not in BASE_POLICIES:
            raise ValueError(f"base: unknown base policy {base!r}; choose one of {tuple(BASE_POLICIES)}")
        max_futures = futures if max_futures is None else max_futures
        for label, value in (("futures", futures), ("horizon", horizon), ("max_futures", max_futures)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{label}: expected an integer >= 1, got {value!r}")
        if max_futures < futures:
            raise ValueError(f"max_futures: expected at least futures ({futures}), got {max_futures}")
        if not (isinstance(confidence, (int, float)) and np.isfinite(confidence) and confidence >= 0):
            raise ValueError(f"confidence: expected a finite number >= 0, got {confidence!r}")
        if safety_risk is not None and not (isinstance(safety_risk, (int, float)) and not isinstance(safety_risk, bool)
                                            and 0.0 < safety_risk < 1.0):
            raise ValueError(f"safety_risk: expected a probability in (0, 1) or None, got {safety_risk!r}")
        if (isinstance(safety_horizon_steps, bool) or not isinstance(safety_horizon_steps, (int, np.integer))
                or safety_horizon_steps < 1):
            raise ValueError(f"safety_horizon_steps: expected an integer >= 1, got {safety_horizon_steps!r}")
        self.params = params
        self.futures, self.horizon, self.base = int(futures), int(horizon), base
        self.margin, self.min_reward = float(margin), float(min_reward)
        self.overflow_penalty = float(overflow_penalty)
        self.seed = int(seed)
        self.max_futures, self.confidence = int(max_futures), float(confidence)
        self.safety_risk = None if safety_risk is None else float(safety_risk)
        self.safety_horizon_steps = int(safety_horizon_steps)
        self._base = BASE_POLICIES[base]
        self._rng: np.random.Generator | None = None
        self._seeded_by_reset = False
        self._plant: tuple[PlantParams, np.ndarray, float] | None = None
        #: decisions taken / planned (with a look-ahead) / planned again with max_futures, since construction
        self.decisions = self.planned = self.widened = 0
        #: decisions the deadline check replaced, since construction
        self.shielded = 0

    # ---- episode control --------------------------------------------------------------------
    def reset(self, seed: int | None = None) -> None:
        """Start an episode: the planner's generator is seeded from ``(seed, self.seed)``."""
        self._rng = None if seed is None else self._generator_for(int(seed))
        self._seeded_by_reset = seed is not None

    def _generator_for(self, episode_seed: int) -> np.random.Generator:
        return np.random.default_rng([episode_seed % 2**64, self.seed % 2**64, _STREAM_TAG])

    def _start_of_step(self, state: PlantState) -> None:
        """Episode bookkeeping, at every decision: an episode that starts without a :meth:`reset`
        gets a generator seeded from its initial state (a function of the environment's seed)."""
        if state.step_count.item(0) == 0:
            if not self._seeded_by_reset:
                self._rng = None
            self._seeded_by_reset = False
        if self._rng is None:
            digest = hashlib.sha256(state.volumes[:1].tobytes()).digest()
            self._rng = self._generator_for(int.from_bytes(digest[:8], "little"))

    # ---- the decision ------------------------------------------------------------------------
    def _plant_constants(self, params: PlantParams) -> tuple[np.ndarray, float]:
        """r(v*) per container and ρ, the reward per step of emptying everything at its optimum."""
        if self._plant is None or self._plant[0] is not params:
            target_reward = emptying_rewards(np.asarray(params.target_volume)[None, :], params)[0]
            rate = float((target_reward * params.fill_mean_per_step / params.target_volume).sum())
            self._plant = (params, target_reward, rate)
        return self._plant[1], self._plant[2]

    def decide(self, state: PlantState, params: PlantParams) -> np.ndarray:
        """(n,) bool: the containers to empty now in the one-simulation ``state``."""
        return decide_all([self], state, params)[0]

    def _begin(self, state: PlantState, params: PlantParams) -> np.ndarray | _Look:
        """The decision where it needs no look-ahead; else the look-ahead to simulate, its futures drawn."""
        self.decisions += 1
        self._start_of_step(state)
        n = params.n_containers
        free = int((state.pu_timers_s[0] == 0.0).sum())
        if free == 0:
            return np.zeros(n, dtype=bool)
        limit = free if self.max_requests is None else min(free, self.max_requests)
        volumes = state.volumes[:1]
        eligible = self._eligible(volumes, params)
        check = None
        if self.safety_risk is not None:
            check = DeadlineCheck(volumes[0], state.pu_timers_s[0], params, self.safety_risk,
                                  self.safety_horizon_steps, one_per_step=self.max_requests == 1)
        if not eligible.any() and (check is None or check.safe(np.zeros(n, dtype=bool))):
            return np.zeros(n, dtype=bool)
        base = self._base(state, params, limit, self.margin)[0]
        candidates = self._candidates(base, eligible, limit, volumes[0] / params.max_volume)
        if len(candidates) == 1:
            return self._finish(state, params, _Look(candidates, None, (check, base, eligible, limit)), None)
        self.planned += 1
        return _Look(candidates, self._normals(params, self.futures), (check, base, eligible, limit))

    def _finish(self, state: PlantState, params: PlantParams, look: _Look, values: np.ndarray | None) -> np.ndarray:
        """The decision from the look-ahead's (C, K) ``values`` (None: a single candidate)."""
        check, base, eligible, limit = look.context
        candidates = look.candidates
        if values is not None and self.max_futures > self.futures and self.uncertain(values, self.confidence):
            self.widened += 1
            values = np.concatenate([values, self._values(state, params, candidates,
                                                          self.max_futures - self.futures)], axis=1)
        best = 0 if values is None else int(np.argmax(values.mean(axis=1)))  # the first best: the base on ties
        if check is None or check.safe(candidates[best]):
            return candidates[best]
        return self._shielded(state, params, check, base, eligible, limit, candidates, values)

    def _eligible(self, volumes: np.ndarray, params: PlantParams) -> np.ndarray:
        """(n,) bool: the containers worth emptying now in the (1, n) ``volumes``: within the base
        rule's margin of their optimum, or earning at least ``min_reward``."""
        return (within_margin(volumes, params, self.margin)[0]
                | (emptying_rewards(volumes, params)[0] >= self.min_reward))

    def contended(self, state: PlantState, params: PlantParams) -> np.ndarray:
        """(B,) bool: the simulations of ``state`` whose free PUs are contested, where at least one PU
        is free and more containers are due than PUs are free, a container being due within the base
        rule's margin below its optimum or past it. There it matters which container asks, and a
        wrong choice is the one that overflows; they are a few percent of ``planner_agents``' steps
        on n11_m2 and n16_m2 (the states DAgger's ``contended_share`` oversamples). Containers that
        merely earn something (the rest of :meth:`decide`'s eligible ones) are left out: counting
        them makes about half of those steps contended."""
        free = (state.pu_timers_s == 0.0).sum(axis=1)
        return (free >= 1) & (within_margin(state.volumes, params, self.margin).sum(axis=1) > free)

    def _shielded(self, state: PlantState, params: PlantParams, check: DeadlineCheck, base: np.ndarray,
                  eligible: np.ndarray, limit: int, candidates: np.ndarray, values: np.ndarray | None) -> np.ndarray:
        """The decision when the look-ahead's choice fails the deadline check: the best-valued safe
        candidate, the containers due in the check's window candidates too (each set of up to
        ``limit`` of them and of the base policy's requests: the sets built around the base's choice
        can all be unsafe where emptying two due containers now is safe); if none is safe, the one of
        least total schedule risk."""
        self.shielded += 1
        due = np.zeros(params.n_containers, dtype=bool)
        due[check.due] = True
        extended = self._candidates(base, eligible | due, limit, state.volumes[0] / params.max_volume)
        if limit > 1:  # more than one emptying a step (the container agents): sets the base's choice misses
            # every one or two of the earliest-due containers and of the base's requests, and the
            # earliest-due first k for each k up to the free PUs (kept few where many PUs are free)
            pool = np.union1d(check.due[:SHIELD_POOL], np.flatnonzero(base))
            chosen = [*(c for size in (1, 2) for c in itertools.combinations(pool, size)),
                      *(check.due[:k] for k in range(3, limit + 1))]
            extended = _unique_rows([*extended, *(np.isin(np.arange(params.n_containers), c) for c in chosen)])
        if len(extended) > len(candidates):
            candidates = extended
            values = self._values(state, params, candidates, self.futures)
        mean = np.zeros(len(candidates)) if values is None else values.mean(axis=1)
        risks = np.array([check.schedule_risk(c) for c in candidates])  # (C, n)
        safe = risks.max(axis=1) <= check.epsilon
        if safe.any():
            return candidates[int(np.argmax(np.where(safe, mean, -np.inf)))]
        total = risks.sum(axis=1)
        return candidates[int(np.lexsort((-mean, total))[0])]  # least risk, then best value

    def _values(self, state: PlantState, params: PlantParams, candidates: np.ndarray, futures: int) -> np.ndarray:
        """(C, K) values of ``futures`` new futures of every candidate (the same streams for each)."""
        simulated = simulate_futures(state, 0, candidates, self._later_requests, params,
                                     self._normals(params, futures))
        return self._value_candidates(state, params, candidates, simulated)

    def _value_candidates(self, state: PlantState, params: PlantParams, candidates: np.ndarray,
                          simulated: Futures) -> np.ndarray:
        """(C, K) values of the ``candidates``' ``simulated`` futures from the one-simulation ``state``:
        every look-ahead's values pass here (alone or batched)."""
        return self.future_values(simulated, params, int(state.step_count[0]))

    def _normals(self, params: PlantParams, futures: int) -> np.ndarray:
        """(H, K, n) standard normals from the planner's generator: the noise streams of K futures."""
        return self._rng.standard_normal((self.horizon, futures, params.n_containers))

    def _later_requests(self, state: PlantState, params: PlantParams) -> np.ndarray:
        """The base policy's requests at the look-ahead's later steps."""
        max_requests = params.n_containers if self.max_requests is None else self.max_requests
        return self._base(state, params, max_requests, self.margin)

    def _same_look_ahead(self, other: "RolloutPlanner") -> bool:
        """Whether ``other``'s futures may be simulated in one batch with this planner's (:func:`decide_all`)."""
        return (other.horizon == self.horizon and other._base is self._base and other.margin == self.margin
                and other.max_requests == self.max_requests)

    @staticmethod
    def uncertain(values: np.ndarray, confidence: float) -> bool:
        """Whether some candidate's mean value is within ``confidence`` standard errors of the best
        one's, the error that of the mean of their paired differences ((C, K) ``values``, the same
        futures in a column); a candidate whose every future is worth the same is not uncertain."""
        best = int(np.argmax(values.mean(axis=1)))
        gaps = values[best] - np.delete(values, best, axis=0)  # (C - 1, K)
        error = gaps.std(axis=1, ddof=1) / np.sqrt(values.shape[1])
        return bool(np.any((error > 0) & (gaps.mean(axis=1) <= confidence * error)))

    @staticmethod
    def _candidates(base: np.ndarray, eligible: np.ndarray, limit: int, fullness: np.ndarray) -> np.ndarray:
        """(C, n) candidate request sets, the base policy's first, without duplicates."""
        out = [base]
        if base.any():
            out.append(np.zeros_like(base))
        members = np.flatnonzero(base)
        if members.size >= 2:
            for j in members:
                c = base.copy()
                c[j] = False
                out.append(c)
        least_full = members[np.argmin(fullness[members])] if members.size else -1
        for i in np.flatnonzero(eligible & ~base):
            c = base.copy()
            if members.size >= limit:
                c[least_full] = False
            c[i] = True
            out.append(c)
        return _unique_rows(out)

    def future_values(self, futures: Futures, params: PlantParams, step: int) -> np.ndarray:
        """(C, K) value of every simulated future from absolute step ``step`` (see the module doc)."""
        target_reward, rate = self._plant_constants(params)
        value = futures.rewards.sum(axis=-1)
        horizon = futures.rewards.shape[-1]
        # an overflow at step t loses the rest of the episode, and is an incident in itself
        cost = rate * np.maximum(params.episode_length_steps - (step + 1 + np.arange(horizon)), 0)
        cost += self.overflow_penalty
        value -= futures.overflow_risk @ cost  # the expected cost, from each step's overflow probability
        v = futures.final_state.volumes
        target = np.asarray(params.target_volume)
        worth = np.where(v <= target, target_reward * v / target, emptying_rewards(v, params))
        terminal = worth.sum(axis=1).reshape(futures.end_step.shape)
        return value + np.where(futures.ended, 0.0, terminal)

    def act(self, observation: Any, env: Any) -> int:
        sim = env.unwrapped.simulator if hasattr(env, "unwrapped") else env.simulator
        requests = self.decide(sim.state, sim.params)
        return int(requests.argmax()) + 1 if requests.any() else 0


class PlannerAgents(RolloutPlanner):
    """The rollout planner acting for all container agents (decentralised view): it decides which
    containers request, never more than there are free PUs."""

    name = "planner_agents"
    view = "decentralised"
    max_requests = None

    def act(self, observations: dict[str, Any], env: Any) -> dict[str, int]:
        sim = env.unwrapped.simulator if hasattr(env, "unwrapped") else env.simulator
        requests = self.decide(sim.state, sim.params)
        return {agent: int(requests[i]) for i, agent in enumerate(env.possible_agents) if agent in observations}

    def respond(self, state: PlantState, params: PlantParams, requests: np.ndarray) -> np.ndarray:
        """(n,) bool: each container agent's best response to the others' ``requests`` ((n,) bool, as
        the agents made them), by this planner's look-ahead: agent i requests where the futures of
        ``requests`` with i's request on are worth more than with it off, every other agent's request
        as it was and the plant's arbitration deciding which requests are granted (a request no free
        PU takes is denied, and costs). The n + 1 request sets (``requests`` and each agent's flip)
        are valued on the same K futures. No look-ahead where no PU is free (every request would be
        denied) or no container is eligible and none requested (what :meth:`decide` does there):
        nothing is requested."""
        return respond_all([self], state, params, np.asarray(requests, dtype=bool).reshape(1, -1))[0]

    def _begin_response(self, state: PlantState, params: PlantParams, requests: np.ndarray) -> np.ndarray | _Look:
        """:meth:`respond` where it needs no look-ahead; else the look-ahead of the n + 1 request sets."""
        self.decisions += 1
        self._start_of_step(state)
        n = params.n_containers
        requests = np.asarray(requests, dtype=bool).reshape(n)
        if not (state.pu_timers_s[0] == 0.0).any():
            return np.zeros(n, dtype=bool)
        if not self._eligible(state.volumes[:1], params).any() and not requests.any():
            return np.zeros(n, dtype=bool)
        self.planned += 1
        flips = np.logical_xor(requests[None, :], np.eye(n, dtype=bool))  # row i: agent i's request flipped
        return _Look(np.vstack([requests[None, :], flips]), self._normals(params, self.futures), requests)

    @staticmethod
    def _finish_response(look: _Look, values: np.ndarray) -> np.ndarray:
        worth, requests = values.mean(axis=1), look.context
        with_request = np.where(requests, worth[0], worth[1:])
        without = np.where(requests, worth[1:], worth[0])
        return with_request > without  # a tie: no request


class _Look(NamedTuple):
    """A decision's look-ahead: its (C, n) candidates, their (H, K, n) noise (None: nothing to
    simulate) and what the decision needs afterwards."""

    candidates: np.ndarray
    normals: np.ndarray | None
    context: Any


def _simulate_looks(planners: Sequence[RolloutPlanner], states: list[PlantState], state: PlantState,
                    params: PlantParams, looks: dict[int, _Look]) -> dict[int, np.ndarray]:
    """The (C, K) values of each planner b's look-ahead ``looks[b]`` in simulation b of ``state``
    (``states[b]`` alone), all futures stepped in one batch
    (:func:`~containergym_marl.core.whatif.simulate_future_groups`)."""
    if not looks:
        return {}
    first = planners[next(iter(looks))]
    if not all(first._same_look_ahead(planners[b]) for b in looks):
        raise ValueError("planners: a batch of decisions needs the same horizon, base policy, margin and view")
    order = list(looks)
    futures = simulate_future_groups(state, [(b, looks[b].candidates, looks[b].normals) for b in order],
                                     first._later_requests, params)
    return {b: planners[b]._value_candidates(states[b], params, looks[b].candidates, f)
            for b, f in zip(order, futures)}


def decide_all(planners: Sequence[RolloutPlanner], state: PlantState, params: PlantParams) -> np.ndarray:
    """(B, n) bool: planner b's decision in simulation b of ``state`` (B rows), each what
    ``planners[b].decide`` would return in that simulation alone (same look-ahead, same random stream),
    with the look-ahead futures of every planner that plans simulated together: one compiled step per
    look-ahead step for the whole batch rather than per planner, which is what labelling many
    simulations at once costs (:class:`~containergym_marl.training.dagger.Labeller`). The planners must
    share their horizon, base policy, margin and view."""
    return _decide_together(planners, state, params, lambda b, planner, one: planner._begin(one, params),
                            lambda planner, one, look, values: planner._finish(one, params, look, values))


def respond_all(planners: Sequence[PlannerAgents], state: PlantState, params: PlantParams,
                requests: np.ndarray) -> np.ndarray:
    """(B, n) bool: :meth:`PlannerAgents.respond` of planner b in simulation b of ``state`` to the
    agents' ``requests[b]`` ((B, n) bool), the look-aheads simulated together as in :func:`decide_all`."""
    requests = np.asarray(requests, dtype=bool)
    b_count = state.volumes.shape[0]
    if requests.shape != (b_count, params.n_containers):
        raise ValueError(f"requests: expected shape ({b_count}, {params.n_containers}), got {requests.shape}")
    return _decide_together(planners, state, params,
                            lambda b, planner, one: planner._begin_response(one, params, requests[b]),
                            lambda planner, one, look, values: PlannerAgents._finish_response(look, values))


def _decide_together(planners: Sequence[RolloutPlanner], state: PlantState, params: PlantParams,
                     begin: Callable[[int, RolloutPlanner, PlantState], np.ndarray | _Look],
                     finish: Callable[[RolloutPlanner, PlantState, _Look, np.ndarray], np.ndarray]) -> np.ndarray:
    """Each planner's ``begin`` in its simulation (a decision, or a look-ahead to simulate), then every
    look-ahead simulated in one batch and each planner's ``finish`` on its values."""
    b_count = state.volumes.shape[0]
    if len(planners) != b_count:
        raise ValueError(f"planners: expected one per simulation ({b_count}), got {len(planners)}")
    out = np.zeros((b_count, params.n_containers), dtype=bool)
    states = [state.select(slice(b, b + 1)) for b in range(b_count)]
    looks = {}
    for b, planner in enumerate(planners):
        begun = begin(b, planner, states[b])
        if isinstance(begun, _Look):
            looks[b] = begun
        else:
            out[b] = begun
    for b, values in _simulate_looks(planners, states, state, params, looks).items():
        out[b] = finish(planners[b], states[b], looks[b], values)
    return out


#: The deadline check's setting of the shielded planners, chosen on validation episodes (seeds 20000+,
#: studies/planner_validation.py --parts risk): the largest ε of 1e-4, 1e-5 and 1e-6 whose overflow risk
#: (expected overflowing episodes) is at most 0.1 per 1,000 episodes on both contended plants, both views;
#: 1e-4 and 1e-5 left about 0.2 per 1,000 on n16_m2 (and 1e-2, 1e-3 let replayed overflows happen again).
SHIELD = {"safety_risk": 1e-6, "safety_horizon_steps": 24}


class ShieldedPlanner(RolloutPlanner):
    """The rollout planner with the deadline check on (ε = 1e-6, W = 24: :data:`SHIELD`)."""

    name = "planner_shielded"
    shield_by_default = True

    def __init__(self, params: PlantParams | None = None, **settings: Any):
        super().__init__(params, **{**SHIELD, **settings})


class ShieldedPlannerAgents(PlannerAgents):
    """The rollout planner for all container agents with the deadline check on (ε = 1e-6, W = 24: :data:`SHIELD`)."""

    name = "planner_agents_shielded"
    shield_by_default = True

    def __init__(self, params: PlantParams | None = None, **settings: Any):
        super().__init__(params, **{**SHIELD, **settings})

