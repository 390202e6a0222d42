"""A deadline check for the rollout planner: can every container still be emptied in time?

The planner's look-ahead estimates the overflow risk of a candidate from K = 16 sampled futures.
Near an overflow that estimate is noisy: the risk is carried by the few futures whose fills run high
for several steps in a row, so 16 futures can see 0.3 % where the true risk is 5 % (validation
episode 20072 of ``n16_m2``, container agents, step 480: the planner gave the last free PU to a
container at its optimum for 12 steps while a container 5 units below v_max had to wait 4 steps for
the other PU; it overflowed). Widening to more futures helps only where the values are close, and a
longer horizon makes the return worse. This check needs no sampling: it computes, for each
container, how many more fills it can take before its overflow probability exceeds ε, and asks
whether the PUs can reach every container before that deadline.

**Overflow probability of waiting.** A container at volume v that is emptied after s more fills
(fills are independent N(μδ, σ²δ) steps) overflows with probability at most

    P(s) = Σ_{k=1..s} P(v + kμδ + √k·σ√δ·Z >= v_max)      (Z standard normal)

(the union bound over the k steps, each term the marginal of the k-step fill; the floor of volumes at
0 does not matter near v_max). P grows with s; the container's *deadline* d is the largest s <= W
with P(s) <= ε: it can wait d fills, not more. W (``safety_horizon_steps``) bounds the window
looked at: a container with P(W) <= ε needs no emptying within it and is left out.

**Can the PUs meet the deadlines?** A candidate decision (the emptyings of this step) sets the PU
timers of the next state: a PU taken now is busy g_i(v_i) (paper eq. 2), the others count down by δ.
A PU whose timer is q at the next state is free from ``1 + ceil(q / δ)`` steps on (counted from the
decision's step). The containers with a deadline in the window are served *earliest deadline first*
(EDF), each on the PU that frees first, as soon as it frees (in the centralised view, whose action
empties one container, at most one a step), and that PU is then busy
g_i(v + sμδ) (the expected volume then, at most v_max) from that step. Emptying as early as possible
is what makes a deadline easiest to meet (g grows with the volume); EDF (Jackson's rule) is the
order that minimises the largest lateness on one machine, and a good list order on m. Container i
then waits s_i fills and its *schedule risk* is P_i(s_i); the candidate is *safe* if no container's
schedule risk exceeds ε.

**The shield.** With ``safety_risk`` = ε set, the planner takes its look-ahead decision as before when
it is safe. If it is not, it takes the best-valued safe candidate, after adding to the candidates
every container with a deadline in the window (so that a container too far from its optimum to be
eligible can still be emptied early); if no candidate is safe, the one of least total schedule risk.
The check thus keeps, at every step with a free PU, the invariant that some continuation empties
every container before its risk passes ε; it departs from the look-ahead only where the look-ahead
would break it, so the return elsewhere is unchanged. It ignores refills within the window
(emptied containers take tens of steps to fill again) and containers that fall due after the window.

Cost: n·W normal tails per decision, and per candidate an EDF pass over the containers due in the
window (a few per step on the contended plants): well under a millisecond.
"""

from __future__ import annotations

import math

import numpy as np

from containergym_marl.config.bounds import MAX_OWN_CHECK_LEAD_STEPS
from containergym_marl.config.pu_time import jit
from containergym_marl.core.dynamics import pu_busy_time_s
from containergym_marl.core.observations import SCALAR_FEATURES
from containergym_marl.core.params import PlantParams

#: The version at which each view's shielded decisions last changed: results of that version or later stand.
DECISIONS_CHANGED = {"planner": 2, "planner_agents": 3}
#: The check's version, for results kept across changes of its decisions. 1: the centralised view's
#: schedule could start two emptyings in one step (it empties at most one); 2: one a step there; 3: the
#: container agents' shield also weighs every set of due containers (it weighed only sets holding the
#: look-ahead's choice, all of them unsafe where another set was safe).
CHECK_VERSION = max(DECISIONS_CHANGED.values())


@jit
def _waiting_risk(volumes, fill_mean, fill_std, max_volume, horizon_steps, out):
    for i in range(volumes.shape[0]):
        total = 0.0
        for k in range(1, horizon_steps + 1):
            gap = max_volume[i] - volumes[i] - k * fill_mean[i]
            if fill_std[i] > 0.0:
                total += 0.5 * math.erfc(gap / (fill_std[i] * math.sqrt(2.0 * k)))
            elif gap <= 0.0:
                total += 1.0
            out[i, k - 1] = min(total, 1.0)


