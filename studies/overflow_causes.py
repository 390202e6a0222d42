"""Why learned container agents overflow: each overflowing episode of each run, by cause.

    python studies/overflow_causes.py RUN_DIR ...                  # best models, 30 validation episodes
    python studies/overflow_causes.py results/paper_rows/runs/dagger_agents_n11_m2_dt120_s* --out results/x

Evaluates each run's best model (a shared container-agent policy, ``.pt``) with the paper's test
protocol on the *validation* episodes (seeds 20000+: none of them a test episode, so every seed's
failures count, not only the best seed's) and sorts each overflowing episode by
``planner_figures.overflow_causes``: the overflowing container's request was *denied* in its last
10 steps (another agent's request got the free PU: the agents did not coordinate), it was ready
with a PU free and *not requested*, or *no PU was free* while it was ready. Writes ``--out``/causes.json
(per run) and causes.md (per method and row).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from containergym_marl.core.dynamics import DEFAULT_ARBITRATION
from containergym_marl.files import atomic_write_text
from containergym_marl.orchestration.stopping import exit_on_sigterm, worker_pool

CAUSES = ("denied", "not_requested", "no_free_pu")


def run_causes(args: tuple[str, int]) -> dict:
    import torch

    from containergym_marl.algorithms import REGISTRY
    from containergym_marl.core.params import PlantParams
    from containergym_marl.evaluation import EvalProtocol, evaluate
    from containergym_marl.evaluation.protocol import VALIDATION
    from containergym_marl.evaluation.run_policies import policy_from_run
    from containergym_marl.rundir import run_args
    from planner_figures import overflow_causes

    torch.set_num_threads(1)
    run, episodes = args
    saved = run_args(run)
    protocol = EvalProtocol(episodes=episodes, first_seed=VALIDATION.first_seed)
    result = evaluate(policy_from_run(run, "best"), saved["config"], protocol,
                      arbitration=saved.get("arbitration", DEFAULT_ARBITRATION))
    params = PlantParams.from_config(protocol.plant(saved["config"]))
    return {"run": Path(run).name, "method": REGISTRY[saved["algo"]].method_name(saved.get("reward_mode")),
            "row": saved["config"],
            "seed": saved["seed"], "episodes": episodes, "first_seed": protocol.first_seed,
            "return_mean": float(result.returns.mean()),
            "overflowing_episodes": int(sum(e.overflow for e in result.episodes)),
            "causes": overflow_causes(result.records, params)}


def report(entries: list[dict]) -> str:
    lines = ["# Why learned container agents overflow", "",
             "`python studies/overflow_causes.py`: each run's best model on validation episodes (δ = 120 s, "
             "T = 600, seeds 20000+); each overflowing episode sorted by what the overflowing container met in its "
             "last 10 steps: its request *denied* (another agent's request got the free PU), ready with a PU free "
             "and *not requested*, or *no PU free*.", "",
             "| method | row | seeds | episodes | overflowing | denied | not requested | no free PU |",
             "|---|---|---|---|---|---|---|---|"]
    groups: dict[tuple[str, str], list[dict]] = {}
    for e in entries:
        groups.setdefault((e["method"], e["row"]), []).append(e)
    for (method, row), group in sorted(groups.items()):
        total = {c: sum(e["causes"][c] for e in group) for c in CAUSES}
        lines.append(f"| `{method}` | `{row}` | {len(group)} | {sum(e['episodes'] for e in group)} | "
                     f"{sum(e['overflowing_episodes'] for e in group)} | "
                     + " | ".join(str(total[c]) for c in CAUSES) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+", help="run directories (their best_model.pt)")
    p.add_argument("--episodes", type=int, default=30)
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    p.add_argument("--out", default="results/overflow_causes")
    ns = p.parse_args(argv)
    missing = [r for r in ns.runs if not (Path(r) / "best_model.pt").is_file()]
    if missing:
        raise SystemExit(f"no best_model.pt in: {', '.join(missing)}")
    with worker_pool(ns.workers) as pool:
        entries = list(pool.map(run_causes, [(r, ns.episodes) for r in ns.runs]))
    out = Path(ns.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "causes.json", json.dumps({"entries": entries}, indent=1) + "\n")
    atomic_write_text(out / "causes.md", report(entries))
    print(report(entries))


if __name__ == "__main__":
    exit_on_sigterm()  # stopped by SIGTERM, the study's workers stop with it
    main()
