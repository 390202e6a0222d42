"""Environment and training throughput, measured side by side in one run on this machine.

Run from the repository root (the package installed, with its training extra)::

    python benchmarks/throughput.py                 # full benchmark, about 2 minutes on 2 cores
    python benchmarks/throughput.py --json out.json # also write every number as JSON
    python benchmarks/throughput.py --smoke         # tiny sizes, a few seconds (what the tests run)
    python benchmarks/throughput.py --skip-ppo      # environment tables only (about 1.5 minutes)

It prints Markdown to stdout:

1. **Environment steps per second** for n = 5 (``n5_m2_dt120``) and n = 11 (``n11_m2_dt120``): the
   earlier implementation's cost model (``reference_cost_model.py``, with a ``np.random.Generator``
   and with the global ``np.random`` the earlier code used), the centralised Gymnasium env and the
   PettingZoo parallel env (B = 1), the SuperSuit stack (``pettingzoo_env_to_vec_env_v1`` +
   ``concat_vec_envs_v1``, in-process copies), and the native vectorised envs at B ∈ {1, 64, 1024,
   4096}, each with both backends of the core (``numpy``, and ``numba`` when installed; see
   ``containergym_marl.core.compiled``). An *env step* is one step of one simulated plant (a vector env stepping B simulations
   makes B env steps per call); for the decentralised paths the agent steps (× n) are shown too.
   Ratios are against the cost model measured in the same run.
2. **Where the time goes** in a few configurations, per backend (random streams, physics,
   observations, resets, the rest: the view / vector-env plumbing), from timers around the core's
   functions.
3. **SB3 PPO training throughput** (samples/s = environment slots stepped per second of
   ``model.learn``) and the share of that wall time spent in the environment (``step_wait``),
   for the parameter-shared PPO on the SuperSuit stack and on the native agents vec env, and for
   the centralised PPO on the native vec env (default backend); with the time a 2M-step run would
   take at that rate.

Actions are drawn in advance (uniformly random valid actions: the centralised controller picks one
of the n + 1 actions, each container agent requests with probability 1/2), so policy time is not
counted. Each rate is the median of several timed bursts after a warm-up; other processes on the
machine make single numbers noisy, ratios within one run much less so. PPO runs use
``torch.set_num_threads(1)``, SB3's defaults except ``n_steps`` (6144 samples per update) and,
as the package's training runs do, Adam's fused kernel and no torch.distributions argument checks
(one row keeps SB3's defaults for comparison); no seeding (the raw SuperSuit stack has no
``seed()``).
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as _dt
import json
import os
import platform
import statistics
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from reference_cost_model import ReferenceCostModelEnv  # noqa: E402

from containergym_marl import ContainerGymEnv, container_agents_v0, load_config  # noqa: E402
from containergym_marl.core import compiled  # noqa: E402
from containergym_marl.envs.vector import (  # noqa: E402
    ContainerAgentsVecEnv,
    ContainerGymVecEnv,
    ContainerGymVectorEnv,
)

CONFIGS = {5: "n5_m2_dt120", 11: "n11_m2_dt120"}
PPO_CONFIG = "n5_m2_dt120"
ROLLOUT_SAMPLES = 6144  # samples per PPO update, as the package's training runs

PATHS = (
    # (key, label, decentralised)
    ("ref_global", "earlier implementation, cost model (global np.random)", False),
    ("ref_generator", "earlier implementation, cost model (np.random.Generator)", False),
    ("gym", "centralised Gymnasium env (ContainerGymEnv)", False),
    ("pettingzoo", "PettingZoo parallel env (container_agents_v0)", True),
    ("supersuit", "SuperSuit stack (pettingzoo_env_to_vec_env_v1 + concat_vec_envs_v1)", True),
    ("vec_central", "native SB3 ContainerGymVecEnv", False),
    ("vec_gymnasium", "native Gymnasium ContainerGymVectorEnv", False),
    ("vec_agents", "native SB3 ContainerAgentsVecEnv (B·n agent slots)", True),
)
#: The core's backends measured: numpy always, numba when installed (the "fast" extra).
BACKENDS = ("numpy", "numba") if compiled.numba_available() else ("numpy",)
ENV_COLUMNS = ("path", "backend", "B", "n=5 env steps/s", "n=5 agent steps/s", "n=5 × ref (global)",
               "n=5 × ref (Generator)", "n=11 env steps/s", "n=11 agent steps/s",
               "n=11 × ref (global)", "n=11 × ref (Generator)")
PROFILE_COLUMNS = ("configuration", "µs per call", "random streams", "physics", "observations",
                   "resets", "rest (view / vec-env plumbing)")
PPO_COLUMNS = ("training", "env slots", "samples/s", "env share of wall time",
               "projected 2M-step run (min)")


@dataclass
class Sizes:
    batch_sizes: tuple[int, ...]
    burst_s: float  # target duration of one timed burst
    bursts: int
    supersuit_copies: int
    ppo_sims: int  # simulations of the PPO envs (slots = sims × n for the agents envs)
    ppo_timesteps: int  # samples per PPO measurement
    ppo_n_steps: int | None  # None: ROLLOUT_SAMPLES // slots
    profile_batch: int
    profile_calls: int


FULL = Sizes(batch_sizes=(1, 64, 1024, 4096), burst_s=0.4, bursts=5, supersuit_copies=16,
             ppo_sims=16, ppo_timesteps=3 * ROLLOUT_SAMPLES, ppo_n_steps=None, profile_batch=4096,
             profile_calls=300)
SMOKE = Sizes(batch_sizes=(1, 4), burst_s=0.01, bursts=2, supersuit_copies=2, ppo_sims=2,
              ppo_timesteps=64, ppo_n_steps=16, profile_batch=4, profile_calls=20)


# ---- timing ------------------------------------------------------------------------------------
def _rate(run: Callable[[int], None], steps_per_call: int, sizes: Sizes) -> float:
    """Median env steps per second over ``sizes.bursts`` bursts of about ``sizes.burst_s`` each."""
    run(2)  # warm-up
    calls = 1
    while True:  # calibrate the burst length
        t = time.perf_counter()
        run(calls)
        dt = time.perf_counter() - t
        if dt >= sizes.burst_s / 4 or calls >= 1 << 20:
            break
        calls *= 2
    calls = max(1, int(calls * sizes.burst_s / max(dt, 1e-9)))
    rates = []
    for _ in range(sizes.bursts):
        t = time.perf_counter()
        run(calls)
        rates.append(calls * steps_per_call / (time.perf_counter() - t))
    return statistics.median(rates)


def _central_actions(n: int, batch: int, count: int = 64) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    return [rng.integers(0, n + 1, batch) for _ in range(count)]


def _agent_actions(n: int, batch: int, count: int = 64) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    return [rng.integers(0, 2, batch * n) for _ in range(count)]


# ---- the environment paths ---------------------------------------------------------------------
def _runner(key: str, n: int, batch: int, sizes: Sizes, backend: str = "auto"):
    """A function running k calls of path ``key``, the env steps one call makes, and the path's
    PlantSimulator (None for the cost model and SuperSuit)."""
    name = CONFIGS[n]
    cfg = load_config(name)
    if key in ("ref_global", "ref_generator"):
        env = ReferenceCostModelEnv(cfg, rng="global" if key == "ref_global" else "generator", seed=0)
        env.reset()
        acts = [int(a) for a in _central_actions(n, 4096, 1)[0]]
        state = {"t": 0}

        def run(k):
            t = state["t"]
            for i in range(k):
                _, _, done, _ = env.step(acts[(t + i) % 4096])
                if done:
                    env.reset()
            state["t"] = t + k
        return run, 1, None
    if key == "gym":
        env = ContainerGymEnv(name, backend=backend)
        env.reset(seed=0)
        acts = [int(a) for a in _central_actions(n, 4096, 1)[0]]
        state = {"t": 0}

        def run(k):
            t = state["t"]
            for i in range(k):
                _, _, term, trunc, _ = env.step(acts[(t + i) % 4096])
                if term or trunc:
                    env.reset()
            state["t"] = t + k
        return run, 1, env.simulator
    if key == "pettingzoo":
        env = container_agents_v0.parallel_env(config=name, backend=backend)
        env.reset(seed=0)
        agents = env.possible_agents
        acts = [dict(zip(agents, a.tolist())) for a in _agent_actions(n, 1)]
        state = {"t": 0}

        def run(k):
            t = state["t"]
            for i in range(k):
                env.step(acts[(t + i) % len(acts)])
                if not env.agents:
                    env.reset()
            state["t"] = t + k
        return run, 1, env.simulator
    if key == "supersuit":
        import supersuit

        par = container_agents_v0.parallel_env(config=name, backend=backend)
        venv = supersuit.concat_vec_envs_v1(supersuit.pettingzoo_env_to_vec_env_v1(par), batch,
                                            num_cpus=0, base_class="stable_baselines3")
        venv.reset()
        return _vec_runner(venv, _agent_actions(n, batch)), batch, None
    if key == "vec_central":
        venv = ContainerGymVecEnv(name, num_envs=batch, backend=backend)
        venv.seed(0)
        venv.reset()
        return _vec_runner(venv, _central_actions(n, batch)), batch, venv.simulator
    if key == "vec_agents":
        venv = ContainerAgentsVecEnv(name, num_sims=batch, backend=backend)
        venv.seed(0)
        venv.reset()
        return _vec_runner(venv, _agent_actions(n, batch)), batch, venv.simulator
    if key == "vec_gymnasium":
        venv = ContainerGymVectorEnv(num_envs=batch, config=name, backend=backend)
        venv.reset(seed=0)
        acts = _central_actions(n, batch)
        state = {"t": 0}

        def run(k):
            t = state["t"]
            for i in range(k):
                venv.step(acts[(t + i) % len(acts)])
            state["t"] = t + k
        return run, batch, venv.simulator
    raise KeyError(key)


def _vec_runner(venv, acts: list[np.ndarray]) -> Callable[[int], None]:
    state = {"t": 0}

    def run(k):
        t = state["t"]
        for i in range(k):
            venv.step_async(acts[(t + i) % len(acts)])
            venv.step_wait()
        state["t"] = t + k
    return run


def _batches_of(key: str, sizes: Sizes) -> tuple[int, ...]:
    if key.startswith("vec_"):
        return sizes.batch_sizes
    if key == "supersuit":
        return (sizes.supersuit_copies,)
    return (1,)


def _backends_of(key: str) -> tuple[str, ...]:
    return ("–",) if key.startswith("ref_") else BACKENDS


def measure_envs(sizes: Sizes, log=print) -> list[dict]:
    rows = []
    for key, label, decentralised in PATHS:
        for batch in _batches_of(key, sizes):
            for backend in _backends_of(key):
                row = {"key": key, "path": label, "backend": backend, "B": batch,
                       "decentralised": decentralised}
                for n in CONFIGS:
                    run, per_call, _ = _runner(key, n, batch, sizes, "auto" if backend == "–" else backend)
                    rate = _rate(run, per_call, sizes)
                    row[f"n{n}_env_steps_per_s"] = rate
                    row[f"n{n}_agent_steps_per_s"] = rate * n if decentralised else None
                    del run
                log(f"  measured {label} [{backend}] B={batch}")
                rows.append(row)
    for n in CONFIGS:
        ref = {k: next(r for r in rows if r["key"] == k)[f"n{n}_env_steps_per_s"]
               for k in ("ref_global", "ref_generator")}
        for row in rows:
            row[f"n{n}_x_ref_global"] = row[f"n{n}_env_steps_per_s"] / ref["ref_global"]
            row[f"n{n}_x_ref_generator"] = row[f"n{n}_env_steps_per_s"] / ref["ref_generator"]
    return rows


def reference_sampling_share(n: int, steps: int) -> float:
    """Share of the cost model's step time spent in its per-second normal draws (global RNG)."""
    env = ReferenceCostModelEnv(load_config(CONFIGS[n]), rng="global", seed=0)
    env.reset()
    inner, spent = env._future_volume, [0.0]

    def timed(volumes):
        t = time.perf_counter()
        out = inner(volumes)
        spent[0] += time.perf_counter() - t
        return out
    env._future_volume = timed
    acts = [int(a) for a in _central_actions(n, 4096, 1)[0]]
    t = time.perf_counter()
    for i in range(steps):
        if env.step(acts[i % 4096])[2]:
            env.reset()
    return spent[0] / (time.perf_counter() - t)


