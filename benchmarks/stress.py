"""Stress test: many random and adversarial steps through the core and every view, with every
invariant checked at every step.

    python benchmarks/stress.py                      # the full run (≥ 10⁷ core steps per config)
    python benchmarks/stress.py --smoke              # seconds; run by the default tests
    python benchmarks/stress.py --core-steps 1e6 --view-steps 1e5 --configs n5_m2_dt120 --json out.json

**Core** (per built-in config, ``--core-steps`` simulation steps, split evenly over the four
arbitration rules): a batched :class:`~containergym_marl.core.PlantSimulator` of ``--batch``
simulations, finished simulations reset in place. Each simulation draws its own request pattern
every step (random at 5 %, 30 % or 70 %; all; none; one container; everything while no PU is
free; every container below one product), and every fifth step a sixteenth of the simulations is
put into an extreme but valid state (volumes 0, 5e-324, a reward peak, just below v_max, v_max −
μδ; timers 0, 5e-324, δ and its float neighbours, the longest PU time; step counts 0, T − 2,
T − 1). Checked against the previous state, every step, for every simulation:

* requested = the requests; granted ⊆ requested; denied = requested − granted;
* grants = min(requests, free PUs) ≤ m; free PUs reported = PUs whose timer is 0;
* each granted container took a distinct PU that was free; pu_index −1 elsewhere;
* deterministic rules: no denied request outranks a granted one;
* emptied volume = v where granted, else 0;
* container reward = the paper's eq. 5 (recomputed here from the config) where granted, r_pen
  where denied, 0 otherwise; individual rewards in [r_min, 1] and = r_min where overflowed;
* volumes finite and ≥ 0, 0 where emptied; noiseless containers fill by exactly μδ; the others'
  standardised inflow z = (v' − v − μδ)/(σ√δ) is finite, |z| < 9, and (where no censoring at 0
  is possible) has mean ≈ 0 and variance ≈ 1 over the run;
* timers in [0, max PU time]: g(v) = β + λ⌊v/b⌋ on the granted PU, max(0, p − δ) elsewhere;
* overflowed = v' ≥ v_max; terminated iff an overflow; truncated iff T reached without one;
  step count + 1;
* plant reward = r_min on overflow, else the sum of the container rewards, hence within
  [requests · r_pen, grants · 1].

**Views** (``--view-steps`` plant steps per view, split over the configs): the centralised env,
the PettingZoo parallel and AEC envs (each config cycles through the four arbitration rules, both
reward modes, box and dict observations), the SB3 vector envs of both views and the Gymnasium
vector env (``--vec-batch`` simulations). Checked every step: observations (and ``state()``,
terminal and final observations) inside their spaces, with the right dtype and shape; rewards in
[r_min, 1] per container, the team reward = r_min on overflow else the sum of the step's emptying
rewards, equal for all agents; granted ⊆ requested, denied = requested − granted, at most
min(m, free PUs) grants on distinct PUs; emptying rewards = eq. 5 of the emptied volume;
terminated iff an overflow (some volume ≥ v_max), truncated iff the T-th step without one; info
keys and value types the same at every step and reset; action masks = PU availability. One step
in a hundred first tries an invalid action (out of range, float, NaN, None, bool, string, arrays
of floats), which must be refused with the state and random stream unchanged; one in two hundred
starts from an injected extreme state.

Prints a Markdown summary (steps, time, invariants, violations); ``--json`` writes the figures.
Exits 1 if any invariant was violated.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import platform
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from containergym_marl.config import PlantConfig, list_configs, load_config  # noqa: E402
from containergym_marl.core import PlantSimulator, PlantState  # noqa: E402
from containergym_marl.core.dynamics import ARBITRATION_RULES  # noqa: E402

RULES = tuple(ARBITRATION_RULES)
FULL = {"core_steps": 10**7, "view_steps": 10**6, "batch": 1024, "vec_batch": 64}
SMOKE = {"core_steps": 8192, "view_steps": 450, "batch": 256, "vec_batch": 8}
Z_LIMIT = 9.0  # |z| of one normal draw: P(|z| > 9) ≈ 2e-19
TOL = 1e-9


# ---- bookkeeping --------------------------------------------------------------------------------
@dataclass
class Checker:
    """Counts invariant evaluations and records violations (the first few in detail)."""

    evaluations: int = 0
    violations: int = 0
    names: set = field(default_factory=set)
    examples: list = field(default_factory=list)
    where: str = ""
    episode_ends: int = 0  # episodes that ended (overflow or T) and were reset

    def __call__(self, name: str, ok, count: int = 1, detail=None) -> bool:
        self.names.add(name)
        self.evaluations += count
        if ok is not True and (ok is False or not bool(np.all(ok))):
            self.violations += 1
            if len(self.examples) < 25:
                self.examples.append(f"{self.where}: {name}" + (f" ({detail})" if detail is not None else ""))
            return False
        return True


class Reward:
    """The paper's emptying reward (eq. 5), computed here from the config's per-container fields,
    independently of the core's PlantParams and compiled function."""

    def __init__(self, cfg: PlantConfig):
        n = cfg.n_containers
        k = max(len(c.reward_peaks) for c in cfg.containers)
        self.r_pen = cfg.penalty_reward
        self.peak = np.zeros((n, k))
        self.coef = np.zeros((n, k))
        self.width = np.ones((n, k))
        for i, c in enumerate(cfg.containers):
            p = len(c.reward_peaks)
            self.peak[i, :p] = c.reward_peaks
            self.coef[i, :p] = np.array(c.reward_heights) - cfg.penalty_reward
            self.width[i, :p] = c.reward_widths

    def __call__(self, volumes: np.ndarray) -> np.ndarray:
        """(..., n) rewards of emptying at (..., n) volumes."""
        d = volumes[..., None] - self.peak
        r = self.r_pen + (self.coef * np.exp(-(d * d) / (2.0 * self.width**2))).sum(-1)
        return np.where(volumes == 0.0, self.r_pen, r)

    def cells(self, volumes: np.ndarray, containers: np.ndarray) -> np.ndarray:
        """Rewards of emptying ``containers[k]`` at ``volumes[k]`` (1-D arrays)."""
        d = volumes[:, None] - self.peak[containers]
        r = self.r_pen + (self.coef[containers] * np.exp(-(d * d) / (2.0 * self.width[containers] ** 2))).sum(-1)
        return np.where(volumes == 0.0, self.r_pen, r)

    def one(self, i: int, volume: float) -> float:
        if volume == 0.0:
            return self.r_pen
        d = volume - self.peak[i]
        return float(self.r_pen + (self.coef[i] * np.exp(-(d * d) / (2.0 * self.width[i] ** 2))).sum())


