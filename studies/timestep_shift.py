"""How much of the δ = 60 s rows' overflows the test protocol's δ = 120 s causes (issue 34).

    python studies/timestep_shift.py                       # the four δ = 60 s rows, the native PPO methods
    python studies/timestep_shift.py --rows n5_m2_dt60 --methods fast_shared_ppo --seeds 1 2 --episodes 20
    python studies/timestep_shift.py --smoke               # one row, one method, two seeds, 4 episodes

A policy of a ``_dt60`` row is trained at δ = 60 s and tested, as the paper tests every row, at δ = 120 s:
between two of its decisions a container fills twice as much as it ever did in training. This study evaluates
each published seed's standing model (``results/paper_rows/runs``, the model every table reads) on the same
validation episodes (seeds 20000+, none of them a test or fresh episode) twice: at the test protocol's plant
(δ = 120 s, T = 600) and at the row's own δ = 60 s over the same plant time (T = 1200), beside
``rule_based_agents`` at both. Per (row, method) it reports the mean return, the overflowing episodes per 100
and the seeds whose overflow rate is above the rule's at each δ: the issue's overflow criterion, asked at the
δ the policies were trained at. Writes ``--out``/shift.json (per seed, after every one: resumable) and shift.md.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from containergym_marl.files import atomic_write_text
from containergym_marl.orchestration.stopping import exit_on_sigterm, worker_pool

REPO = Path(__file__).resolve().parents[1]
ROWS = ("n5_m2_dt60", "n5_m5_dt60", "n11_m2_dt60", "n11_m11_dt60")
METHODS = ("fast_ppo", "fast_shared_ppo", "fast_shared_ppo_team")
RULE = "rule_based_agents"
#: name -> (δ in seconds, T in steps): the test protocol's plant, and the training δ over the same plant time
TIMESTEPS = {"test_dt120": (120.0, 600), "own_dt60": (60.0, 1200)}


def evaluate_one(job: tuple[str, str, int, str, int]) -> dict:
    """One (row, method, seed)'s standing model, or the rule (seed 0), at both timesteps."""
    import torch

    from containergym_marl.core.params import PlantParams
    from containergym_marl.evaluation.batched import evaluate_batched
    from containergym_marl.evaluation.protocol import VALIDATION, EvalProtocol, evaluate
    from containergym_marl.evaluation.run_policies import evaluated_which, policy_from_run
    from containergym_marl.methods import get_method

    torch.set_num_threads(1)
    row, method, seed, runs, episodes = job
    entry = {"row": row, "method": method, "seed": seed, "episodes": episodes, "first_seed": VALIDATION.first_seed}
    run = Path(runs) / f"{method}_{row}_s{seed}"
    if method != RULE:
        entry["model"] = evaluated_which(run)
    for name, (timestep_s, steps) in TIMESTEPS.items():
        protocol = EvalProtocol(timestep_s=timestep_s, episode_length_steps=steps, episodes=episodes,
                                first_seed=VALIDATION.first_seed)
        if method == RULE:
            policy = get_method(RULE).controller(PlantParams.from_config(protocol.plant(row)))
            result = evaluate(policy, row, protocol, keep_records=False)
        else:
            result = evaluate_batched(policy_from_run(run, entry["model"]), row, protocol)
        summary = result.summary()
        entry[name] = {"return_mean": summary["return_mean"],
                       "overflowing_episodes": round(summary["overflow_rate"] * episodes)}
    return entry


def report(entries: list[dict]) -> dict:
    """Per (row, method): seeds, mean return and overflowing episodes per 100 at each δ, seeds above the rule."""
    rule = {e["row"]: e for e in entries if e["method"] == RULE}
    groups: dict[tuple[str, str], list[dict]] = {}
    for e in entries:
        if e["method"] != RULE:
            groups.setdefault((e["row"], e["method"]), []).append(e)
    cells = []
    for (row, method), seeds in groups.items():
        cell = {"row": row, "method": method, "seeds": len(seeds)}
        for name in TIMESTEPS:
            cell[name] = {
                "return_mean": sum(s[name]["return_mean"] for s in seeds) / len(seeds),
                "overflowing_per_100": 100 * sum(s[name]["overflowing_episodes"] for s in seeds)
                / sum(s["episodes"] for s in seeds),
                "rule_overflowing_per_100": (100 * rule[row][name]["overflowing_episodes"] / rule[row]["episodes"]
                                             if row in rule else None),
                "seeds_above_rule": (sum(s[name]["overflowing_episodes"] / s["episodes"]
                                         > rule[row][name]["overflowing_episodes"] / rule[row]["episodes"]
                                         for s in seeds) if row in rule else None)}
        cells.append(cell)
    return {"timesteps": {k: {"timestep_s": v[0], "episode_length_steps": v[1]} for k, v in TIMESTEPS.items()},
            "cells": cells}


