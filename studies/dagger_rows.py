"""The imitations of the rollout planner on every row, against ``planner_agents`` (issue 27).

    python studies/dagger_rows.py             # nine rows x 5 seeds x 2 methods at the paper's budgets
    python studies/dagger_rows.py --smoke     # one row, one seed, 20k samples, 2 episodes (runs/dagger_smoke)

Trains ``dagger_agents`` and ``dagger_ppo_agents`` with ``containergym-marl compare --train`` (one
Ray task per run on one core, torch one thread; resumable: rerun the same command to continue), each
row under its own training settings (the δ = 60 rows at δ = 60 s), the paper's budget (2M samples
for n = 5, 5M for n >= 11, agent steps) and seeds 1–5, and evaluates each run's best model with
the paper's test protocol (δ = 120 s, T = 600, 15 episodes, seeds 10000–10014), beside
``planner_agents``, the reference. Then writes ``--out``/rows.json and rows.md: per row and method
the IQM over seeds, its share of ``planner_agents``' mean return (the issue's target: >= 97 %), the
best seed's overflowing test episodes, and the training cost per seed (wall seconds, the planner's
labelling CPU seconds from run.json's ``"imitation"``, samples per second); and the decision time
of a learned policy per plant step at n = 11 on one thread (``SharedActorCriticPolicy.act``: one
forward for all agents, over 600 steps).

Cost (``results/dagger_rows/rows.md``, the published runs on a 2-core machine training two at a
time): ``dagger_agents`` 129–142 s of one core per seed at n = 5 (2M samples) and 236–285 s at
n >= 11 (5M), of which the planner's labelling takes 104–191 CPU seconds (45 runs in 1h17m);
``dagger_ppo_agents``, whose planner labels half the samples, 87–92 s and 180–210 s; the learned
policy decides in a median 0.05 ms per plant step at n = 11 (the planner: 1–2 ms).
"""

from __future__ import annotations

import argparse
import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from containergym_marl.evaluation.decision_time import decision_times_ms
from containergym_marl.files import atomic_write_text
from containergym_marl.orchestration.compare_args import PAPER_ROWS

ROWS = PAPER_ROWS
METHODS = ("dagger_agents", "dagger_ppo_agents")
REFERENCE = "planner_agents"
#: the row on which the decision time is measured (n = 11)
TIMING_ROW = "n11_m2_dt120"


@dataclass
class Args:
    rows: list[str] = field(default_factory=lambda: list(ROWS))
    methods: list[str] = field(default_factory=lambda: list(METHODS))
    seeds: list[int] = field(default_factory=lambda: [1, 2, 3, 4, 5])
    timesteps: int | None = None  # None: the paper's budget of each row
    episodes: int = 15
    out: str = "results/dagger_rows"  # a study writes only under results/<study>/
    runs: str = "runs/dagger"
    num_cpus: int | None = None
    smoke: bool = False

    def for_smoke(self) -> "Args":
        return Args(rows=["n5_m2_dt120"], methods=self.methods, seeds=[1], timesteps=20_000, episodes=2,
                    out=self.out if self.out != Args.out else "runs/dagger_smoke/results",
                    runs=self.runs if self.runs != Args.runs else "runs/dagger_smoke/runs", num_cpus=self.num_cpus,
                    smoke=True)


def train_and_evaluate(args: Args) -> dict:
    """``compare --train`` of the methods and the reference on the rows; its table.json."""
    from containergym_marl.orchestration import CompareArgs, compare

    compare(CompareArgs(configs=args.rows, methods=[REFERENCE, *args.methods], seeds=args.seeds,
                        timesteps=args.timesteps, episodes=args.episodes, out=str(Path(args.out) / "compare"),
                        runs=args.runs, num_cpus=args.num_cpus, figures="none"))
    return json.loads((Path(args.out) / "compare" / "table.json").read_text())


def training_cost(runs: Path, method: str, row: str) -> dict | None:
    """Mean per finished seed: wall seconds, labelling CPU seconds, samples and samples per second."""
    from containergym_marl.rundir import read_run_summary, seeded_runs

    summaries = [s for _, run in seeded_runs(runs, method, row) if (s := read_run_summary(run))]
    if not summaries:
        return None
    wall = np.array([s["wall_time_s"] for s in summaries])
    label = np.array([(s.get("imitation") or {}).get("label_cpu_s", 0.0) for s in summaries])
    samples = np.array([s["timesteps"] for s in summaries])
    return {"seeds": len(summaries), "wall_s": float(wall.mean()), "label_cpu_s": float(label.mean()),
            "samples": int(samples.mean()), "samples_per_s": float((samples / wall).mean())}


