"""The native PPO against SB3's PPO: the same algorithm at SB3's settings, and no worse at its own.

    python studies/fast_ppo_validation.py paper-shape     # trains 2 x 5 runs (resumable), then compares
    python studies/fast_ppo_validation.py defaults        # compares published runs, trains nothing

``paper-shape``: ``fast_ppo`` and ``fast_shared_ppo`` with SB3's exact batch shape (8 simulations;
768 steps a rollout for the controller and 152 for the 5 container agents, i.e. 6144 and 6080
samples; minibatches of 64; 10 epochs) on n5_m2_dt120 at the paper's budget, seeds 1-5, each
run's best model evaluated with the paper's test protocol (15 episodes, seeds 10000-10014) as the
published SB3 runs were. Their seed means are set against the published SB3 runs' (``ppo``,
``shared_ppo``, seeds 1-5, ``results/paper_rows/evaluations``): the IQM over seeds with its 95 %
stratified-bootstrap interval for each side, and whether the two intervals overlap.

``defaults``: the native methods at their defaults against SB3's on the rows named (published
evaluation files of both under ``--results``): the two IQM intervals, and whether the native one
is no worse, i.e. its upper end reaches at least the SB3 interval's lower end.

Writes ``--out``/<mode>.md and .json.
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import numpy as np

from containergym_marl.evaluation import stats as st
from containergym_marl.evaluation.run_policies import evaluate_run
from containergym_marl.evaluation.table import bootstrap_rng, load_evaluations
from containergym_marl.training import TrainArgs, train
from containergym_marl.rundir import run_name, run_status

#: SB3's batch shape on n5_m2_dt120 (containergym_marl.algorithms.rollout_steps).
PAPER_SHAPE = {"fast_ppo": {"n_steps": 768, "minibatch_size": 64},
               "fast_shared_ppo": {"n_steps": 152, "minibatch_size": 64}}
COUNTERPART = {"fast_ppo": "ppo", "fast_shared_ppo": "shared_ppo", "fast_shared_ppo_team": "shared_ppo_team"}


def iqm_interval(seed_means, *names: str) -> tuple[float, float, float]:
    return tuple(st.stratified_bootstrap_ci(np.asarray(seed_means, dtype=float)[:, None], st.iqm, reps=2000,
                                            rng=bootstrap_rng("validation", *names)))


def sb3_seed_means(results: Path, config: str, method: str, seeds=None) -> dict[int, float]:
    for group in load_evaluations(results / "evaluations" / config):
        if group.method == method:
            return {s: float(m) for s, m in zip(group.seeds, group.seed_means) if seeds is None or s in seeds}
    raise FileNotFoundError(f"no published evaluations of {method} on {config} under {results}")


def paper_shape(ns) -> dict:
    config, entries = "n5_m2_dt120", []
    for algo, hp in PAPER_SHAPE.items():
        means = {}
        for seed in ns.seeds:
            run = Path(ns.runs) / run_name(f"{algo}_paper_shape", config, seed)
            status = run_status(run)
            if status != "finished" and ns.report_only:
                continue
            if status != "finished":
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    train(TrainArgs(algo=algo, config=config, seed=seed, out=str(run), n_envs=8, hyperparams=hp,
                                    resume=status == "interrupted", progress_bar=False))
            evaluation = run / "evaluation_best.json"
            if not evaluation.is_file():
                evaluate_run(run)
            episodes = json.loads(evaluation.read_text())["episodes"]
            means[seed] = float(np.mean([e["cumulative_reward"] for e in episodes]))
            print(f"{algo} s{seed}: {means[seed]:.2f}", flush=True)
        if len(means) < 2:
            print(f"skipped: {algo} has {len(means)} finished paper-shape run(s)")
            continue
        theirs = sb3_seed_means(Path(ns.results), config, COUNTERPART[algo], set(ns.seeds))
        entries.append(_compare(config, algo, means, COUNTERPART[algo], theirs, "overlap"))
    return {"mode": "paper-shape", "config": config, "settings": PAPER_SHAPE, "n_envs": 8, "entries": entries}


def defaults(ns) -> dict:
    entries = []
    for config in ns.rows:
        for algo, sb3 in COUNTERPART.items():
            try:
                ours = sb3_seed_means(Path(ns.results), config, algo)
                theirs = sb3_seed_means(Path(ns.results), config, sb3)
            except FileNotFoundError as exc:
                print(f"skipped: {exc}")
                continue
            if len(ours) < ns.min_seeds:
                print(f"skipped: {algo} on {config} has {len(ours)} published seed(s), fewer than {ns.min_seeds}")
                continue
            entries.append(_compare(config, algo, ours, sb3, theirs, "no worse"))
    return {"mode": "defaults", "entries": entries}


def _compare(config, ours_name, ours, theirs_name, theirs, test: str) -> dict:
    a = iqm_interval(list(ours.values()), config, ours_name)
    b = iqm_interval(list(theirs.values()), config, theirs_name)
    passed = (a[1] <= b[2] and b[1] <= a[2]) if test == "overlap" else a[2] >= b[1]
    return {"config": config, "native": ours_name, "sb3": theirs_name, "native_seed_means": ours,
            "sb3_seed_means": theirs, "native_iqm": a, "sb3_iqm": b, "test": test, "passed": bool(passed)}


def markdown(report: dict) -> str:
    title = {"paper-shape": "The native PPO at SB3's batch shape against SB3 (n5_m2_dt120)",
             "defaults": "The native PPO at its defaults against SB3 at the paper's settings"}[report["mode"]]
    lines = [f"# {title}", "", "Seed means of each run's best model under the paper's test protocol (15 episodes); "
             "IQM over seeds with its 95 % stratified-bootstrap interval. Generated by "
             f"`python studies/fast_ppo_validation.py {report['mode']}`.", "",
             "| row | native | seeds | IQM [95 % CI] | SB3 | seeds | IQM [95 % CI] | test | holds |",
             "|---|---|---|---|---|---|---|---|---|"]
    for e in report["entries"]:
        lines.append(f"| {e['config']} | {e['native']} | {len(e['native_seed_means'])} | {st.format_ci(e['native_iqm'])} "
                     f"| {e['sb3']} | {len(e['sb3_seed_means'])} | {st.format_ci(e['sb3_iqm'])} | {e['test']} | "
                     f"{'yes' if e['passed'] else 'no'} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("mode", choices=("paper-shape", "defaults"))
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    p.add_argument("--report-only", action="store_true", help="paper-shape: train nothing, report finished runs")
    p.add_argument("--min-seeds", type=int, default=5, help="defaults: compare only native methods with this many seeds")
    p.add_argument("--rows", nargs="+", default=["n5_m2_dt120", "n11_m2_dt120", "n16_m2_dt120", "n11_m11_dt120"])
    p.add_argument("--runs", default="runs/fast_ppo_validation")
    p.add_argument("--results", default="results/paper_rows")
    p.add_argument("--out", default="studies/fast_ppo_validation")
    ns = p.parse_args(argv)
    report = paper_shape(ns) if ns.mode == "paper-shape" else defaults(ns)
    out = Path(ns.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{ns.mode}.json").write_text(json.dumps(report, indent=1) + "\n")
    (out / f"{ns.mode}.md").write_text(markdown(report))
    print(markdown(report))
    return report


if __name__ == "__main__":
    main()