def markdown(summary: dict, episodes: int) -> str:
    def above(c, name):
        return "–" if c[name]["seeds_above_rule"] is None else f"{c[name]['seeds_above_rule']} of {c['seeds']}"

    lines = ["# The δ = 60 s rows at the test protocol's δ and at their own", "",
             "`python studies/timestep_shift.py`: each published seed's standing model on the same "
             f"{episodes} validation episodes (seeds 20000+) at the test protocol's plant (δ = 120 s, T = 600) and at "
             "the row's training δ over the same plant time (δ = 60 s, T = 1200). Per cell: mean return over seeds, "
             "overflowing episodes per 100 (all seeds' episodes), and the seeds whose overflow rate is above "
             "`rule_based_agents`' on the same episodes and δ (the rule's own rates below the table).", "",
             "| row | method | seeds | return, 120 s | return, 60 s | overflowing per 100, 120 s | "
             "overflowing per 100, 60 s | seeds above the rule, 120 s | seeds above the rule, 60 s |",
             "|---|---|---|---|---|---|---|---|---|"]
    for c in summary["cells"]:
        t, o = c["test_dt120"], c["own_dt60"]
        lines.append(f"| {c['row']} | `{c['method']}` | {c['seeds']} | {t['return_mean']:.2f} | {o['return_mean']:.2f} | "
                     f"{t['overflowing_per_100']:.1f} | {o['overflowing_per_100']:.1f} | {above(c, 'test_dt120')} | "
                     f"{above(c, 'own_dt60')} |")
    rules = {c["row"]: c for c in summary["cells"]}
    lines += ["", "`rule_based_agents` overflowing per 100: " + ", ".join(
        f"{row} {c['test_dt120']['rule_overflowing_per_100']:.1f} at 120 s and {c['own_dt60']['rule_overflowing_per_100']:.1f}"
        " at 60 s" for row, c in rules.items() if c["test_dt120"]["rule_overflowing_per_100"] is not None) + "."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rows", nargs="+", default=list(ROWS))
    p.add_argument("--methods", nargs="+", default=list(METHODS))
    p.add_argument("--seeds", nargs="+", type=int, default=list(range(1, 16)))
    p.add_argument("--episodes", type=int, default=100, help="validation episodes (seeds 20000 on)")
    p.add_argument("--runs", type=Path, default=REPO / "results" / "paper_rows" / "runs")
    p.add_argument("--out", type=Path, default=REPO / "results" / "timestep_shift")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    p.add_argument("--smoke", action="store_true", help="one row, one method, two seeds, 4 episodes")
    ns = p.parse_args(argv)
    if ns.smoke:
        ns.rows, ns.methods, ns.seeds, ns.episodes = ["n5_m2_dt60"], ["fast_shared_ppo"], [1, 2], 4
    for row in ns.rows:
        if not row.endswith("_dt60"):
            raise SystemExit(f"--rows: {row} is not a δ = 60 s row")
    missing = [f"{m}_{r}_s{s}" for r in ns.rows for m in ns.methods for s in ns.seeds
               if not (ns.runs / f"{m}_{r}_s{s}").is_dir()]
    if missing:
        raise SystemExit(f"--runs {ns.runs}: no run {missing[0]}" + (f" (and {len(missing) - 1} more)" if missing[1:] else ""))
    ns.out.mkdir(parents=True, exist_ok=True)
    path = ns.out / "shift.json"
    saved = json.loads(path.read_text())["entries"] if path.is_file() else []
    entries = [e for e in saved if e["episodes"] == ns.episodes]
    done = {(e["row"], e["method"], e["seed"]) for e in entries}
    jobs = [(r, RULE, 0, str(ns.runs), ns.episodes) for r in ns.rows]
    jobs += [(r, m, s, str(ns.runs), ns.episodes) for r in ns.rows for m in ns.methods for s in ns.seeds]
    jobs = [j for j in jobs if j[:3] not in done]
    order = {(r, m): i for i, (r, m) in enumerate((r, m) for r in ns.rows for m in (RULE, *ns.methods))}

    def save():
        entries.sort(key=lambda e: (order.get((e["row"], e["method"]), len(order)), e["seed"]))
        atomic_write_text(path, json.dumps({"entries": entries}, indent=1) + "\n")

    with worker_pool(ns.workers) as pool:
        for entry in pool.map(evaluate_one, jobs):
            entries.append(entry)
            print(entry["row"], entry["method"], entry["seed"], entry["test_dt120"], entry["own_dt60"], flush=True)
            save()
    save()
    summary = report(entries)
    atomic_write_text(ns.out / "shift.md", markdown(summary, ns.episodes))
    print(markdown(summary, ns.episodes))
    return summary


if __name__ == "__main__":
    exit_on_sigterm()
    main()
