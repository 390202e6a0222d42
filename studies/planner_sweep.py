"""The planner's return against its look-ahead budget: futures K × horizon H on one row.

    python studies/planner_sweep.py                       # n11_m2_dt120, validation seeds 20000-20004
    python studies/planner_sweep.py --row n16_m2_dt120 --futures 16 --horizons 4 8 16

Runs ``planner_agents`` (or ``--view centralised``) for every (K, H) with the paper's δ = 120 s and
T = 600 on *validation* seeds (default 20000–20004, not the test seeds 10000–10014: this is where the
defaults were chosen), and writes ``--out``/sweep_<row>.json and .md: mean return, overflowing
episodes and CPU time per step for each setting.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from containergym_marl.evaluation import EvalProtocol, evaluate
from containergym_marl.policies import PlannerAgents, RolloutPlanner


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--row", default="n11_m2_dt120")
    p.add_argument("--view", choices=("decentralised", "centralised"), default="decentralised")
    p.add_argument("--futures", type=int, nargs="+", default=[4, 16, 64])
    p.add_argument("--horizons", type=int, nargs="+", default=[2, 4, 8, 16, 32])
    p.add_argument("--episodes", type=int, default=5)
    p.add_argument("--first-seed", type=int, default=20_000)
    p.add_argument("--episode-length-steps", type=int, default=600, help="T (600: the paper's test protocol)")
    p.add_argument("--out", default="results/planner")
    ns = p.parse_args(argv)
    cls = PlannerAgents if ns.view == "decentralised" else RolloutPlanner
    protocol = EvalProtocol(episodes=ns.episodes, first_seed=ns.first_seed, episode_length_steps=ns.episode_length_steps)
    evaluate(cls(futures=4, horizon=2), ns.row, EvalProtocol(episodes=1, episode_length_steps=20, first_seed=1),
             keep_records=False)  # warm-up: load the compiled kernels
    entries = []
    for k in ns.futures:
        for h in ns.horizons:
            planner = cls(futures=k, horizon=h)
            cpu = time.process_time()
            result = evaluate(planner, ns.row, protocol, keep_records=False)
            cpu = time.process_time() - cpu
            returns = result.returns
            entries.append({"futures": k, "horizon": h, "return_mean": float(returns.mean()),
                            "return_std": float(returns.std()), "returns": returns.tolist(),
                            "overflowing_episodes": int(sum(e.overflow for e in result.episodes)),
                            "cpu_ms_per_step": 1e3 * cpu / sum(e.steps for e in result.episodes)})
            print(f"K={k:3d} H={h:3d}  return {returns.mean():7.2f} ± {returns.std():5.2f}  overflows "
                  f"{entries[-1]['overflowing_episodes']}  {entries[-1]['cpu_ms_per_step']:.2f} ms CPU/step", flush=True)
    out = Path(ns.out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"row": ns.row, "view": ns.view, "episodes": ns.episodes, "first_seed": ns.first_seed,
            "timestep_s": protocol.timestep_s, "episode_length_steps": protocol.episode_length_steps}
    (out / f"sweep_{ns.row}.json").write_text(json.dumps({"meta": meta, "settings": entries}, indent=1) + "\n")
    table = {(e["futures"], e["horizon"]): e for e in entries}
    lines = [f"# {cls.name} on {ns.row}: return against futures K and horizon H", "",
             f"Validation seeds {ns.first_seed}–{ns.first_seed + ns.episodes - 1} (not the test seeds), δ = 120 s, "
             f"T = {protocol.episode_length_steps}; mean return over the episodes (overflowing episodes in "
             "brackets when any), CPU ms per step below.", "",
             "| K \\ H | " + " | ".join(str(h) for h in ns.horizons) + " |",
             "|---" * (len(ns.horizons) + 1) + "|"]
    for k in ns.futures:
        cells = []
        for h in ns.horizons:
            e = table[(k, h)]
            flag = f" ({e['overflowing_episodes']})" if e["overflowing_episodes"] else ""
            cells.append(f"{e['return_mean']:.2f}{flag}<br>{e['cpu_ms_per_step']:.1f} ms")
        lines.append(f"| {k} | " + " | ".join(cells) + " |")
    best = max(entries, key=lambda e: e["return_mean"])
    lines += ["", f"Best: K = {best['futures']}, H = {best['horizon']} ({best['return_mean']:.2f}); the spread "
              f"between episodes (std {np.mean([e['return_std'] for e in entries]):.2f} on average) is larger "
              "than most differences between neighbouring settings, but the episodes are the same for every "
              "setting, so the comparison is paired.", ""]
    (out / f"sweep_{ns.row}.md").write_text("\n".join(lines))
    print(f"wrote {out / f'sweep_{ns.row}.md'}")


if __name__ == "__main__":
    main()