# ---- where the time goes -----------------------------------------------------------------------
class _ComponentTimers:
    """Timers wrapped around the core's functions (module attributes the callers look up)."""

    def __init__(self, simulator):
        import containergym_marl.core.rng as rng
        import containergym_marl.core.simulator as sim
        import containergym_marl.envs.centralised as cen
        import containergym_marl.envs.container_agents_v0 as ag
        import containergym_marl.envs.vector as vec

        self.spent = {"random streams": 0.0, "physics": 0.0, "observations": 0.0, "resets": 0.0}
        self._patches: list = []
        self._depth = [0]
        self._patch(rng.NoiseStreams, "next_rows", "random streams")
        # the simulator holds its backend's step and global-state functions
        self._patch(simulator, "_step_fn", "physics")
        self._patch(simulator, "_global_state", "observations")
        self._patch(sim.PlantSimulator, "reset", "resets")
        for mod in (vec, cen, ag):
            for fn in ("global_state", "agent_observations"):
                if hasattr(mod, fn):
                    self._patch(mod, fn, "observations")

    def _patch(self, owner, name, component):
        inner = getattr(owner, name)
        spent, depth = self.spent, self._depth

        def timed(*args, **kwargs):
            if depth[0]:  # only the outermost timed call counts: a reset's random rows are reset time
                return inner(*args, **kwargs)
            depth[0] += 1
            t = time.perf_counter()
            try:
                return inner(*args, **kwargs)
            finally:
                spent[component] += time.perf_counter() - t
                depth[0] -= 1
        setattr(owner, name, timed)
        self._patches.append((owner, name, inner))

    def restore(self):
        for owner, name, inner in reversed(self._patches):
            setattr(owner, name, inner)


