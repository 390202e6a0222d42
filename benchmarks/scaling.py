"""How the environment and the planner scale with the plant's size: the paper's plants and the larger
ones built from the 16-container plant (``configs/scaled.py``), PUs in proportion.

    python benchmarks/scaling.py                      # n = 5 … 128, ~3 minutes on one core
    python benchmarks/scaling.py --smoke              # seconds: checks the table, not speed
    python benchmarks/scaling.py --md benchmarks/profile/scaling.md --json benchmarks/profile/scaling.json \
        --figure docs/figures/scaling.png             # the table and figure docs/performance.md shows
    python benchmarks/scaling.py --from-json benchmarks/profile/scaling.json --figure docs/figures/scaling.png

For every plant, in this process (one thread: numba's and torch's):

* the centralised vectorised env (``ContainerGymVecEnv``, random actions) at B = 1 and B = 1024:
  plant steps per CPU-second, and container decisions per CPU-second (n per plant step);
* the container agents' vectorised env (``ContainerAgentsVecEnv``, every agent requesting with
  probability 0.3) at B = 1024 / n simulations (about 1024 agents a step), with the default
  observation (12 + m + n entries an agent: its size grows with n) and the ``portable`` one (14);
* the planner for the container agents (``planner_agents``, K = 16, H = 8): CPU milliseconds per
  decision, median and 95th percentile over the steps of validation episodes (seeds 20000+), the
  steps without a choice included, as a policy would be timed in a plant.

CPU time is ``time.process_time``: a busy machine leaves it about as it is, unlike wall time.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from throughput import _load  # benchmarks/, this script's folder

PLANTS = ("n5_m2_dt120", "n11_m2_dt120", "n16_m2_dt120", "n32_m4_dt120", "n64_m8_dt120", "n128_m16_dt120")
BATCH = 1024


def _cpu_rate(step, items_per_call: int, seconds: float) -> float:
    """Items per CPU-second of ``step()``, called until ``seconds`` of CPU time have passed (after one warm-up call)."""
    step()
    calls, start = 0, time.process_time()
    while (elapsed := time.process_time() - start) < seconds or calls < 3:
        step()
        calls += 1
    return calls * items_per_call / elapsed


def centralised_rate(config: str, batch: int, seconds: float) -> float:
    """Plant steps per CPU-second of the centralised vectorised env."""
    from containergym_marl.envs.vector import ContainerGymVecEnv

    venv = ContainerGymVecEnv(config, num_envs=batch)
    venv.seed(0)
    venv.reset()
    n = venv.simulator.params.n_containers
    rng = np.random.default_rng(0)
    actions = [rng.integers(0, n + 1, size=batch) for _ in range(16)]
    state = {"t": 0}

    def step():
        venv.step_async(actions[state["t"] % 16])
        venv.step_wait()
        state["t"] += 1
    return _cpu_rate(step, batch, seconds)


def agents_rate(config: str, observation: str, seconds: float) -> tuple[float, int]:
    """(plant steps per CPU-second, simulations) of the container agents' vectorised env at about
    BATCH agents a step."""
    from containergym_marl.envs.vector import ContainerAgentsVecEnv

    from containergym_marl import load_config

    n = load_config(config).n_containers
    sims = max(1, BATCH // n)
    venv = ContainerAgentsVecEnv(config, num_sims=sims, observation=observation)
    venv.seed(0)
    venv.reset()
    rng = np.random.default_rng(0)
    actions = [(rng.random(sims * n) < 0.3).astype(np.int64) for _ in range(16)]
    state = {"t": 0}

    def step():
        venv.step_async(actions[state["t"] % 16])
        venv.step_wait()
        state["t"] += 1
    return _cpu_rate(step, sims, seconds), sims


def planner_ms(config: str, steps: int) -> dict:
    """CPU ms per decision of planner_agents over ``steps`` steps of validation episodes."""
    from containergym_marl import container_agents_v1
    from containergym_marl.core.params import PlantParams
    from containergym_marl.evaluation.protocol import VALIDATION
    from containergym_marl.policies import PlannerAgents

    env = container_agents_v1.parallel_env(config, protocol="paper_test")
    planner = PlannerAgents(PlantParams.from_config(env.config))
    observations, _ = env.reset(seed=VALIDATION.first_seed)
    planner.reset(seed=VALIDATION.first_seed)
    times = np.empty(steps)
    for k in range(steps):
        if not env.agents:
            observations, _ = env.reset(seed=VALIDATION.first_seed + k)
            planner.reset(seed=VALIDATION.first_seed + k)
        t0 = time.process_time()
        actions = planner.act(observations, env)
        times[k] = time.process_time() - t0
        observations, *_ = env.step(actions)
    return {"median_ms": float(np.median(times) * 1e3), "p95_ms": float(np.percentile(times, 95) * 1e3),
            "steps": steps}


def measure(plants, seconds: float, planner_steps: int) -> list[dict]:
    from containergym_marl import load_config

    rows = []
    for config in plants:
        plant = load_config(config)
        n, m = plant.n_containers, plant.num_processing_units
        row = {"config": config, "n": n, "m": m}
        for batch in (1, BATCH):
            rate = centralised_rate(config, batch, seconds)
            row[f"central_b{batch}_steps"] = rate
            row[f"central_b{batch}_decisions"] = rate * n
        for observation in ("local", "portable"):
            rate, sims = agents_rate(config, observation, seconds)
            row[f"agents_{observation}_steps"], row["agents_sims"] = rate, sims
            row[f"agents_{observation}_decisions"] = rate * n
        row["planner"] = planner_ms(config, planner_steps)
        rows.append(row)
        print(f"{config}: {row['central_b1024_decisions'] / 1e6:.1f}M container decisions/CPU-s batched, "
              f"planner median {row['planner']['median_ms']:.1f} ms", flush=True)
    return rows


def _m(x: float) -> str:
    return f"{x / 1e6:.2f}M" if x >= 1e5 else f"{x / 1e3:.1f}k"


def markdown(rows: list[dict], command: str, started: str) -> str:
    lines = [f"`{command}` · {started} UTC · {os.cpu_count()} CPUs · load average {_load()} (CPU time, one thread)", "",
             "| plant | n | m | centralised env, B = 1: plant steps/CPU-s | B = 1024: plant steps/CPU-s | "
             "B = 1024: container decisions/CPU-s | agents' env (local obs.): container decisions/CPU-s | "
             "agents' env (portable obs.) | planner_agents: ms CPU per decision, median (95th pct.) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| `{r['config']}` | {r['n']} | {r['m']} | {_m(r['central_b1_steps'])} | "
                     f"{_m(r['central_b1024_steps'])} | {_m(r['central_b1024_decisions'])} | "
                     f"{_m(r['agents_local_decisions'])} | {_m(r['agents_portable_decisions'])} | "
                     f"{r['planner']['median_ms']:.2f} ({r['planner']['p95_ms']:.2f}) |")
    lines += ["", f"The agents' env steps about {BATCH} agents a call ({BATCH} // n simulations); the planner is "
              f"timed over {rows[0]['planner']['steps']} steps of validation episodes from seed 20000 "
              "(δ = 120 s, T = 600), steps without a choice included.", ""]
    return "\n".join(lines)


def draw(rows: list[dict], path: str | Path) -> Path:
    """The table against n, log-log: container decisions per CPU-second of each env path (left), the
    planner's milliseconds per decision, median with the 95th percentile above it (right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = [r["n"] for r in rows]
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    for key, label in (("central_b1", "centralised env, B = 1"), ("central_b1024", f"centralised env, B = {BATCH}"),
                       ("agents_local", "agents' env, local obs."), ("agents_portable", "agents' env, portable obs.")):
        left.plot(n, [r[f"{key}_decisions"] for r in rows], marker="o", label=label)
    left.set(xscale="log", yscale="log", xlabel="containers n", ylabel="container decisions per CPU-second",
             title="Environment throughput, one core")
    left.legend(fontsize=8)
    median = np.array([r["planner"]["median_ms"] for r in rows])
    p95 = np.array([r["planner"]["p95_ms"] for r in rows])
    right.errorbar(n, median, yerr=[np.zeros_like(median), p95 - median], marker="o", capsize=3)
    right.set(xscale="log", yscale="log", xlabel="containers n", ylabel="ms CPU per decision",
              title="planner_agents (K = 16, H = 8): median, 95th pct.")
    for ax in (left, right):
        ax.set_xticks(n, [str(k) for k in n])
        ax.minorticks_off()
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv=None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--plants", nargs="+", default=list(PLANTS))
    p.add_argument("--seconds", type=float, default=2.0, help="CPU seconds per env measurement")
    p.add_argument("--planner-steps", type=int, default=300)
    p.add_argument("--smoke", action="store_true", help="two small plants, tiny measurements")
    p.add_argument("--json", default=None)
    p.add_argument("--md", default=None, help="also write the table to this file")
    p.add_argument("--figure", default=None, help="also draw the table against n to this PNG file")
    p.add_argument("--from-json", default=None, help="measure nothing: draw --figure from this --json file")
    ns = p.parse_args(argv)
    if ns.from_json:
        if not ns.figure:
            p.error("--from-json draws a figure: give --figure")
        rows = json.loads(Path(ns.from_json).read_text())
        print(f"wrote {draw(rows, ns.figure)}")
        return rows
    import numba
    import torch

    numba.set_num_threads(1)
    torch.set_num_threads(1)
    if ns.smoke:
        ns.plants, ns.seconds, ns.planner_steps = ["n5_m2_dt120", "n32_m4_dt120"], 0.05, 3
    started = time.strftime("%Y-%m-%d %H:%M", time.gmtime())
    rows = measure(ns.plants, ns.seconds, ns.planner_steps)
    command = "python benchmarks/scaling.py" + (" --smoke" if ns.smoke else "")
    text = markdown(rows, command, started)
    print(text)
    if ns.md:
        Path(ns.md).parent.mkdir(parents=True, exist_ok=True)
        Path(ns.md).write_text(text)
    if ns.json:
        Path(ns.json).write_text(json.dumps(rows, indent=1) + "\n")
    if ns.figure:
        draw(rows, ns.figure)
    return rows


if __name__ == "__main__":
    main()