def decision_time(runs: Path, methods: list[str], steps: int = 600) -> dict:
    """Wall time of the learned policy's ``act`` per plant step at n = 11, one torch thread (the
    median, which a busy machine disturbs least; the mean and p99 too):
    a trained model of :data:`TIMING_ROW` if there is one (the time does not depend on the weights,
    only on the network's shape), else an untrained network of that shape."""
    import torch

    from containergym_marl.config import load_config
    from containergym_marl.core.observations import agent_feature_names
    from containergym_marl.core.params import PlantParams
    from containergym_marl.envs.container_agents_v0 import parallel_env
    from containergym_marl.policies.actor_critic import ActorCritic, policy_for
    from containergym_marl.rundir import seeded_runs

    torch.set_num_threads(1)
    found = [run / "final_model.pt" for m in methods for _, run in seeded_runs(runs, m, TIMING_ROW)
             if (run / "final_model.pt").is_file()]
    if found:
        model, source = ActorCritic.load(found[0]), str(found[0])
    else:
        features = len(agent_feature_names(PlantParams.from_config(load_config(TIMING_ROW))))
        model = ActorCritic("decentralised", features, 2, generator=torch.Generator().manual_seed(0))
        source = "an untrained network of the same shape"
    policy = policy_for(model, "timed")
    env = parallel_env(TIMING_ROW)
    # an untrained policy's episodes end early: the next one continues
    ms = decision_times_ms(policy, env, steps, seed=0)
    return {"row": TIMING_ROW, "model": source, "steps": len(ms), "ms_per_step_median": float(np.median(ms)),
            "ms_per_step_mean": float(np.mean(ms)), "ms_per_step_p99": float(np.quantile(ms, 0.99)),
            "torch_threads": 1}


def summarise(args: Args, table: dict) -> dict:
    by = {(r["config"], r["method"]): r for r in table["rows"]}
    entries = []
    for row in args.rows:
        reference = by.get((row, REFERENCE))
        ref_return = reference["best_mean"] if reference else None
        for method in args.methods:
            r = by.get((row, method))
            if r is None:
                continue
            entries.append({
                "row": row, "method": method, "seeds": r["seeds"], "iqm": r["iqm"], "iqm_low": r["iqm_low"],
                "iqm_high": r["iqm_high"], "best_mean": r["best_mean"], "reference_return": ref_return,
                "share_of_reference": r["iqm"] / ref_return if ref_return else None,
                "best_seed_overflow_rate": r["overflow_rate"], "samples": r["samples"],
                "training_cost_per_seed": training_cost(Path(args.runs), method, row)})
    return {"args": asdict(args), "reference": REFERENCE, "entries": entries,
            "decision_time": decision_time(Path(args.runs), args.methods), "load_average": os.getloadavg()}


def markdown(report: dict) -> str:
    lines = ["# Imitations of the rollout planner on every row", "",
             f"Paper test protocol, best model of each run; share: the IQM over seeds as a share of "
             f"`{REFERENCE}`'s mean return on the row (target >= 97 %). Cost per seed: mean wall time of a "
             f"run (one core), of which the planner's labelling CPU time.", "",
             "| row | method | seeds | IQM [95 % CI] | share | best seed's overflows | wall s / seed | "
             "labelling CPU s | samples/s |", "|---|---|---|---|---|---|---|---|---|"]
    for e in report["entries"]:
        cost = e["training_cost_per_seed"] or {}
        share = f"{100 * e['share_of_reference']:.1f} %" if e["share_of_reference"] is not None else "–"
        lines.append(f"| {e['row']} | {e['method']} | {e['seeds']} | {e['iqm']:.2f} [{e['iqm_low']:.2f}, "
                     f"{e['iqm_high']:.2f}] | {share} | {e['best_seed_overflow_rate']:.2f} | "
                     f"{cost.get('wall_s', float('nan')):.0f} | {cost.get('label_cpu_s', float('nan')):.0f} | "
                     f"{cost.get('samples_per_s', float('nan')):,.0f} |")
    d = report["decision_time"]
    lines += ["", f"Decision time of the learned policy at n = 11 ({d['row']}, one thread, {d['model']}): "
              f"median {d['ms_per_step_median']:.3f} ms per plant step (mean {d['ms_per_step_mean']:.3f} ms, "
              f"p99 {d['ms_per_step_p99']:.3f} ms).", ""]
    return "\n".join(lines)


def main(args: Args) -> dict:
    if args.smoke:
        args = args.for_smoke()
    table = train_and_evaluate(args)
    report = summarise(args, table)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "rows.json", json.dumps(report, indent=2))
    atomic_write_text(out / "rows.md", markdown(report))
    print(markdown(report))
    return report


def parse(argv=None) -> Args:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rows", nargs="+", default=list(ROWS))
    p.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    p.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3, 4, 5])
    p.add_argument("--timesteps", type=int, default=None, help="samples per run (default: the paper's budget)")
    p.add_argument("--episodes", type=int, default=15)
    p.add_argument("--out", default=Args.out)
    p.add_argument("--runs", default=Args.runs)
    p.add_argument("--num-cpus", type=int, default=None)
    p.add_argument("--smoke", action="store_true", help="one row, one seed, 20k samples, 2 episodes")
    return Args(**vars(p.parse_args(argv)))


if __name__ == "__main__":
    main(parse())
