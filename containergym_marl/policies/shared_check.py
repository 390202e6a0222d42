"""One message per container agent and step, and the rule every agent applies to all of them.

Where two PUs serve 11 or 16 containers, a container agent that sees only its own container loses to
the planner in two ways that need the others' state: requests that the arbitration denies (each costs
r_pen) and the rare step where a PU goes to a container that could have waited while another one, due
sooner, is left to overflow. The *shared check* lets the agents talk once a step:

**What is communicated.** Each agent broadcasts one message: its container's volume (its own
``volume_frac`` × its v_max) and its policy's log-odds of requesting (its request, with ``prefer=
"nearest"``). Every agent receives all n messages and the PU timers it already observes
(``pu_timer_frac``), and knows the plant's description (each container's v_max, fill statistics and
PU times, as the planner does). From the same messages every agent computes the same deterministic
rule, so each agent's request stays its own decision, taken on what it was allowed to receive:

1. the requests the plant's arbitration would grant (fullest first, the default rule,
   :func:`~containergym_marl.core.dynamics.grant_requests`), so that a request it would deny is
   withdrawn: the same emptyings, without the denied requests' cost;
2. the reference's deadline check (:class:`~containergym_marl.policies.safety.DeadlineCheck`, risk ε,
   window W) on those emptyings: if they leave some container's overflow risk above ε, the agents
   request the safe set of emptyings that their policy finds most likely instead (``prefer="policy"``:
   the largest sum of the members' log-odds; ``"nearest"``: most of the granted emptyings kept, then
   the fewest; ties to the earliest-due). The candidates are the planner's shield's: the granted set,
   the k earliest-due for k up to the free PUs, every one or two of the earliest-due and the granted.
   If none is safe, the one of least total schedule risk.

No PU free: every request would be denied, so none is made.

A model carries the rule as its ``shared_check`` (``{"risk": ε, "window_steps": W, "prefer": ...}``,
:class:`~containergym_marl.policies.actor_critic.ActorCritic`): its policy adapter applies it
wherever it acts, once bound to the plant (:class:`SharedCheck`). ``studies/shared_check_screen.py``
chose ε = 1e-4, W = 24 and the policy's preference on validation episodes (:data:`SHARED_CHECK`).

Cost: the arbitration and n·W normal tails per simulation with a free PU; the candidates' EDF passes
only at the rare steps where the granted emptyings are unsafe; all of it compiled.
"""

from __future__ import annotations

import math

import numpy as np

from containergym_marl.config.pu_time import jit
from containergym_marl.core.dynamics import DEFAULT_ARBITRATION, fullest_first, grant_requests
from containergym_marl.core.observations import agent_feature_names
from containergym_marl.core.params import PlantParams, unpack_params
from containergym_marl.policies.safety import _waiting_risk, schedule_risk_into

#: How the check chooses among safe emptyings: the agents' policy's most likely, or nearest to the granted.
PREFERENCES = ("policy", "nearest")
#: The setting chosen on validation episodes (``studies/shared_check_screen.py``, results/shared_check/).
SHARED_CHECK = {"risk": 1e-4, "window_steps": 24, "prefer": "policy"}
#: The earliest-due containers among which the check forms its candidate pairs (the planner's shield's).
POOL = 8
#: The longest window the check takes (steps).
MAX_WINDOW_STEPS = 256