def waiting_risk(volumes: np.ndarray, params: PlantParams, horizon_steps: int) -> np.ndarray:
    """(n, W) P_i(s) for s = 1..W: the probability (union bound) that container i, at ``volumes`` (n,)
    before this step's fill, reaches v_max within its next s fills if it is not emptied."""
    volumes = np.ascontiguousarray(volumes, dtype=np.float64)
    if volumes.shape != (params.n_containers,):
        raise ValueError(f"volumes: expected shape ({params.n_containers},), got {volumes.shape}")
    out = np.empty((params.n_containers, int(horizon_steps)))
    _waiting_risk(volumes, np.asarray(params.fill_mean_per_step), np.asarray(params.fill_std_per_step),
                  np.asarray(params.max_volume), int(horizon_steps), out)
    return out


def deadlines(risk: np.ndarray, epsilon: float) -> np.ndarray:
    """(n,) int: the fills each container can wait with a waiting risk <= ``epsilon`` (0 .. W; W: no
    deadline within the window), from ``risk`` (n, W) of :func:`waiting_risk`."""
    return (risk <= epsilon).sum(axis=1)  # P(s) grows with s: the fills that keep it <= ε come first


@jit
def busy_steps(i, volume, params):
    """Steps a PU stays busy after emptying container i at ``volume`` (at most v_max): free
    ``1 + ceil(g / δ)`` steps after the emptying's step."""
    g = pu_busy_time_s(i, min(volume, params.max_volume[i]), params)
    return 1 + math.ceil(g / params.timestep_s - 1e-9)


@jit
def schedule_risk_into(volumes, pu_timers_s, emptied, risk, due, params, one_per_step, free_at, out):
    """:meth:`DeadlineCheck.schedule_risk` into ``out`` (n,), compiled (``free_at``: (m,) int scratch).
    ``emptied`` may hold at most as many containers as PUs are free (the caller checks)."""
    dt, window = params.timestep_s, risk.shape[1]
    # the step (from this one) from which each PU is free: the emptied containers, in index order, take the
    # free PUs in index order (as the plant does) and busy them g(v); every other PU counts down
    member = 0
    for j in range(pu_timers_s.shape[0]):
        while member < emptied.shape[0] and not emptied[member]:
            member += 1
        if pu_timers_s[j] == 0.0 and member < emptied.shape[0]:
            free_at[j] = busy_steps(member, volumes[member], params)
            member += 1
        else:
            free_at[j] = 1 + math.ceil(max(pu_timers_s[j] - dt, 0.0) / dt - 1e-9)
    out[:] = 0.0
    last_start = 0  # this step's emptying, if any: the schedule's first start is a later step
    for i in due:
        if emptied[i]:
            continue
        j = 0
        for k in range(1, free_at.shape[0]):
            if free_at[k] < free_at[j]:
                j = k
        start = free_at[j]  # fills container i waits (the starts never decrease: list scheduling, EDF)
        if one_per_step:
            start = max(start, last_start + 1)
        last_start = start
        out[i] = risk[i, min(start, window) - 1]
        free_at[j] = start + busy_steps(i, volumes[i] + start * params.fill_mean_per_step[i], params)


class DeadlineCheck:
    """The schedule risks of a step's candidates, from one state (see the module doc).

    Args:
        volumes: (n,) volumes before this step.
        pu_timers_s: (m,) PU timers before this step (seconds).
        params: the plant.
        epsilon: ε, the largest overflow probability a container may be left with (per container).
        horizon_steps: W, the window of the check (steps).
        one_per_step: the schedule starts at most one emptying a step (the centralised view's action
            empties one container): two PUs free at the same step serve their containers a step apart.
    """

    def __init__(self, volumes: np.ndarray, pu_timers_s: np.ndarray, params: PlantParams, epsilon: float,
                 horizon_steps: int, one_per_step: bool = False):
        self.params, self.epsilon, self.horizon_steps = params, float(epsilon), int(horizon_steps)
        self.one_per_step = bool(one_per_step)
        self.volumes = np.asarray(volumes, dtype=np.float64)
        self.pu_timers_s = np.asarray(pu_timers_s, dtype=np.float64)
        self.risk = waiting_risk(self.volumes, params, self.horizon_steps)  # (n, W)
        self.deadline = deadlines(self.risk, self.epsilon)
        #: containers that must be emptied within the window, earliest deadline first (ties: riskier first)
        due = np.flatnonzero(self.deadline < self.horizon_steps)
        self.due = due[np.lexsort((-self.risk[due, -1], self.deadline[due]))]

    def schedule_risk(self, emptied: np.ndarray) -> np.ndarray:
        """(n,) each container's waiting risk P_i(s_i) under the EDF schedule after this step empties
        ``emptied`` (n,) bool (every emptying granted); 0 for containers emptied now or not due in
        the window."""
        emptied = np.asarray(emptied, dtype=bool)
        free = int((self.pu_timers_s == 0.0).sum())
        if int(emptied.sum()) > free:
            raise ValueError(f"emptied: {int(emptied.sum())} emptyings but only {free} free PU(s)")
        out = np.empty(self.params.n_containers)
        schedule_risk_into(self.volumes, self.pu_timers_s, emptied, self.risk, self.due, self.params,
                           self.one_per_step, np.empty(self.params.n_pus, dtype=np.int64), out)
        return out

    def safe(self, emptied: np.ndarray) -> bool:
        return bool(self.schedule_risk(emptied).max(initial=0.0) <= self.epsilon)