class Plant:
    """Per-config constants read from the config (not from the core)."""

    def __init__(self, cfg: PlantConfig):
        self.cfg = cfg
        self.n, self.m = cfg.n_containers, cfg.num_processing_units
        self.dt, self.T = cfg.timestep_s, cfg.episode_length_steps
        self.r_min, self.r_pen = cfg.overflow_reward, cfg.penalty_reward
        col = lambda a: np.array([getattr(c, a) for c in cfg.containers], dtype=np.float64)  # noqa: E731
        self.vmax, self.b = col("max_volume"), col("product_size")
        self.beta, self.lam = col("pu_offset_s"), col("pu_time_per_product_s")
        self.mu_dt = col("fill_rate_per_s") * self.dt
        self.sd = col("fill_noise_per_sqrt_s") * math.sqrt(self.dt)
        self.max_pu = float(np.max(self.beta + self.lam * np.floor(self.vmax / self.b)))
        self.reward = Reward(cfg)
        self.peaks = [np.array(c.reward_peaks) for c in cfg.containers]
        self.names = cfg.container_names


def extreme_states(plant: Plant, rng: np.random.Generator, rows: int):
    """``rows`` extreme but valid states: volumes, timers, step counts."""
    n, m, dt = plant.n, plant.m, plant.dt
    vmax = plant.vmax
    below = np.nextafter(vmax, 0.0)
    peak = np.array([rng.choice(p) for p in plant.peaks])
    edge = np.maximum(vmax - plant.mu_dt, 0.0)
    vol_choices = np.stack(np.broadcast_arrays(0.0, 5e-324, below, vmax * (1 - 1e-12), peak, edge,
                                               np.minimum(plant.cfg.initial_volume_max, below),
                                               vmax * 0.999))  # (8, n)
    k = rng.integers(0, vol_choices.shape[0] + 2, (rows, n))
    uniform = rng.random((rows, n)) * vmax
    volumes = np.where(k < vol_choices.shape[0],
                       vol_choices[np.minimum(k, vol_choices.shape[0] - 1), np.arange(n)], uniform)
    timer_choices = np.array([0.0, 5e-324, dt, np.nextafter(dt, 0.0), np.nextafter(dt, np.inf),
                              plant.max_pu, 0.0])
    j = rng.integers(0, timer_choices.size + 2, (rows, m))
    timers = np.where(j < timer_choices.size, timer_choices[np.minimum(j, timer_choices.size - 1)],
                      rng.random((rows, m)) * plant.max_pu)
    counts = rng.choice(np.array([0, max(plant.T - 2, 0), plant.T - 1, rng.integers(0, plant.T)]), rows)
    return volumes, np.minimum(timers, plant.max_pu), counts.astype(np.int64)


def _sim_snapshot(sim: PlantSimulator):
    st = sim.state
    gens = [copy.deepcopy(sim.generator(i).bit_generator.state) for i in range(min(sim.num_sims, 4))]
    return (st.volumes.copy(), st.pu_timers_s.copy(), st.step_count.copy(), sim.previous_requests.copy(),
            sim._streams._cursor.copy(), gens)


def _same_snapshot(a, b) -> bool:
    for x, y in zip(a, b):
        if isinstance(x, np.ndarray):
            if not np.array_equal(x, y):
                return False
        elif x != y:
            return False
    return True


# ---- the core ----------------------------------------------------------------------------------
@dataclass
class ZStats:
    count: int = 0
    total: float = 0.0
    total_sq: float = 0.0

    def add(self, z: np.ndarray) -> None:
        self.count += z.size
        self.total += float(z.sum())
        self.total_sq += float((z * z).sum())


def _requests(plant: Plant, rng, v: np.ndarray, free: np.ndarray) -> np.ndarray:
    bsz, n = v.shape
    pattern = rng.integers(0, 8, bsz)
    threshold = np.array([0.05, 0.3, 0.7, 1.01, 0.0, 0.0, 0.0, 0.0])[pattern]
    req = rng.random((bsz, n)) < threshold[:, None]
    one = np.flatnonzero(pattern == 5)
    req[one, rng.integers(0, n, one.size)] = True
    busy = (pattern == 6) & (free == 0)
    req[busy] = True
    cheap = pattern == 7
    req[cheap] = v[cheap] < plant.b
    return req