def check_shared_check(value, where: str = "shared_check") -> dict | None:
    """``value`` as a model's shared check, ``{"risk": ε, "window_steps": W, "prefer": ...}`` (ε in (0, 1),
    W an integer in [1, MAX_WINDOW_STEPS], prefer one of :data:`PREFERENCES`), or None; a ValueError naming
    ``where`` otherwise."""
    if value is None:
        return None
    if not isinstance(value, dict) or set(value) != set(SHARED_CHECK):
        raise ValueError(f"{where}: expected None or {{'risk': ε, 'window_steps': W, 'prefer': {PREFERENCES}}}, "
                         f"got {value!r}")
    risk, window, prefer = value["risk"], value["window_steps"], value["prefer"]
    if isinstance(risk, bool) or not isinstance(risk, (int, float)) or not (math.isfinite(risk) and 0 < risk < 1):
        raise ValueError(f"{where}: risk must be a probability in (0, 1), got {risk!r}")
    if isinstance(window, bool) or not isinstance(window, (int, np.integer)) or not 1 <= window <= MAX_WINDOW_STEPS:
        raise ValueError(f"{where}: window_steps must be an integer in [1, {MAX_WINDOW_STEPS}], got {window!r}")
    if prefer not in PREFERENCES:
        raise ValueError(f"{where}: prefer must be one of {PREFERENCES}, got {prefer!r}")
    return {"risk": float(risk), "window_steps": int(window), "prefer": str(prefer)}


def shared_check_setting(risk: float, window_steps: int, prefer: str) -> dict | None:
    """A trainer's ``shared_check_risk``, ``shared_check_window_steps`` and ``shared_check_prefer`` (``--hp``;
    risk 0: no check) as the model's shared check, or None; a ValueError naming the setting otherwise."""
    if not (math.isfinite(risk) and 0 <= risk < 1):
        raise ValueError(f"hp: shared_check_risk must be a probability in [0, 1) (0: no check), got {risk}")
    value = {"risk": float(risk) or 0.5, "window_steps": window_steps, "prefer": prefer}
    try:
        check_shared_check(value, "hp")
    except ValueError as exc:
        raise ValueError(str(exc).replace("hp: ", "hp: shared_check_", 1)) from None
    return None if risk == 0 else value


# ---- the compiled rule ---------------------------------------------------------------------------------
@jit
def _block_sum(x, start, count):
    """numpy's sum of at most 128 entries: in order below 8, else 8 accumulators then the rest in order."""
    if count < 8:
        total = 0.0
        for i in range(start, start + count):
            total += x[i]
        return total
    r = x[start:start + 8].copy()
    i = 8
    while i < count - count % 8:
        for j in range(8):
            r[j] += x[start + i + j]
        i += 8
    total = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    for k in range(i, count):
        total += x[start + k]
    return total


@jit
def _pairwise_sum(x, start, count):
    """The sum of ``x[start:start + count]`` as numpy's ``sum`` adds it, bit for bit: blocks of at most 128,
    halves (a multiple of 8 first) added pairwise. Candidates whose total risks tie exactly (as where two
    emptyings leave the same containers waiting) then break the tie as the screen's first rule, written with
    numpy, did. Written without recursion, which numba's disk cache cannot hold."""
    if count <= 128:
        return _block_sum(x, start, count)
    starts, counts = np.empty(64, dtype=np.int64), np.empty(64, dtype=np.int64)
    stages, lefts = np.zeros(64, dtype=np.int64), np.empty(64)
    top, starts[0], counts[0], result = 0, start, count, 0.0
    while top >= 0:
        if counts[top] <= 128:  # a leaf: its sum goes to its parent
            result = _block_sum(x, starts[top], counts[top])
            top -= 1
            continue
        half = counts[top] // 2
        half -= half % 8
        if stages[top] == 0:  # the left half first
            stages[top] = 1
            starts[top + 1], counts[top + 1], stages[top + 1] = starts[top], half, 0
            top += 1
        elif stages[top] == 1:  # then the right half
            lefts[top], stages[top] = result, 2
            starts[top + 1], counts[top + 1], stages[top + 1] = starts[top] + half, counts[top] - half, 0
            top += 1
        else:
            result = lefts[top] + result
            top -= 1
    return result


@jit
def _lexicographic_less(a, b):
    for k in range(a.shape[0]):
        if a[k] != b[k]:
            return a[k] < b[k]
    return False