def profile_paths(sizes: Sizes) -> list[dict]:
    cases = []
    for backend in BACKENDS:
        cases += [
            (f"centralised Gymnasium env, n=5, B=1 [{backend}]", "gym", 5, 1, backend),
            (f"native SB3 ContainerGymVecEnv, n=11, B={sizes.profile_batch} [{backend}]", "vec_central", 11,
             sizes.profile_batch, backend),
            (f"native SB3 ContainerAgentsVecEnv, n=11, B={sizes.profile_batch} [{backend}]", "vec_agents", 11,
             sizes.profile_batch, backend),
        ]
    rows = []
    for label, key, n, batch, backend in cases:
        run, _, simulator = _runner(key, n, batch, sizes, backend)
        run(3)
        calls = sizes.profile_calls if batch > 1 else sizes.profile_calls * 20
        timers = _ComponentTimers(simulator)
        try:
            t = time.perf_counter()
            run(calls)
            total = time.perf_counter() - t
        finally:
            timers.restore()
        shares = {k: v / total for k, v in timers.spent.items()}
        shares["rest"] = max(0.0, 1.0 - sum(shares.values()))
        rows.append({"configuration": label, "us_per_call": total / calls * 1e6, "shares": shares})
    return rows


# ---- PPO ---------------------------------------------------------------------------------------
def _timed_step_wait(venv) -> list[float]:
    spent = [0.0]
    inner = venv.step_wait

    def step_wait():
        t = time.perf_counter()
        try:
            return inner()
        finally:
            spent[0] += time.perf_counter() - t
    venv.step_wait = step_wait
    return spent


