"""How the native PPO's default batch shape was chosen: a small sweep on validation episodes.

    python studies/fast_ppo_defaults.py                 # the committed sweep (resumable)
    python studies/fast_ppo_defaults.py --rows n5_m2_dt120 --seeds 1 --variants wide

Trains ``fast_ppo`` and ``fast_shared_ppo`` with each batch-shape variant below at the paper's budget
(2M samples for n = 5, 5M for n >= 11), one torch thread per run, then evaluates each run's best
model on the *validation* episodes (seeds 20000-20029, δ = 120 s, T = 600; never the test seeds
10000-10014). Writes ``--out``/defaults.json and defaults.md: validation return per run, the mean
per variant, and each run's training wall time and CPU time. Finished runs in ``--runs`` are
reused, so an interrupted sweep continues where it stopped.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from containergym_marl.evaluation import evaluate
from containergym_marl.evaluation.protocol import VALIDATION
from containergym_marl.evaluation.run_policies import policy_from_run
from containergym_marl.training import TrainArgs, train
from containergym_marl.rundir import read_run_summary, run_name, run_status

#: The batch shapes tried (``--hp`` settings; 64 simulations each), against a start of 64 steps per
#: rollout and minibatches of 4096 ("wide"): smaller minibatches (4x and 8x the gradient steps),
#: a longer rollout (half the updates), a shorter rollout with smaller minibatches, and half the
#: epochs with smaller minibatches (the gradient steps of a wider minibatch at half the compute).
VARIANTS = {
    "wide": {"n_steps": 64, "minibatch_size": 4096},
    "mb1024": {"n_steps": 64, "minibatch_size": 1024},
    "mb512": {"n_steps": 64, "minibatch_size": 512},
    "steps128": {"n_steps": 128, "minibatch_size": 4096},
    "steps32_mb1024": {"n_steps": 32, "minibatch_size": 1024},
    "mb1024_e5": {"n_steps": 64, "minibatch_size": 1024, "n_epochs": 5},
    "mb512_e5": {"n_steps": 64, "minibatch_size": 512, "n_epochs": 5},
}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rows", nargs="+", default=["n11_m2_dt120", "n5_m2_dt120"])
    p.add_argument("--algos", nargs="+", default=["fast_shared_ppo", "fast_ppo"])
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    p.add_argument("--runs", default="runs/fast_ppo_defaults")
    p.add_argument("--out", default="studies/fast_ppo_defaults")
    p.add_argument("--report-only", action="store_true", help="train nothing: report the finished runs only")
    ns = p.parse_args(argv)
    out = Path(ns.out)
    out.mkdir(parents=True, exist_ok=True)
    entries = []
    for row in ns.rows:
        for algo in ns.algos:
            for variant in ns.variants:
                for seed in ns.seeds:
                    run = Path(ns.runs) / run_name(f"{algo}_{variant}", row, seed)
                    status = run_status(run)
                    if status != "finished" and ns.report_only:
                        continue
                    if status != "finished":
                        cpu = time.process_time()
                        train(TrainArgs(algo=algo, config=row, seed=seed, out=str(run), resume=status == "interrupted",
                                        hyperparams=dict(VARIANTS[variant]), progress_bar=False))
                        (run / "cpu_time_s.txt").write_text(f"{time.process_time() - cpu:.1f}\n")
                    cached = run / "validation.json"  # one evaluation per run, reused by later reports
                    if cached.is_file():
                        entries.append(json.loads(cached.read_text()))
                        continue
                    result = evaluate(policy_from_run(run), row, VALIDATION, keep_records=False)
                    summary = read_run_summary(run)
                    cpu_file = run / "cpu_time_s.txt"
                    entries.append({"row": row, "algo": algo, "variant": variant, "seed": seed,
                                    "validation_return": float(result.returns.mean()),
                                    "overflowing_episodes": int(sum(e.overflow for e in result.episodes)),
                                    "samples": summary["timesteps"], "wall_time_s": summary["wall_time_s"],
                                    "cpu_time_s": float(cpu_file.read_text()) if cpu_file.is_file() else None})
                    cached.write_text(json.dumps(entries[-1]) + "\n")
                    print(json.dumps(entries[-1]), flush=True)
    meta = {"validation_seeds": VALIDATION.seeds[:1] + VALIDATION.seeds[-1:], "episodes": VALIDATION.episodes,
            "variants": {v: VARIANTS[v] for v in ns.variants}}
    (out / "defaults.json").write_text(json.dumps({"meta": meta, "runs": entries}, indent=1) + "\n")
    lines = ["# Native PPO batch shapes on validation episodes", "",
             f"Best model of each run on validation seeds {VALIDATION.first_seed}-{VALIDATION.seeds[-1]} "
             f"(δ = 120 s, T = 600), paper budgets, one torch thread per run. Generated by "
             f"`python studies/fast_ppo_defaults.py`. Wall times are rough: two or three runs shared the "
             f"machine's 2 cores, and the first variants trained before the networks' tanh went through the "
             f"sigmoid (1.13-1.17x more CPU time, benchmarks/RESULTS.md run 10).", "",
             "| row | algorithm | variant | settings | validation return per seed | mean | overflowing episodes "
             "| wall s per run |", "|---|---|---|---|---|---|---|---|"]
    for row in ns.rows:
        for algo in ns.algos:
            for variant in ns.variants:
                group = [e for e in entries if (e["row"], e["algo"], e["variant"]) == (row, algo, variant)]
                if not group:
                    continue
                returns = [e["validation_return"] for e in group]
                lines.append(f"| {row} | {algo} | {variant} | {VARIANTS[variant]} | "
                             f"{', '.join(f'{r:.1f}' for r in returns)} | {np.mean(returns):.1f} | "
                             f"{sum(e['overflowing_episodes'] for e in group)} | "
                             f"{np.mean([e['wall_time_s'] for e in group]):.0f} |")
    (out / "defaults.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