@jit
def _key_greater(log_odds_sum, kept, size, ranks, best_sum, best_kept, best_size, best_ranks, use_log_odds):
    """Whether a candidate's key (log-odds sum where used, emptyings kept, fewest, earlier-due members)
    is greater than the best's so far."""
    if use_log_odds and log_odds_sum != best_sum:
        return log_odds_sum > best_sum
    if kept != best_kept:
        return kept > best_kept
    if size != best_size:
        return size < best_size
    for k in range(size):
        if ranks[k] != best_ranks[k]:
            return ranks[k] < best_ranks[k]  # the earlier-due first (an index's rank in the due order)
    return False


@jit
def _safe_emptyings(volumes, timers, granted, risk, due, free, log_odds, use_log_odds, epsilon, params, out):
    """``out`` (n,): the safe emptyings the module doc's step 2 chooses (``granted`` unsafe)."""
    n = granted.shape[0]
    in_pool = np.zeros(n, dtype=np.bool_)
    for k in range(min(POOL, due.shape[0])):
        in_pool[due[k]] = True
    for i in range(n):
        in_pool[i] = in_pool[i] or granted[i]
    pool = np.flatnonzero(in_pool)
    p = pool.shape[0]
    # candidate sets as rows of member indices, padded with -1 (which sorts an index set after its prefixes)
    rows = 2 + min(free, due.shape[0]) + p + p * (p - 1) // 2
    sets = np.full((rows, max(free, 2)), -1, dtype=np.int64)
    count = 1  # row 0: no emptying
    members = np.flatnonzero(granted)
    if 0 < members.shape[0] <= free:
        sets[count, :members.shape[0]] = members
        count += 1
    for k in range(1, min(free, due.shape[0]) + 1):
        sets[count, :k] = np.sort(due[:k])
        count += 1
    for a in range(p):
        sets[count, 0] = pool[a]
        count += 1
    if free >= 2:
        for a in range(p):
            for b in range(a + 1, p):
                sets[count, 0], sets[count, 1] = pool[a], pool[b]
                count += 1
    sets = sets[:count, :free] if free >= 2 else sets[:count, :1]
    # in lexicographic order (as Python sorts tuples), each set once
    order = np.arange(count)
    for x in range(1, count):
        y = x
        while y > 0 and _lexicographic_less(sets[order[y]], sets[order[y - 1]]):
            order[y], order[y - 1] = order[y - 1], order[y]
            y -= 1
    rank = np.full(n, n, dtype=np.int64)
    for k in range(due.shape[0]):
        rank[due[k]] = k
    chosen = np.zeros(n, dtype=np.bool_)
    schedule = np.empty(n)
    free_at = np.empty(timers.shape[0], dtype=np.int64)
    ranks = np.empty(sets.shape[1], dtype=np.int64)
    best_ranks = np.empty(sets.shape[1], dtype=np.int64)
    member_log_odds = np.empty(sets.shape[1])
    found, best_row, best_sum, best_kept, best_size = False, -1, 0.0, 0, 0
    least_row, least_risk = -1, np.inf
    previous = -1
    for x in range(count):
        row = order[x]
        if previous >= 0 and not _lexicographic_less(sets[previous], sets[row]):
            continue  # the same set as the one before
        previous = row
        chosen[:] = False
        size, kept = 0, 0
        for k in range(sets.shape[1]):
            i = sets[row, k]
            if i < 0:
                break
            chosen[i] = True
            ranks[size] = rank[i]
            member_log_odds[size] = log_odds[i] if use_log_odds else 0.0
            size += 1
            kept += granted[i]
        log_odds_sum = _pairwise_sum(member_log_odds, 0, size)
        schedule_risk_into(volumes, timers, chosen, risk, due, params, False, free_at, schedule)
        total, worst = _pairwise_sum(schedule, 0, n), schedule.max()
        if worst <= epsilon and (not found or _key_greater(log_odds_sum, kept, size, ranks, best_sum, best_kept,
                                                           best_size, best_ranks, use_log_odds)):
            found, best_row, best_sum, best_kept, best_size = True, row, log_odds_sum, kept, size
            best_ranks[:size] = ranks[:size]
        if total < least_risk:
            least_row, least_risk = row, total
    out[:] = False
    pick = best_row if found else least_row
    for k in range(sets.shape[1]):
        if sets[pick, k] >= 0:
            out[sets[pick, k]] = True


