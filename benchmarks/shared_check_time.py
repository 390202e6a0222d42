"""The decision time of a container-agent policy with the agents' shared check and without, side by side.

    python benchmarks/shared_check_time.py        # dagger_checked_agents' published best model, n11_m2_dt120
    python benchmarks/shared_check_time.py --config n16_m2_dt120 --json out.json
    python benchmarks/shared_check_time.py --method dagger_messaging_agents    # the method trained with the check
    python benchmarks/shared_check_time.py --rounds 1 --steps 50          # the smoke test: seconds

Each round times ``policy.act`` per plant step (all agents at once, one torch thread, through the PettingZoo
env, :func:`~containergym_marl.evaluation.decision_time.decision_times_ms`) over ``--steps`` steps from
validation seed 20000: the model as published, then the same network with the shared check
(:data:`~containergym_marl.policies.shared_check.SHARED_CHECK`; the order alternates). It prints the median,
mean and 99th percentile of the wall milliseconds per decision of each, the CPU seconds of each round
(``time.process_time``, env steps included) and their ratios, medians over rounds: a busy machine slows both.
"""

from __future__ import annotations

import argparse
import copy
import json
import statistics
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_MODEL = "results/paper_rows/runs/{method}_{config}_s{seed}/validated_model.pt"  # under ROOT


def _best_seed(method: str, config: str) -> int:
    """The seed of ``method``'s published best model on ``config`` (chosen on validation episodes)."""
    table = json.loads((ROOT / "results" / "paper_rows" / "table.json").read_text())
    rows = [r for r in table["rows"] if r["config"] == config and r["method"] == method]
    if not rows:
        raise SystemExit(f"--method: no published {method} on {config} in results/paper_rows/table.json")
    return int(rows[0]["best_seed"])


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", help="a decentralised native model file (default: --method's published best model on "
                                   "--config)")
    p.add_argument("--method", default="dagger_checked_agents", help="whose published best model to time")
    p.add_argument("--config", default="n11_m2_dt120")
    p.add_argument("--steps", type=int, default=600)
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--json", help="write the measurements here")
    args = p.parse_args(argv)

    import torch

    from containergym_marl.config import load_config
    from containergym_marl.envs.container_agents_v0 import parallel_env
    from containergym_marl.evaluation.decision_time import decision_times_ms
    from containergym_marl.policies.actor_critic import ActorCritic, policy_for
    from containergym_marl.policies.shared_check import SHARED_CHECK

    torch.set_num_threads(1)
    model_file = args.model or DEFAULT_MODEL.format(method=args.method, config=args.config,
                                                       seed=_best_seed(args.method, args.config))
    plain = ActorCritic.load(args.model or ROOT / model_file)
    if plain.shared_check is not None:
        plain.shared_check = None
    checked = copy.copy(plain)
    checked.shared_check = dict(SHARED_CHECK)
    policies = {"network": policy_for(plain, "network"), "shared_check": policy_for(checked, "shared_check")}
    env = parallel_env(load_config(args.config), action_masking=True, observation=plain.observation)
    rounds = []
    for r in range(args.rounds):
        names = list(policies) if r % 2 == 0 else list(policies)[::-1]
        out = {}
        for name in names:
            cpu = time.process_time()
            ms = decision_times_ms(policies[name], env, args.steps, 20_000)
            out[name] = {"ms_median": float(np.median(ms)), "ms_mean": float(ms.mean()),
                         "ms_p99": float(np.quantile(ms, 0.99)), "cpu_s": time.process_time() - cpu}
        rounds.append(out)
    summary = {name: {k: statistics.median(r[name][k] for r in rounds) for k in rounds[0][name]} for name in policies}
    result = {"config": args.config, "steps": args.steps, "model": model_file, "shared_check": SHARED_CHECK,
              "rounds": rounds, "summary": summary,
              "ratio_wall_median": statistics.median(r["shared_check"]["ms_median"] / r["network"]["ms_median"]
                                                     for r in rounds),
              "ratio_cpu": statistics.median(r["shared_check"]["cpu_s"] / r["network"]["cpu_s"] for r in rounds)}
    print(f"{args.config}, {args.steps} steps x {args.rounds} rounds, one torch thread, model {model_file}")
    for name, s in summary.items():
        print(f"  {name:13s} ms per plant step: median {s['ms_median']:.4f}, mean {s['ms_mean']:.4f}, "
              f"p99 {s['ms_p99']:.4f}; CPU per round {s['cpu_s']:.2f} s")
    print(f"  with / without the shared check: median wall {result['ratio_wall_median']:.2f}x, "
          f"CPU per round (env steps included) {result['ratio_cpu']:.2f}x")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=1)
    return result


if __name__ == "__main__":
    main()
