"""DAgger's labels, one planner at a time against every simulation's look-ahead in one batch, side by side.

    python benchmarks/labelling.py                                  # n11_m2_dt120 and n16_m2_dt120, ~2 minutes
    python benchmarks/labelling.py --configs n16_m2_dt120 --labels response --safety-risk 1e-6
    python benchmarks/labelling.py --smoke                          # seconds, numbers meaningless

DAgger labels every agent of ``--sims`` simulations at every step with ``planner_agents``' decision
(:class:`~containergym_marl.training.dagger.Labeller`; ``--labels response``: each agent's best response
to the others' requests). Each side labels the same ``--steps`` steps of those simulations from the
same start, the simulations driven by the labels themselves (``response``: by requests drawn at 5 %
from a fixed seed), with fresh planners of the same seeds:

* **one at a time**: ``planner.decide`` (``respond``) per simulation, each look-ahead its own batch of
  the compiled step (how the labels were computed before :func:`~containergym_marl.policies.planner.decide_all`);
* **batched**: :func:`~containergym_marl.policies.planner.decide_all` (``respond_all``), every
  simulation's look-ahead in one batch, what the labeller calls.

CPU time is this process's (``time.process_time``), wall time ``time.perf_counter``; both exclude the
first, untimed round (compilation). The sides alternate within each round, and each ratio is the
median over rounds of one-at-a-time / batched, so a busy machine slows both alike. The labels of both
sides are hashed: the table says whether they are identical (they must be: the batch changes only
how the futures are stepped, not what is simulated).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import statistics
import time
from pathlib import Path

import numpy as np

from containergym_marl.config import load_config
from containergym_marl.core.simulator import PlantSimulator
from containergym_marl.policies.planner import PlannerAgents, decide_all, respond_all

LABEL_SEED = 7  # the planners' seed (planner b: LABEL_SEED + b), as a Labeller seeds them
REQUEST_RATE = 0.05  # share of agents requesting where the labels are best responses


def label_steps(config: str, sims: int, steps: int, labels: str, safety_risk: float | None, batched: bool) -> dict:
    """Label ``steps`` steps of ``sims`` simulations; CPU and wall seconds of the labelling alone."""
    simulator = PlantSimulator(load_config(config), num_sims=sims)
    simulator.reset(generators=[np.random.default_rng(1000 + b) for b in range(sims)])
    params = simulator.params
    planners = [PlannerAgents(safety_risk=safety_risk) for _ in range(sims)]
    for b, planner in enumerate(planners):
        planner.reset(LABEL_SEED + b)
    requests_rng = np.random.default_rng(5)
    digest, cpu, wall = hashlib.sha256(), 0.0, 0.0
    for _ in range(steps):
        state = simulator.state
        requests = requests_rng.random((sims, params.n_containers)) < REQUEST_RATE if labels == "response" else None
        c0, w0 = time.process_time(), time.perf_counter()
        if batched:
            out = decide_all(planners, state, params) if requests is None else respond_all(planners, state, params,
                                                                                            requests)
        else:
            out = np.stack([p.decide(state.select(slice(b, b + 1)), params) if requests is None
                            else p.respond(state.select(slice(b, b + 1)), params, requests[b])
                            for b, p in enumerate(planners)])
        cpu, wall = cpu + time.process_time() - c0, wall + time.perf_counter() - w0
        digest.update(out.tobytes())
        outcome = simulator.step(out if requests is None else requests)
        done = outcome.terminated | outcome.truncated
        if done.any():
            simulator.reset(np.flatnonzero(done))
    return {"cpu_s": cpu, "wall_s": wall, "planned": sum(p.planned for p in planners),
            "labels_sha256": digest.hexdigest()}


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--configs", nargs="+", default=["n11_m2_dt120", "n16_m2_dt120"])
    p.add_argument("--sims", type=int, default=64, help="simulations labelled together (DAgger's default)")
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--labels", choices=("planner", "response"), default="planner")
    p.add_argument("--safety-risk", type=float, default=None, help="the planner's deadline check (e.g. 1e-6)")
    p.add_argument("--smoke", action="store_true", help="4 simulations, 3 steps, 1 round")
    p.add_argument("--json", default=None)
    ns = p.parse_args(argv)
    if ns.smoke:
        ns.sims, ns.steps, ns.rounds = 4, 3, 1
    lines = [f"# DAgger's labels ({ns.labels}, deadline check {ns.safety_risk}): {ns.sims} simulations, "
             f"{ns.steps} steps, {ns.rounds} round(s)", "",
             "| config | planned decisions | one at a time: CPU ms / planned | batched | "
             "ratio, CPU (each round) | ratio, wall | labels |", "|---|---|---|---|---|---|---|"]
    summary: dict = {"sims": ns.sims, "steps": ns.steps, "rounds": ns.rounds, "labels": ns.labels,
                     "safety_risk": ns.safety_risk, "configs": {}}
    for config in ns.configs:
        args = (config, ns.sims, ns.steps, ns.labels, ns.safety_risk)
        label_steps(config, 2, 2, ns.labels, ns.safety_risk, True)  # compile, untimed
        label_steps(config, 2, 2, ns.labels, ns.safety_risk, False)
        rounds = [(label_steps(*args, batched=False), label_steps(*args, batched=True)) for _ in range(ns.rounds)]
        cpu = [one["cpu_s"] / batch["cpu_s"] for one, batch in rounds]
        wall = [one["wall_s"] / batch["wall_s"] for one, batch in rounds]
        planned = rounds[0][0]["planned"]
        same = all(one["labels_sha256"] == batch["labels_sha256"] for one, batch in rounds)
        per = {side: statistics.median(r[k]["cpu_s"] for r in rounds) * 1000 / max(planned, 1)
               for k, side in enumerate(("one_at_a_time", "batched"))}
        summary["configs"][config] = {"planned": planned, "cpu_ms_per_planned": per, "cpu_ratio": statistics.median(cpu),
                                      "wall_ratio": statistics.median(wall), "identical_labels": same,
                                      "rounds": rounds}
        lines.append(f"| {config} | {planned:,} | {per['one_at_a_time']:.3f} | {per['batched']:.3f} | "
                     f"{statistics.median(cpu):.2f}x ({', '.join(f'{r:.2f}' for r in cpu)}) | "
                     f"{statistics.median(wall):.2f}x | {'identical' if same else 'DIFFERENT'} |")
    print("\n".join(lines))
    if ns.json:
        Path(ns.json).write_text(json.dumps(summary, indent=1) + "\n")
    return summary


if __name__ == "__main__":
    main()