@jit
def _due_now(volume, fill_mean, fill_std, max_volume, window, epsilon):
    """False only where the container cannot be due in the window: its waiting risk P(W), a sum of W terms
    that grow with the fills (safety's union bound), is at most W times the last term, here below ε / 2."""
    gap = max_volume - volume - window * fill_mean
    if fill_std > 0.0:
        last = 0.5 * math.erfc(gap / (fill_std * math.sqrt(2.0 * window)))
    else:
        last = 1.0 if gap <= 0.0 else 0.0
    return window * last > 0.5 * epsilon


@jit
def _shared_check(observations, volume_column, timer_columns, requests, log_odds, use_log_odds, epsilon, window,
                  deadline_check, per_container, reward_table, scalars, granted, changed):
    """Every simulation b's emptyings after the module doc's rule into ``granted`` (B, n): from the agents'
    ``observations`` (B·n, F; the messages: ``volume_frac`` at ``volume_column``, the PU timers at
    ``timer_columns``), ``requests`` (B·n,) and ``log_odds`` (B·n,); ``changed[b]``: the check replaced
    the granted emptyings (``deadline_check`` False: step 1 alone)."""
    params = unpack_params(per_container, reward_table, scalars)
    n, m = params.n_containers, params.n_pus
    volumes, timers = np.empty(n), np.empty(m)
    priorities = np.empty((1, n))
    one_request = np.empty((1, n), dtype=np.bool_)
    one_granted = np.empty((1, n), dtype=np.bool_)
    risk = np.empty((n, window))
    safe = np.empty(n, dtype=np.bool_)
    schedule = np.empty(n)
    free_at = np.empty(m, dtype=np.int64)
    deadline = np.empty(n, dtype=np.int64)
    due = np.empty(n, dtype=np.int64)
    for b in range(granted.shape[0]):
        changed[b] = False
        free = 0
        for j in range(m):  # every agent observes the PU timers
            timers[j] = np.float64(observations[b * n, timer_columns[j]]) * params.max_pu_time_s
            free += timers[j] == 0.0
        for i in range(n):  # the messages
            volumes[i] = np.float64(observations[b * n + i, volume_column]) * params.max_volume[i]
            one_request[0, i] = requests[b * n + i] != 0
            priorities[0, i] = fullest_first(i, volumes[i], 0.0, params)
        grant_requests(one_request, priorities, 0, free, one_granted)
        granted[b] = one_granted[0]
        if free == 0 or not deadline_check:
            continue
        n_due = 0
        for i in range(n):  # safety.deadlines, and the due containers earliest deadline first (riskier first)
            if not _due_now(volumes[i], params.fill_mean_per_step[i], params.fill_std_per_step[i],
                            params.max_volume[i], window, epsilon):
                continue  # not due: its row of the risks is never read
            _waiting_risk(volumes[i:i + 1], params.fill_mean_per_step[i:i + 1], params.fill_std_per_step[i:i + 1],
                          params.max_volume[i:i + 1], window, risk[i:i + 1])
            deadline[i] = 0
            for k in range(window):
                deadline[i] += risk[i, k] <= epsilon
            if deadline[i] < window:
                y = n_due
                while y > 0 and (deadline[due[y - 1]] > deadline[i] or (
                        deadline[due[y - 1]] == deadline[i] and risk[due[y - 1], window - 1] < risk[i, window - 1])):
                    due[y] = due[y - 1]
                    y -= 1
                due[y] = i
                n_due += 1
        if n_due == 0:
            continue
        schedule_risk_into(volumes, timers, granted[b], risk, due[:n_due], params, False, free_at, schedule)
        if schedule.max() <= epsilon:
            continue
        _safe_emptyings(volumes, timers, granted[b], risk, due[:n_due], free, log_odds[b * n:(b + 1) * n],
                        use_log_odds, epsilon, params, safe)
        for i in range(n):
            changed[b] = changed[b] or safe[i] != granted[b, i]
            granted[b, i] = safe[i]