# ---- a container agent's own check --------------------------------------------------------------------
#: The entries of a container agent's observation (every variant) that its own check reads.
_OWN = tuple(SCALAR_FEATURES.index(name) for name in
             ("volume_frac", "fill_rate_frac", "fill_noise_frac", "free_pu_frac"))
_OWN_COLUMNS = np.asarray(_OWN, dtype=np.int64)


@jit
def _own_due(observations, columns, risk, fills, out):
    volume, rate, noise, free = columns
    for i in range(observations.shape[0]):
        total = 0.0
        for k in range(1, fills + 1):  # the union bound above, in units of the container's v_max
            gap = 1.0 - observations[i, volume] - k * observations[i, rate]
            if observations[i, noise] > 0.0:
                total += 0.5 * math.erfc(gap / (observations[i, noise] * math.sqrt(2.0 * k)))
            elif gap <= 0.0:
                total += 1.0
        out[i] = total > risk and observations[i, free] > 0.0


def own_deadline_due(observations: np.ndarray, risk: float, lead_steps: int) -> np.ndarray:
    """(N,) bool: the container agents that must ask now by their own check: a PU is free and, by the
    agent's own observation alone, its container overflows within ``lead_steps`` + 1 more fills with
    probability (the union bound above) above ``risk`` unless emptied now, i.e. its deadline is at
    most ``lead_steps`` fills. It reads ``volume_frac`` (v / v_max), ``fill_rate_frac`` (μδ / v_max),
    ``fill_noise_frac`` (σ√δ / v_max) and ``free_pu_frac``, entries of every observation variant, so
    it needs nothing an agent does not see: a safety layer a decentralised policy can carry."""
    obs = np.ascontiguousarray(observations, dtype=np.float64)
    if obs.ndim != 2 or obs.shape[1] < len(SCALAR_FEATURES):
        raise ValueError(f"observations: expected (N, F >= {len(SCALAR_FEATURES)}) container-agent observations, "
                         f"got shape {obs.shape}")
    out = np.empty(obs.shape[0], dtype=np.bool_)
    _own_due(obs, _OWN_COLUMNS, float(risk), int(lead_steps) + 1, out)
    return out


def check_own_check(value, where: str = "own_check") -> dict | None:
    """``value`` as a learned policy's own check, ``{"risk": ε, "lead_steps": L}`` (ε in (0, 1), L an
    integer in [0, MAX_OWN_CHECK_LEAD_STEPS]), or None; a ValueError naming ``where`` otherwise."""
    if value is None:
        return None
    if not isinstance(value, dict) or set(value) != {"risk", "lead_steps"}:
        raise ValueError(f"{where}: expected None or {{'risk': ε, 'lead_steps': L}}, got {value!r}")
    risk, lead = value["risk"], value["lead_steps"]
    if isinstance(risk, bool) or not isinstance(risk, (int, float)) or not (math.isfinite(risk) and 0 < risk < 1):
        raise ValueError(f"{where}: risk must be a probability in (0, 1), got {risk!r}")
    if isinstance(lead, bool) or not isinstance(lead, (int, np.integer)) or not 0 <= lead <= MAX_OWN_CHECK_LEAD_STEPS:
        raise ValueError(f"{where}: lead_steps must be an integer in [0, {MAX_OWN_CHECK_LEAD_STEPS}], got {lead!r}")
    return {"risk": float(risk), "lead_steps": int(lead)}


#: The agents' own check as ``fast_shared_ppo_checked`` and the tuning study's ``--own-check`` use it: the
#: setting that removed most of the published policies' overflows at the least cost in return on
#: validation episodes (``studies/own_check_screen.py``).
OWN_CHECK_RISK, OWN_CHECK_LEAD_STEPS = 1e-4, 1


def own_check_setting(risk: float, lead_steps: int) -> dict | None:
    """A trainer's ``own_check_risk`` and ``own_check_lead_steps`` (``--hp``; risk 0: no check) as the
    model's own check, or None; a ValueError naming the setting when one is out of its range."""
    if not (math.isfinite(risk) and 0 <= risk < 1):
        raise ValueError(f"hp: own_check_risk must be a probability in [0, 1) (0: no check), got {risk}")
    if not 0 <= lead_steps <= MAX_OWN_CHECK_LEAD_STEPS:
        raise ValueError(f"hp: own_check_lead_steps must be in [0, {MAX_OWN_CHECK_LEAD_STEPS}], got {lead_steps}")
    return None if risk == 0 else {"risk": float(risk), "lead_steps": int(lead_steps)}