def stress_core(plant: Plant, rule: str, steps: int, batch: int, seed: int, chk: Checker,
                z: ZStats) -> int:
    """``steps`` simulation steps (rounded up to whole batches) with one arbitration rule."""
    n, m = plant.n, plant.m
    sim = PlantSimulator(plant.cfg, num_sims=batch, arbitration=rule)
    rng = np.random.default_rng([seed, 1])
    sim.reset(generators=[np.random.default_rng(s) for s in np.random.SeedSequence([seed, 2]).spawn(batch)])
    calls = -(-steps // batch)
    cols = np.arange(n)
    deterministic = rule != "random"
    for t in range(calls):
        if t % 5 == 4:
            rows = rng.choice(batch, max(batch // 16, 1), replace=False)
            vol, tim, cnt = extreme_states(plant, rng, rows.size)
            st = sim.state
            v_, p_, c_ = st.volumes.copy(), st.pu_timers_s.copy(), st.step_count.copy()
            v_[rows], p_[rows], c_[rows] = vol, tim, cnt
            sim.state = PlantState(v_, p_, c_)
        v, p, c = sim.state
        free = (p == 0.0).sum(1)
        req = _requests(plant, rng, v, free)
        out = sim.step(req)
        v2, p2, c2 = sim.state
        g, d = out.granted, out.denied
        nreq, ngr = req.sum(1), g.sum(1)

        chk("requested = requests", np.array_equal(out.requested, req), batch)
        chk("granted ⊆ requested", not (g & ~req).any(), batch)
        chk("denied = requested − granted", np.array_equal(d, req & ~g), batch)
        chk("free PUs reported = timers at 0", np.array_equal(out.free_pus_before, free), batch)
        chk("grants = min(requests, free PUs) ≤ m",
            np.array_equal(ngr, np.minimum(nreq, free)) and bool((ngr <= m).all()), batch)
        r_idx, c_idx = np.nonzero(g)
        pus = out.pu_index[r_idx, c_idx]
        chk("pu_index −1 iff not granted", bool((out.pu_index[~g] == -1).all()), batch)
        ok_pus = bool(((pus >= 0) & (pus < m)).all())
        chk("granted PUs exist", ok_pus, batch)
        if ok_pus:
            chk("granted PUs were free", bool((p[r_idx, pus] == 0.0).all()), batch)
            chk("granted PUs distinct", np.unique(r_idx * m + pus).size == pus.size, batch)
        if deterministic:
            contested = nreq > free
            if contested.any():
                vv = v[contested]
                if rule == "fullest":
                    pr = vv / plant.vmax
                elif rule == "index":
                    pr = np.broadcast_to(-cols.astype(float), vv.shape)
                else:
                    pr = plant.reward(vv)
                gg, dd = g[contested], d[contested]
                lowest_granted = np.where(gg, pr, np.inf).min(1)
                highest_denied = np.where(dd, pr, -np.inf).max(1)
                chk(f"arbitration order ({rule})", bool((lowest_granted >= highest_denied - 1e-12).all()),
                    int(contested.sum()))
        chk("emptied volume", np.array_equal(out.emptied_volume, np.where(g, v, 0.0)), batch)
        expected = np.where(d, plant.r_pen, 0.0)
        expected[r_idx, c_idx] = plant.reward.cells(v[r_idx, c_idx], c_idx)
        chk("container reward = eq. 5 / r_pen / 0",
            np.allclose(out.container_reward, expected, rtol=1e-12, atol=1e-12), batch,
            detail=float(np.abs(out.container_reward - expected).max()))
        # next state
        chk("volumes finite and ≥ 0", bool(np.isfinite(v2).all() and (v2 >= 0).all()), batch)
        chk("emptied volumes are 0", bool((v2[g] == 0.0).all()), batch)
        fill = ~g
        quiet = fill & (plant.sd == 0.0)
        if quiet.any():
            chk("noiseless fill = μδ", np.array_equal(v2[quiet], np.maximum(v + plant.mu_dt, 0.0)[quiet]),
                int(quiet.sum()))
        noisy = fill & (plant.sd > 0.0)
        sd = np.broadcast_to(plant.sd, v.shape)
        mean = v + plant.mu_dt
        positive = noisy & (v2 > 0.0)
        zz = (v2[positive] - mean[positive]) / sd[positive]
        chk("fill noise: z finite, |z| < 9", bool(np.isfinite(zz).all() and (np.abs(zz) < Z_LIMIT).all()), batch)
        censored = noisy & (v2 == 0.0)
        chk("fill floored at 0 only when plausible", bool((mean[censored] - Z_LIMIT * sd[censored] <= 0).all()),
            batch)
        deep = noisy & (mean - Z_LIMIT * sd > 0.0)
        z.add((v2[deep] - mean[deep]) / sd[deep])
        expected_p = np.maximum(p - plant.dt, 0.0)
        if ok_pus:
            expected_p[r_idx, pus] = plant.beta[c_idx] + plant.lam[c_idx] * np.floor(v[r_idx, c_idx] / plant.b[c_idx])
        chk("timers: g(v) on granted PUs, max(0, p − δ) elsewhere", np.array_equal(p2, expected_p), batch)
        chk("timers in [0, max PU time]", bool((p2 >= 0).all() and (p2 <= plant.max_pu).all()), batch)
        overflow = v2 >= plant.vmax
        term = overflow.any(1)
        chk("overflowed = v' ≥ v_max", np.array_equal(out.overflowed, overflow), batch)
        chk("terminated iff overflow", np.array_equal(out.terminated, term), batch)
        chk("step count + 1", np.array_equal(c2, c + 1), batch)
        chk("truncated iff T reached without overflow", np.array_equal(out.truncated, ~term & (c2 >= plant.T)),
            batch)
        chk("individual reward = r_min where overflowed",
            np.array_equal(out.individual_reward, np.where(overflow, plant.r_min, out.container_reward)), batch)
        ind = out.individual_reward
        chk("individual rewards in [r_min, 1]", bool((ind >= plant.r_min).all() and (ind <= 1.0 + TOL).all()), batch)
        plant_r = np.where(term, plant.r_min, out.container_reward.sum(1))
        chk("plant reward = r_min on overflow, else the sum", np.allclose(out.plant_reward, plant_r, rtol=0, atol=TOL),
            batch)
        ok_range = term | ((out.plant_reward >= nreq * plant.r_pen - TOL) & (out.plant_reward <= ngr + TOL))
        chk("plant reward in [requests · r_pen, grants]", bool(ok_range.all()), batch)
        done = np.flatnonzero(out.terminated | out.truncated)
        chk.episode_ends += done.size
        if done.size:
            sim.reset(sims=done)
    return calls * batch


# ---- the views ---------------------------------------------------------------------------------
BAD_SCALARS = (-1, 2, 1.0, 0.0, float("nan"), None, True, "1", np.float64(1.0), np.array(1.0),
               np.array([0, 1]))


def _in_box(x: np.ndarray, low: np.ndarray, high: np.ndarray) -> bool:
    return (x.dtype == np.float32 and x.shape[-low.ndim:] == low.shape and bool(np.isfinite(x).all())
            and bool((x >= low).all()) and bool((x <= high).all()))


def _maybe_inject(sim: PlantSimulator, plant: Plant, rng, p: float = 0.005, keep_count: bool = True) -> None:
    if rng.random() >= p:
        return
    rows = np.arange(sim.num_sims) if sim.num_sims == 1 else rng.choice(sim.num_sims, 1)
    vol, tim, cnt = extreme_states(plant, rng, rows.size)
    st = sim.state
    v_, p_, c_ = st.volumes.copy(), st.pu_timers_s.copy(), st.step_count.copy()
    v_[rows], p_[rows] = vol, tim
    if not keep_count:
        c_[rows] = cnt
    sim.state = PlantState(v_, p_, c_)


def _refused(chk: Checker, sim: PlantSimulator, call, what: str) -> None:
    before = _sim_snapshot(sim)
    try:
        call()
    except (TypeError, ValueError, KeyError):
        refused = True
    else:
        refused = False
    chk(f"{what}: invalid action refused", refused)
    chk(f"{what}: refused action changes nothing", _same_snapshot(before, _sim_snapshot(sim)))


def stress_centralised(plant: Plant, steps: int, seed: int, chk: Checker) -> int:
    from containergym_marl.envs.centralised import ContainerGymEnv

    env = ContainerGymEnv(plant.cfg)
    rng = np.random.default_rng([seed, 3])
    low, high = env.observation_space.low, env.observation_space.high
    obs, info = env.reset(seed=seed)
    types = {k: type(v) for k, v in info.items()}
    chk("centralised: reset obs in space", _in_box(obs, low, high))
    sim, n, m = env.simulator, plant.n, plant.m
    for _ in range(steps):
        _maybe_inject(sim, plant, rng)
        if rng.random() < 0.01:
            bad = BAD_SCALARS[rng.integers(len(BAD_SCALARS))]
            bad = n + 1 if isinstance(bad, int) and bad == 2 else bad
            _refused(chk, sim, lambda: env.step(bad), "centralised")
        v = sim.state.volumes[0].copy()
        free = int((sim.state.pu_timers_s[0] == 0).sum())
        count = int(sim.state.step_count[0])
        a = 0 if rng.random() < 0.5 else int(rng.integers(1, n + 1))
        obs, r, term, trunc, info = env.step(a)
        chk("centralised: obs in space", _in_box(obs, low, high))
        chk("centralised: info keys and types stable", {k: type(x) for k, x in info.items()} == types)
        chk("centralised: reward in [r_min, 1]", type(r) is float and plant.r_min <= r <= 1.0 + TOL)
        chk("centralised: step count", info["step"] == count + 1)
        chk("centralised: free PUs before", info["free_pus"] == free)
        if a == 0:
            chk("centralised: waiting empties nothing",
                info["emptied_index"] == -1 and not info["no_free_pu"] and info["emptying_reward"] == 0.0)
            chk("centralised: waiting scores 0 (r_min on overflow)", r == (plant.r_min if term else 0.0))
        elif free > 0:
            i = a - 1
            ok = (info["emptied_index"] == i and info["emptied_container"] == plant.names[i]
                  and info["emptied_volume"] == v[i] and 0 <= info["pu_index"] < m and not info["no_free_pu"])
            chk("centralised: a free PU takes the request", ok)
            chk("centralised: emptying reward = eq. 5",
                abs(info["emptying_reward"] - plant.reward.one(i, v[i])) <= 1e-12)
            chk("centralised: reward = emptying reward (r_min on overflow)",
                r == (plant.r_min if term else info["emptying_reward"]))
        else:
            chk("centralised: no free PU denies",
                info["no_free_pu"] and info["pu_index"] == -1 and info["emptying_reward"] == plant.r_pen)
            chk("centralised: denied reward r_pen (r_min on overflow)", r == (plant.r_min if term else plant.r_pen))
        overflow = bool((sim.state.volumes[0] >= plant.vmax).any())
        chk("centralised: terminated iff overflow", term == overflow == bool(info["overflowed_containers"]))
        chk("centralised: truncated iff T without overflow", trunc == (not overflow and count + 1 >= plant.T))
        chk("centralised: action mask = PU availability",
            np.array_equal(env.action_masks(), [True] + [bool((sim.state.pu_timers_s[0] == 0).any())] * n))
        if term or trunc:
            chk.episode_ends += 1
            obs, info = env.reset()
            chk("centralised: reset obs in space", _in_box(obs, low, high))
            chk("centralised: info keys and types stable", {k: type(x) for k, x in info.items()} == types)
    return steps


SEGMENTS = (("fullest", "individual", "box"), ("random", "team", "dict"),
            ("index", "individual", "dict"), ("best_reward", "team", "box"))


def _check_agent_step(chk: Checker, plant: Plant, what: str, mode: str, actions, rewards, terms, truncs,
                      infos, v_before, free_before, count, sim, types) -> bool:
    """Invariants of one decentralised plant step; returns whether the episode ended."""
    agents = list(infos)
    n, m = plant.n, plant.m
    chk(f"{what}: info keys and types stable",
        all({k: type(x) for k, x in infos[a].items()} == types for a in agents), n)
    req = np.array([actions[a] == 1 for a in agents])
    gr = np.array([infos[a]["granted"] for a in agents])
    de = np.array([infos[a]["denied"] for a in agents])
    pu = np.array([infos[a]["pu_index"] for a in agents])
    chk(f"{what}: requested = actions", np.array_equal(np.array([infos[a]["requested"] for a in agents]), req), n)
    chk(f"{what}: granted ⊆ requested", not (gr & ~req).any(), n)
    chk(f"{what}: denied = requested − granted", np.array_equal(de, req & ~gr), n)
    chk(f"{what}: grants ≤ min(m, free PUs)", gr.sum() <= min(m, free_before), n)
    chk(f"{what}: free PUs reported", all(infos[a]["free_pus"] == free_before for a in agents), n)
    chk(f"{what}: distinct PUs in range for grants, −1 otherwise",
        bool((pu[~gr] == -1).all()) and bool(((pu[gr] >= 0) & (pu[gr] < m)).all())
        and np.unique(pu[gr]).size == gr.sum(), n)
    emp = np.array([infos[a]["emptying_reward"] for a in agents])
    expected = np.where(gr, plant.reward(v_before), np.where(de, plant.r_pen, 0.0))
    chk(f"{what}: emptying rewards = eq. 5 / r_pen / 0", np.allclose(emp, expected, rtol=1e-12, atol=1e-12), n)
    overflowed = np.array([infos[a]["overflowed"] for a in agents])
    overflow = sim.state.volumes[0] >= plant.vmax
    chk(f"{what}: overflowed = v' ≥ v_max", np.array_equal(overflowed, overflow), n)
    term = bool(overflow.any())
    chk(f"{what}: terminated iff overflow", all(terms[a] == term for a in agents), n)
    chk(f"{what}: truncated iff T without overflow",
        all(truncs[a] == (not term and count + 1 >= plant.T) for a in agents), n)
    plant_r = plant.r_min if term else math.fsum(emp)
    chk(f"{what}: plant reward = r_min on overflow, else the sum",
        all(abs(infos[a]["plant_reward"] - plant_r) <= TOL for a in agents), n)
    r = np.array([rewards[a] for a in agents])
    if mode == "team":
        chk(f"{what}: team reward = plant reward for everyone", bool(np.all(np.abs(r - plant_r) <= TOL)), n)
    else:
        chk(f"{what}: individual reward = emptying reward, r_min where overflowed",
            np.array_equal(r, np.where(overflowed, plant.r_min, emp)), n)
        chk(f"{what}: individual rewards in [r_min, 1]", bool(((r >= plant.r_min) & (r <= 1 + TOL)).all()), n)
    chk(f"{what}: step count", all(infos[a]["step"] == count + 1 for a in agents), n)
    free_now = bool((sim.state.pu_timers_s[0] == 0).any())
    masks = np.stack([infos[a]["action_mask"] for a in agents])
    chk(f"{what}: action mask = PU availability",
        masks.dtype == np.int8 and bool((masks[:, 0] == 1).all()) and bool((masks[:, 1] == int(free_now)).all()), n)
    return term or (count + 1 >= plant.T)


def _check_agent_obs(chk: Checker, what: str, obs, low, high, free: bool, dict_mode: bool, n: int) -> None:
    if dict_mode:
        feats = np.stack([o["observation"] for o in obs])
        masks = np.stack([o["action_mask"] for o in obs])
        chk(f"{what}: dict obs action mask = PU availability",
            masks.dtype == np.int8 and bool((masks[:, 0] == 1).all()) and bool((masks[:, 1] == int(free)).all()), n)
    else:
        feats = np.stack(obs)
    chk(f"{what}: obs in space", _in_box(feats, low, high), n)


def stress_parallel(plant: Plant, steps: int, seed: int, chk: Checker) -> int:
    from containergym_marl.envs.container_agents_v0 import parallel_env

    rng = np.random.default_rng([seed, 4])
    done_steps = 0
    for s, (rule, mode, obs_mode) in enumerate(SEGMENTS):
        seg = steps // len(SEGMENTS) + (1 if s < steps % len(SEGMENTS) else 0)
        env = parallel_env(plant.cfg, arbitration=rule, reward_mode=mode, observation_mode=obs_mode,
                           action_masking=True, state_mode="normalised" if s % 2 else "physical")
        sim = env.simulator
        box = env.observation_space(env.possible_agents[0])
        box = box["observation"] if obs_mode == "dict" else box
        low, high = box.low, box.high
        obs, infos = env.reset(seed=seed + s)
        types = {k: type(x) for k, x in infos[env.possible_agents[0]].items()}
        what = f"parallel[{rule},{mode},{obs_mode}]"
        for _ in range(seg):
            _maybe_inject(sim, plant, rng)
            if rng.random() < 0.01:
                bad = BAD_SCALARS[rng.integers(len(BAD_SCALARS))]
                victim = env.agents[int(rng.integers(plant.n))]
                acts = {a: (bad if a == victim else 0) for a in env.agents}
                _refused(chk, sim, lambda: env.step(acts), what)
            v = sim.state.volumes[0].copy()
            free = int((sim.state.pu_timers_s[0] == 0).sum())
            count = int(sim.state.step_count[0])
            p_req = (0.05, 0.3, 0.7, 1.0)[int(rng.integers(4))]
            actions = {a: int(rng.random() < p_req) for a in env.agents}
            obs, rewards, terms, truncs, infos = env.step(actions)
            free_now = bool((sim.state.pu_timers_s[0] == 0).any())
            _check_agent_obs(chk, what, list(obs.values()), low, high, free_now, obs_mode == "dict", plant.n)
            st = env.state()
            chk(f"{what}: state in state_space", _in_box(st, env.state_space.low, env.state_space.high))
            ended = _check_agent_step(chk, plant, what, mode, actions, rewards, terms, truncs, infos, v, free,
                                      count, sim, types)
            chk(f"{what}: agents empty iff the episode ended", (env.agents == []) == ended)
            if ended:
                chk.episode_ends += 1
                obs, infos = env.reset()
                chk(f"{what}: reset info keys and types stable",
                    all({k: type(x) for k, x in infos[a].items()} == types for a in infos), plant.n)
        done_steps += seg
    return done_steps


def stress_aec(plant: Plant, steps: int, seed: int, chk: Checker) -> int:
    """``steps`` plant steps (each n agent turns) through the AEC env."""
    from containergym_marl.envs.container_agents_v0 import env as aec_env

    rng = np.random.default_rng([seed, 5])
    done_steps = 0
    for s, (rule, mode, obs_mode) in enumerate(SEGMENTS):
        seg = steps // len(SEGMENTS) + (1 if s < steps % len(SEGMENTS) else 0)
        env = aec_env(plant.cfg, arbitration=rule, reward_mode=mode, observation_mode=obs_mode,
                      action_masking=True)
        sim = env.unwrapped.simulator
        box = env.observation_space(env.possible_agents[0])
        box = box["observation"] if obs_mode == "dict" else box
        low, high = box.low, box.high
        env.reset(seed=seed + s)
        types = {k: type(x) for k, x in env.infos[env.possible_agents[0]].items()}
        what = f"aec[{rule},{mode},{obs_mode}]"
        for _ in range(seg):
            _maybe_inject(sim, plant, rng)
            v = sim.state.volumes[0].copy()
            free = int((sim.state.pu_timers_s[0] == 0).sum())
            count = int(sim.state.step_count[0])
            p_req = (0.05, 0.3, 0.7, 1.0)[int(rng.integers(4))]
            agents = list(env.agents)
            actions = {}
            for a in agents:
                chk(f"{what}: turn order", env.agent_selection == a)
                if rng.random() < 0.01:
                    bad = BAD_SCALARS[rng.integers(len(BAD_SCALARS))]
                    _refused(chk, sim, lambda: env.step(bad), what)
                    chk(f"{what}: refused action keeps the turn", env.agent_selection == a)
                actions[a] = int(rng.random() < p_req)
                env.step(actions[a])
            free_now = bool((sim.state.pu_timers_s[0] == 0).any())
            _check_agent_obs(chk, what, [env.observe(a) for a in agents], low, high, free_now,
                             obs_mode == "dict", plant.n)
            ended = _check_agent_step(chk, plant, what, mode, actions, dict(env.rewards), dict(env.terminations),
                                      dict(env.truncations), dict(env.infos), v, free, count, sim, types)
            if ended:
                chk.episode_ends += 1
                for a in agents:
                    chk(f"{what}: finished agent's turn", env.agent_selection == a)
                    env.step(None)
                chk(f"{what}: no agents after the end", env.agents == [])
                env.reset()
        done_steps += seg
    return done_steps


def _vec_bad_actions(rng, slots: int, top: int):
    kind = int(rng.integers(5))
    a = np.zeros(slots)
    if kind == 0:
        a[-1] = np.nan
    elif kind == 1:
        a[0] = 0.5
    elif kind == 2:
        return np.full(slots, top + 1, dtype=np.int64)
    elif kind == 3:
        return np.full(slots, -1, dtype=np.int64)
    else:
        return np.zeros(slots + 1, dtype=np.int64)
    return a


def stress_vector(plant: Plant, steps: int, batch: int, seed: int, chk: Checker) -> dict[str, tuple[int, float]]:
    """``steps`` plant steps through each of the three vector envs (B = ``batch``); returns
    (steps, seconds) per env."""
    from containergym_marl.envs.vector import ContainerAgentsVecEnv, ContainerGymVecEnv, ContainerGymVectorEnv

    rng = np.random.default_rng([seed, 6])
    n, calls = plant.n, -(-steps // batch)
    counts_out = {}
    vmax32 = plant.vmax.astype(np.float32)

    # --- SB3, centralised and container agents ---
    for kind in ("sb3_central", "sb3_agents"):
        t0 = time.perf_counter()
        if kind == "sb3_central":
            venv = ContainerGymVecEnv(plant.cfg, num_envs=batch)
            slots, top = batch, n
        else:
            mode = ("individual", "team")[seed % 2]
            venv = ContainerAgentsVecEnv(plant.cfg, num_sims=batch, reward_mode=mode,
                                         arbitration=RULES[seed % len(RULES)])
            slots, top = batch * n, 1
        what = kind if kind == "sb3_central" else f"sb3_agents[{venv.reward_mode}]"
        low, high = venv.observation_space.low, venv.observation_space.high
        venv.seed(seed)
        obs = venv.reset()
        chk(f"{what}: obs in space", _in_box(obs, low, high), slots)
        sim = venv.simulator
        count = np.zeros(batch, dtype=np.int64)
        for _ in range(calls):
            _maybe_inject(sim, plant, rng, p=0.02)
            if rng.random() < 0.01:
                bad = _vec_bad_actions(rng, slots, top)
                _refused(chk, sim, lambda: venv.step(bad), what)
            if kind == "sb3_central":
                actions = np.where(rng.random(batch) < 0.5, 0, rng.integers(1, n + 1, batch))
            else:
                actions = (rng.random(slots) < rng.choice([0.05, 0.3, 0.7])).astype(np.int64)
            obs, rewards, dones, infos = venv.step(actions)
            count += 1
            chk(f"{what}: obs in space", _in_box(obs, low, high), slots)
            chk(f"{what}: rewards float32 of shape (slots,)", rewards.dtype == np.float32 and rewards.shape == (slots,))
            rr = rewards.reshape(batch, -1)
            if kind == "sb3_agents" and venv.reward_mode == "team":
                chk(f"{what}: team reward equal within a plant", bool((rr == rr[:, :1]).all()), slots)
                chk(f"{what}: team reward ≥ r_min or n·r_pen", bool((rr >= min(plant.r_min, n * plant.r_pen) - 1e-5).all()), slots)
            else:
                chk(f"{what}: rewards in [r_min, 1]",
                    bool(((rr >= np.float32(plant.r_min)) & (rr <= 1 + 1e-5)).all()), slots)
            dd = dones.reshape(batch, -1)
            chk(f"{what}: a plant's slots end together", bool((dd == dd[:, :1]).all()), slots)
            ended = dd[:, 0]
            chk(f"{what}: T ends an episode", bool(ended[count >= plant.T].all()), batch)
            chk(f"{what}: infos only at episode ends",
                all((len(infos[k]) > 0) == bool(dones[k]) for k in range(slots)), slots)
            for b in np.flatnonzero(ended).tolist():
                info = infos[b * (slots // batch)]
                term_obs = info["terminal_observation"]
                chk(f"{what}: terminal obs in space", _in_box(term_obs, low, high))
                if kind == "sb3_central":
                    overflow = bool((term_obs[:n] >= vmax32).any())
                else:
                    fracs = np.stack([infos[b * n + i]["terminal_observation"][0] for i in range(n)])
                    overflow = bool((fracs >= 1.0).any())
                trunc = info["TimeLimit.truncated"]
                chk(f"{what}: truncated only at T", not trunc or count[b] >= plant.T)
                chk(f"{what}: an end that is not a truncation is an overflow", trunc or overflow)
                chk(f"{what}: truncated iff the core saw no overflow", trunc != bool(sim.last_outcome.terminated[b]))
            count[ended] = 0
            chk.episode_ends += int(ended.sum())
            masks = venv.action_masks()
            free = (sim.state.pu_timers_s == 0).any(1)
            if kind == "sb3_central":
                chk(f"{what}: action masks = PU availability",
                    bool(masks[:, 0].all()) and np.array_equal(masks[:, 1:], np.repeat(free[:, None], n, 1)), batch)
            else:
                chk(f"{what}: action masks = PU availability", np.array_equal(masks[:, 1], np.repeat(free, n)), slots)
        counts_out[kind] = (calls * batch, time.perf_counter() - t0)

    # --- Gymnasium ---
    t0 = time.perf_counter()
    venv = ContainerGymVectorEnv(num_envs=batch, config=plant.cfg)
    what = "gymnasium_vector"
    low, high = venv.single_observation_space.low, venv.single_observation_space.high
    obs, info = venv.reset(seed=seed)
    keys = set(info)
    chk(f"{what}: obs in space", _in_box(obs, low, high), batch)
    sim = venv.simulator
    count = np.zeros(batch, dtype=np.int64)
    for _ in range(calls):
        _maybe_inject(sim, plant, rng, p=0.02)
        if rng.random() < 0.01:
            bad = _vec_bad_actions(rng, batch, n)
            _refused(chk, sim, lambda: venv.step(bad), what)
        actions = np.where(rng.random(batch) < 0.5, 0, rng.integers(1, n + 1, batch))
        obs, rewards, term, trunc, info = venv.step(actions)
        count += 1
        chk(f"{what}: obs in space", _in_box(obs, low, high), batch)
        chk(f"{what}: rewards in [r_min, 1]", bool(((rewards >= plant.r_min) & (rewards <= 1 + TOL)).all()), batch)
        chk(f"{what}: terminated and truncated exclusive", not (term & trunc).any(), batch)
        chk(f"{what}: truncated iff T reached without overflow", np.array_equal(trunc, (count >= plant.T) & ~term), batch)
        chk(f"{what}: info keys stable", set(info) - {"final_obs", "_final_obs", "final_info", "_final_info"} == keys)
        ended = term | trunc
        if ended.any():
            fin = info["final_info"]
            chk(f"{what}: final obs in space", _in_box(info["final_obs"][ended], low, high), int(ended.sum()))
            chk(f"{what}: terminated iff overflowed containers",
                all(bool(fin["overflowed_containers"][b]) == bool(term[b]) for b in np.flatnonzero(ended)),
                int(ended.sum()))
            chk(f"{what}: overflow volumes ≥ v_max",
                all(bool((info["final_obs"][b, :n] >= vmax32).any()) for b in np.flatnonzero(term)), int(term.sum()))
        chk(f"{what}: emptying rewards in [r_pen, 1] or 0",
            bool(((info["emptying_reward"] == 0) | ((info["emptying_reward"] >= plant.r_pen)
                                                     & (info["emptying_reward"] <= 1 + TOL))).all()), batch)
        count[ended] = 0
        chk.episode_ends += int(ended.sum())
    counts_out["gymnasium_vector"] = (calls * batch, time.perf_counter() - t0)
    return counts_out


# ---- driver ------------------------------------------------------------------------------------
VIEWS = ("centralised", "parallel", "aec", "sb3_central", "sb3_agents", "gymnasium_vector")


def run(configs, core_steps: int, view_steps: int, batch: int, vec_batch: int, seed: int,
        log=print, **overrides) -> dict:
    """The stress run over the built-in ``configs`` (with plant-level ``overrides``, e.g. a short
    ``episode_length_steps`` to end many episodes)."""
    chk = Checker()
    z = ZStats()
    report = {"core": {}, "views": {v: {"steps": 0, "seconds": 0.0} for v in VIEWS}}
    per_config_view = -(-view_steps // len(configs))
    started = time.perf_counter()
    for ci, name in enumerate(configs):
        plant = Plant(load_config(name, **overrides))
        # core: split over the rules
        t0 = time.perf_counter()
        taken = 0
        for ri, rule in enumerate(RULES):
            chk.where = f"core {name} {rule}"
            share = core_steps // len(RULES) + (1 if ri < core_steps % len(RULES) else 0)
            taken += stress_core(plant, rule, share, batch, seed * 1000 + ci * 10 + ri, chk, z)
        report["core"][name] = {"steps": taken, "seconds": time.perf_counter() - t0}
        log(f"core {name}: {taken:,} steps in {time.perf_counter() - t0:.1f} s, violations so far {chk.violations}")
        # views
        for view, fn in (("centralised", stress_centralised), ("parallel", stress_parallel), ("aec", stress_aec)):
            chk.where = f"{view} {name}"
            t0 = time.perf_counter()
            report["views"][view]["steps"] += fn(plant, per_config_view, seed + ci, chk)
            report["views"][view]["seconds"] += time.perf_counter() - t0
        chk.where = f"vector {name}"
        for view, (k, secs) in stress_vector(plant, per_config_view, vec_batch, seed + ci, chk).items():
            report["views"][view]["steps"] += k
            report["views"][view]["seconds"] += secs
        log(f"views {name}: done, violations so far {chk.violations}")
    zmean = z.total / max(z.count, 1)
    zvar = z.total_sq / max(z.count, 1) - zmean**2
    chk.where = "fill noise over the run"
    if z.count > 1000:
        chk("fill noise: mean of z ≈ 0", abs(zmean) < 5 / math.sqrt(z.count), detail=zmean)
        chk("fill noise: variance of z ≈ 1", abs(zvar - 1) < 5 * math.sqrt(2 / z.count), detail=zvar)
    report.update({
        "configs": list(configs),
        "overrides": {k: v for k, v in overrides.items()},
        "sizes": {"core_steps_per_config": core_steps, "view_steps_per_view": view_steps,
                  "batch": batch, "vec_batch": vec_batch, "seed": seed},
        "seconds": time.perf_counter() - started,
        # an invariant checked by several views (or view settings) counts once here
        "invariants": len({name.split(": ", 1)[-1] for name in chk.names}),
        "invariant_checks": len(chk.names),
        "invariant_names": sorted(chk.names),
        "evaluations": chk.evaluations,
        "violations": chk.violations,
        "episode_ends": chk.episode_ends,
        "violation_examples": chk.examples,
        "fill_noise_z": {"count": z.count, "mean": zmean, "variance": zvar},
        "machine": f"{platform.machine()} {platform.system()}, python {platform.python_version()}, "
                   f"numpy {np.__version__}",
    })
    return report


def markdown(report: dict) -> str:
    lines = ["| part | config / view | steps | seconds | steps/s |", "|---|---|---:|---:|---:|"]
    for name, r in report["core"].items():
        lines.append(f"| core (B = {report['sizes']['batch']}, 4 rules) | {name} | {r['steps']:,} | "
                     f"{r['seconds']:.1f} | {r['steps'] / max(r['seconds'], 1e-9):,.0f} |")
    for view, r in report["views"].items():
        lines.append(f"| view | {view} | {r['steps']:,} | {r['seconds']:.1f} | "
                     f"{r['steps'] / max(r['seconds'], 1e-9):,.0f} |")
    total_core = sum(r["steps"] for r in report["core"].values())
    z = report["fill_noise_z"]
    lines += ["",
              f"Core steps: {total_core:,}; view steps: {sum(r['steps'] for r in report['views'].values()):,}; "
              f"episodes ended and reset: {report['episode_ends']:,}; wall time {report['seconds']:.0f} s.",
              f"Invariants: {report['invariants']} distinct ({report['invariant_checks']} with the view "
              f"and its settings), {report['evaluations']:,} evaluations (one per simulation or agent "
              f"and step); **violations: {report['violations']}**.",
              f"Fill noise z over {z['count']:,} uncensored draws: mean {z['mean']:+.5f}, "
              f"variance {z['variance']:.5f}."]
    if report["violation_examples"]:
        lines += ["", "Violations (first ones):"] + [f"- {e}" for e in report["violation_examples"]]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--smoke", action="store_true", help="tiny sizes (seconds), for the tests")
    parser.add_argument("--configs", nargs="+", default=None, help="built-in config names (default: all)")
    parser.add_argument("--core-steps", type=float, default=None, help="simulation steps per config (1e7)")
    parser.add_argument("--view-steps", type=float, default=None, help="plant steps per view, all configs (1e6)")
    parser.add_argument("--batch", type=int, default=None, help="simulations in the core's batch (1024)")
    parser.add_argument("--vec-batch", type=int, default=None, help="simulations in the vector envs (64)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--episode-length-steps", type=int, default=None,
                        help="override T of every config (short episodes exercise the ends)")
    parser.add_argument("--json", type=Path, default=None, help="write the figures here")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)
    sizes = dict(SMOKE if args.smoke else FULL)
    for key in ("core_steps", "view_steps", "batch", "vec_batch"):
        value = getattr(args, key)
        if value is not None:
            if value < 1 or value != int(value):
                parser.error(f"--{key.replace('_', '-')}: expected a positive integer, got {value}")
            sizes[key] = int(value)
    configs = args.configs or list_configs()
    unknown = sorted(set(configs) - set(list_configs()))
    if unknown:
        parser.error(f"--configs: unknown {unknown}; built-in: {list_configs()}")
    log = (lambda *a, **k: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))
    overrides = {}
    if args.episode_length_steps is not None:
        if args.episode_length_steps < 1:
            parser.error("--episode-length-steps: expected a positive integer")
        overrides["episode_length_steps"] = args.episode_length_steps
    report = run(configs, seed=args.seed, log=log, **sizes, **overrides)
    print(f"# Stress ({'smoke' if args.smoke else 'run'})\n")
    print(markdown(report))
    if args.json:
        args.json.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    return 1 if report["violations"] else 0


if __name__ == "__main__":
    sys.exit(main())