def measure_ppo(sizes: Sizes, log=print) -> list[dict]:
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor

    from containergym_marl.training.loop import _no_distribution_validation

    torch.set_num_threads(1)
    n = load_config(PPO_CONFIG).n_containers

    def supersuit_env():
        import supersuit

        par = container_agents_v0.parallel_env(config=PPO_CONFIG)
        return supersuit.concat_vec_envs_v1(supersuit.pettingzoo_env_to_vec_env_v1(par), sizes.ppo_sims,
                                            num_cpus=0, base_class="stable_baselines3")

    def native_agents():
        venv = ContainerAgentsVecEnv(PPO_CONFIG, num_sims=sizes.ppo_sims)
        venv.seed(0)
        return venv

    def native_central():
        venv = ContainerGymVecEnv(PPO_CONFIG, num_envs=sizes.ppo_sims)
        venv.seed(0)
        return venv

    # The package's training settings (containergym_marl.training.runs): Adam's fused CPU kernel
    # and no torch.distributions argument checks; the last row keeps SB3's defaults for both.
    package = {"optimizer_kwargs": {"fused": True}}
    cases = [
        (f"shared PPO, SuperSuit stack ({sizes.ppo_sims} copies × {n} agents)", supersuit_env, True),
        (f"shared PPO, native ContainerAgentsVecEnv ({sizes.ppo_sims} sims × {n} agents)", native_agents, True),
        (f"centralised PPO, native ContainerGymVecEnv ({sizes.ppo_sims} sims)", native_central, True),
        (f"centralised PPO, native ContainerGymVecEnv ({sizes.ppo_sims} sims), SB3's default Adam and "
         "distribution checks", native_central, False),
    ]
    rows = []
    for label, make, package_settings in cases:
        venv = make()
        spent = _timed_step_wait(venv)
        slots = venv.num_envs
        n_steps = sizes.ppo_n_steps or max(ROLLOUT_SAMPLES // slots, 2)
        batch_size = min(64, n_steps * slots)
        model = PPO("MlpPolicy", VecMonitor(venv), n_steps=n_steps, batch_size=batch_size, device="cpu", verbose=0,
                    policy_kwargs=package if package_settings else None)
        spent[0] = 0.0
        t = time.perf_counter()
        with _no_distribution_validation() if package_settings else contextlib.nullcontext():
            model.learn(sizes.ppo_timesteps)
        wall = time.perf_counter() - t
        samples = model.num_timesteps
        rate = samples / wall
        rows.append({"training": label, "slots": slots, "samples_per_s": rate, "env_share": spent[0] / wall,
                     "projected_2M_minutes": 2e6 / rate / 60, "samples": samples, "wall_s": wall})
        log(f"  measured {label}")
        venv.close()
    return rows


# ---- output ------------------------------------------------------------------------------------
def _fmt_rate(x):
    return "–" if x is None else f"{x:,.0f}"


def _fmt_ratio(x):
    return f"{x:.2f}×"


def markdown(result: dict) -> str:
    meta = result["meta"]
    lines = [f"# Throughput ({'smoke' if meta['smoke'] else 'full'} run)", "",
             f"{meta['date']} · {meta['machine']} · {meta['cpus']} CPUs · load average before the run "
             f"{meta['load_before']} · python {meta['python']} · numpy {meta['numpy']} · numba {meta.get('numba', '?')}", "",
             "## Environment steps per second", "",
             "| " + " | ".join(ENV_COLUMNS) + " |", "|" + "---|" * len(ENV_COLUMNS)]
    for r in result["env"]:
        cells = [r["path"], r["backend"], str(r["B"])]
        for n in CONFIGS:
            cells += [_fmt_rate(r[f"n{n}_env_steps_per_s"]), _fmt_rate(r[f"n{n}_agent_steps_per_s"]),
                      _fmt_ratio(r[f"n{n}_x_ref_global"]), _fmt_ratio(r[f"n{n}_x_ref_generator"])]
        lines.append("| " + " | ".join(cells) + " |")
    shares = result.get("reference_sampling_share", {})
    if shares:
        lines += ["", "The cost model spends " + ", ".join(
            f"{100 * s:.0f} % (n = {n})" for n, s in shares.items())
            + " of its step time in the per-second normal draws (global np.random)."]
    if result.get("profile"):
        lines += ["", "## Where the time goes", "",
                  "| " + " | ".join(PROFILE_COLUMNS) + " |", "|" + "---|" * len(PROFILE_COLUMNS)]
        for r in result["profile"]:
            s = r["shares"]
            lines.append("| " + " | ".join([r["configuration"], f"{r['us_per_call']:,.1f}"] + [
                f"{100 * s[k]:.0f} %" for k in ("random streams", "physics", "observations", "resets", "rest")]) + " |")
    if result.get("ppo"):
        lines += ["", f"## SB3 PPO training throughput ({PPO_CONFIG}, MlpPolicy, torch threads = 1)", "",
                  "| " + " | ".join(PPO_COLUMNS) + " |", "|" + "---|" * len(PPO_COLUMNS)]
        for r in result["ppo"]:
            lines.append(f"| {r['training']} | {r['slots']} | {r['samples_per_s']:,.0f} | "
                         f"{100 * r['env_share']:.1f} % | {r['projected_2M_minutes']:.1f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--smoke", action="store_true", help="tiny sizes (seconds); checks the table, not speed")
    parser.add_argument("--json", type=Path, help="also write the results to this JSON file")
    parser.add_argument("--skip-ppo", action="store_true", help="environment tables only")
    parser.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    args = parser.parse_args(argv)
    sizes = SMOKE if args.smoke else FULL
    # SuperSuit's vec env has no render_mode; SB3 warns about it (and about partial mini-batches
    # at smoke sizes). Neither matters for timing.
    warnings.filterwarnings("ignore", category=UserWarning, module="stable_baselines3")

    def log(msg):
        if not args.quiet:
            print(msg, file=sys.stderr, flush=True)

    import numpy

    meta = {
        "date": _dt.datetime.now().astimezone().isoformat(timespec="seconds"),
        "machine": f"{platform.machine()} {platform.processor() or platform.system()}",
        "cpus": os.cpu_count(),
        "load_before": " ".join(f"{x:.2f}" for x in os.getloadavg()),
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "numba": compiled.numba.__version__ if compiled.numba_available() else "not installed",
        "smoke": args.smoke,
    }
    started = time.perf_counter()
    log("environment throughput ...")
    result: dict = {"meta": meta, "env": measure_envs(sizes, log)}
    result["reference_sampling_share"] = {
        n: reference_sampling_share(n, 200 if args.smoke else 20000) for n in CONFIGS}
    log("profiles ...")
    result["profile"] = profile_paths(sizes)
    if not args.skip_ppo:
        log("PPO training throughput ...")
        result["ppo"] = measure_ppo(sizes, log)
    meta["load_after"] = " ".join(f"{x:.2f}" for x in os.getloadavg())
    meta["duration_s"] = time.perf_counter() - started
    print(markdown(result), end="")
    print(f"\n(benchmark took {meta['duration_s']:.0f} s; load average after {meta['load_after']})")
    if args.json:
        args.json.write_text(json.dumps(result, indent=2, default=float))
    return result


if __name__ == "__main__":
    main()