class SharedCheck:
    """A model's shared check (``setting``, :func:`check_shared_check`) bound to a plant: the emptyings its
    container agents request after the rule (the module doc), from their observations in variant
    ``observation``. ``arbitration``: the plant's rule, which the check predicts; only the default one.
    ``deadline_check=False``: the withdrawal of denied requests alone (step 1; a screen's ablation)."""

    def __init__(self, setting: dict, params: PlantParams, observation: str, arbitration: str = DEFAULT_ARBITRATION,
                 deadline_check: bool = True):
        setting = check_shared_check(setting)
        if setting is None:
            raise ValueError("shared_check: expected a setting, got None")
        if arbitration != DEFAULT_ARBITRATION:
            raise ValueError(f"arbitration: the shared check predicts the plant's {DEFAULT_ARBITRATION!r} arbitration; "
                             f"got {arbitration!r}")
        names = agent_feature_names(params, observation)
        timers = [f"pu_timer_frac[{j}]" for j in range(params.n_pus)]
        if not set(timers) <= set(names):
            raise ValueError(f"observation: the shared check reads every PU's timer, which the {observation!r} "
                             "observation does not hold")
        self.setting, self.params, self.observation, self.arbitration = setting, params, observation, arbitration
        self.deadline_check = bool(deadline_check)
        self.uses_log_odds = setting["prefer"] == "policy" and self.deadline_check  # only the check chooses
        self._columns = (names.index("volume_frac"), np.array([names.index(t) for t in timers], dtype=np.int64))
        self._storage = params.kernel_arrays()
        self._no_log_odds = np.zeros(0)
        self._out: tuple[np.ndarray, np.ndarray] | None = None

    def __call__(self, observations: np.ndarray, requests: np.ndarray, log_odds: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
        """(granted (B, n) bool, changed (B,) bool) for the agents' ``observations`` (B·n, F), their
        ``requests`` (B·n,) and, with ``prefer="policy"``, their log-odds of requesting (B·n,). The
        arrays returned are reused by the next call."""
        n = self.params.n_containers
        if observations.ndim != 2 or observations.shape[0] % n or requests.shape != observations.shape[:1]:
            raise ValueError(f"observations, requests: expected (B·{n}, F) and (B·{n},), got {observations.shape} "
                             f"and {requests.shape}")
        if self.uses_log_odds and (log_odds is None or log_odds.shape != requests.shape):
            raise ValueError("log_odds: the shared check with prefer='policy' needs every agent's log-odds, got "
                             f"{None if log_odds is None else log_odds.shape}")
        sims = observations.shape[0] // n
        if self._out is None or self._out[1].shape[0] != sims:
            self._out = np.empty((sims, n), dtype=np.bool_), np.empty(sims, dtype=np.bool_)
        granted, changed = self._out
        _shared_check(observations, *self._columns, requests, log_odds if self.uses_log_odds else self._no_log_odds,
                      self.uses_log_odds, self.setting["risk"], self.setting["window_steps"], self.deadline_check,
                      *self._storage, granted, changed)
        return granted, changed

    def requests_after(self, observations: np.ndarray, requests: np.ndarray, logits) -> np.ndarray:
        """(B·n,) int64: the agents' ``requests`` after the rule, the log-odds (where the rule uses them) taken
        from the network's decision ``logits`` (a (B·n, 2) tensor): what a policy carrying the rule does."""
        log_odds = (logits[:, 1] - logits[:, 0]).double().numpy() if self.uses_log_odds else None
        return self(observations, requests, log_odds)[0].reshape(-1).astype(np.int64)


__all__ = ["MAX_WINDOW_STEPS", "PREFERENCES", "SHARED_CHECK", "SharedCheck", "check_shared_check",
           "shared_check_setting"]
