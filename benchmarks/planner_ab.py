"""The rollout planner of this checkout against another checkout's, side by side: the same validation
episodes decided by both, in fresh processes, alternated.

    python benchmarks/planner_ab.py --other /path/to/other/checkout          # planner_agents, n11_m2_dt120
    python benchmarks/planner_ab.py --other ../old --planner planner --config n16_m2_dt120 --episodes 4
    python benchmarks/planner_ab.py --other . --episodes 1 --rounds 1        # the smoke test: seconds

Each side evaluates the planner (``--planner``: a name of the planner registry's container-agent or
centralised planners) on ``--episodes`` validation episodes (seeds 20000 + k, the paper's δ and T)
with ``containergym_marl.evaluation.evaluate``, in a new Python process whose ``PYTHONPATH`` is the
checkout. It reports the CPU seconds of the evaluation alone (``time.process_time``: start-up, imports
and the first compilation left out: one episode runs first, untimed), the planner's planned decisions
(those that needed a look-ahead) and the CPU per planned decision, and a hash of every episode's
requests and rewards, so the two sides are also shown to decide the same (or not). The sides alternate
(this, other, this, …) so a busy machine slows both alike; the ratio is the median over rounds of
other / this.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PLANNERS = ("planner_agents", "planner_agents_shielded", "planner", "planner_shielded")
CHILD = r"""
import dataclasses, hashlib, json, sys, time
import numpy as np
from containergym_marl.evaluation import evaluate
from containergym_marl.evaluation.protocol import VALIDATION
from containergym_marl.policies import planner as planners
from containergym_marl.core.params import PlantParams
name, config, episodes = sys.argv[1], sys.argv[2], int(sys.argv[3])
cls = {c.name: c for c in (planners.RolloutPlanner, planners.PlannerAgents, planners.ShieldedPlanner,
                           planners.ShieldedPlannerAgents)}[name]
params = PlantParams.from_config(VALIDATION.plant(config))
evaluate(cls(params), config, dataclasses.replace(VALIDATION, episodes=1))  # compile, untimed
policy = cls(params)
start = time.process_time()
result = evaluate(policy, config, dataclasses.replace(VALIDATION, episodes=episodes))
cpu = time.process_time() - start
digest = hashlib.sha256()
for record in result.records:
    digest.update(np.asarray(record.requested).tobytes())
    digest.update(np.asarray(record.plant_reward).tobytes())
print(json.dumps({"cpu_s": cpu, "planned": policy.planned, "decisions": policy.decisions,
                  "episodes_sha256": digest.hexdigest()}))
"""


def one_side(checkout: Path, planner: str, config: str, episodes: int) -> dict:
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    proc = subprocess.run([sys.executable, "-c", CHILD, planner, config, str(episodes)], env=env,
                          capture_output=True, text=True, check=True, cwd=checkout)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--other", required=True, type=Path, help="the other checkout (a git worktree of another commit)")
    p.add_argument("--planner", default="planner_agents", choices=PLANNERS)
    p.add_argument("--config", default="n11_m2_dt120")
    p.add_argument("--episodes", type=int, default=3)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--json", default=None, help="also write the measurements here")
    ns = p.parse_args(argv)
    if ns.episodes < 1 or ns.rounds < 1:
        raise SystemExit("--episodes and --rounds: at least 1")
    sides = {"this": REPO, "other": ns.other.resolve()}
    results: dict[str, list[dict]] = {name: [] for name in sides}
    for _ in range(ns.rounds):
        for name, checkout in sides.items():
            results[name].append(one_side(checkout, ns.planner, ns.config, ns.episodes))
    ratios = [o["cpu_s"] / t["cpu_s"] for t, o in zip(results["this"], results["other"])]
    same = {r["episodes_sha256"] for side in results.values() for r in side}
    lines = [f"# {ns.planner} on {ns.config}, {ns.episodes} validation episode(s) per side, {ns.rounds} round(s)", "",
             "| checkout | CPU s (each round) | planned decisions | CPU ms per planned decision (median) |",
             "|---|---|---|---|"]
    for name, runs in results.items():
        each = ", ".join(format(r["cpu_s"], ".2f") for r in runs)
        per = statistics.median(1e3 * r["cpu_s"] / max(r["planned"], 1) for r in runs)
        lines.append(f"| {name} ({sides[name]}) | {each} | {runs[0]['planned']:,} of {runs[0]['decisions']:,} | {per:.3f} |")
    lines += ["", f"other / this CPU time: {statistics.median(ratios):.2f}x (median of "
              f"{', '.join(format(x, '.2f') for x in ratios)}); episodes (requests and rewards) "
              + ("identical" if len(same) == 1 else "differ") + " on both sides"]
    print("\n".join(lines))
    report = {"planner": ns.planner, "config": ns.config, "episodes": ns.episodes, "runs": results,
              "ratio_median": statistics.median(ratios), "identical_episodes": len(same) == 1}
    if ns.json:
        Path(ns.json).write_text(json.dumps(report, indent=1) + "\n")
    return report


if __name__ == "__main__":
    main()
