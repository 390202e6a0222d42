"""The benchmark's main job: compare decentralised and centralised policies, with tables and figures.

    containergym-marl compare                       # small but real default, a few minutes on 2 cores
    containergym-marl compare --configs n5_m2_dt120 n11_m2_dt120 --seeds 1 2 3 4 5 --timesteps 2000000

For every configuration it trains (or reuses finished runs of) each learned method for each seed,
evaluates every policy with the paper's test protocol and writes, to ``--out``:

* ``table.md`` / ``table.csv`` / ``table.json`` — the paper's Table 1 shape (best and median policy
  over seeds, mean ± std over the test episodes) plus, across seeds, the interquartile mean (IQM)
  with a stratified-bootstrap 95 % confidence interval, and the probability that the decentralised
  method (shared PPO) improves on its centralised counterpart (PPO), with its interval;
* ``evaluations/<config>/`` — every evaluation as a small JSON file (per-episode metrics);
  ``python -m containergym_marl.evaluation.table`` regenerates the best/median table from them;
* ``figures/`` — the paper's figures for the best seed of each method: episode rollouts, ECDFs of
  emptying volumes per container and of rewards per emptying action, PU occupancy timelines, and
  the reward functions of the containers (PNG and SVG).

Runs live in ``--runs`` (default ``<out>/runs``); a finished run (``final_model.zip`` present and the
same budget) is reused, an interrupted one resumed, so a long comparison can be stopped and rerun.
"""

from __future__ import annotations

import csv
import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from containergym_marl.config import load_config
from containergym_marl.core.params import PlantParams
from containergym_marl.evaluation import EvalProtocol, EvaluationResult, evaluate
from containergym_marl.evaluation import stats as st
from containergym_marl.evaluation.table import PAPER_TABLE_1

RULE_BASED = ("rule_based", "rule_based_agents")
LEARNED = ("ppo", "trpo", "dqn", "maskable_ppo", "shared_ppo")
VIEWS = {"rule_based": "centralised", "rule_based_agents": "decentralised", "shared_ppo": "decentralised"}
#: (decentralised, centralised) pairs whose probability of improvement is reported.
PAIRS = (("shared_ppo", "ppo"), ("rule_based_agents", "rule_based"))


@dataclass
class CompareArgs:
    """A comparison of methods on plant configurations (see the module docstring).

    The defaults are a small but real comparison on n5_m2_dt120 that runs in minutes; the paper's
    budget is ``timesteps=2_000_000`` (n = 5) or ``5_000_000`` (n = 11).
    """

    configs: list[str] = field(default_factory=lambda: ["n5_m2_dt120"])
    methods: list[str] = field(default_factory=lambda: ["rule_based", "rule_based_agents", "ppo", "shared_ppo"])
    seeds: list[int] = field(default_factory=lambda: [1, 2, 3])
    timesteps: int = 30_000
    episodes: int = 15
    out: str = "results/compare"
    runs: str | None = None
    n_envs: int = 8
    bootstrap_reps: int = 2000
    figures: bool = True
    progress_bar: bool = False
    hyperparams: dict = field(default_factory=dict)  # extra SB3 arguments for every learned method


@dataclass
class MethodResult:
    config: str
    method: str
    view: str
    seeds: list[int]
    per_seed: list[EvaluationResult]

    @property
    def seed_means(self) -> np.ndarray:
        return np.array([r.returns.mean() for r in self.per_seed])

    def ranked(self) -> list[int]:
        """Indices of seeds from best to worst mean test return."""
        return list(np.argsort(-self.seed_means, kind="stable"))


def _validate(args: CompareArgs) -> None:
    unknown = [m for m in args.methods if m not in RULE_BASED + LEARNED]
    if unknown:
        raise ValueError(f"methods: unknown method(s) {unknown}; choose from {RULE_BASED + LEARNED}")
    for c in args.configs:
        load_config(c)  # ConfigError for unknown names, before any work
    if not args.seeds:
        raise ValueError("seeds: at least one training seed is needed")


def _train_or_reuse(args: CompareArgs, method: str, config: str, seed: int, runs: Path) -> Path:
    from containergym_marl.training.runs import TrainArgs, train

    run = runs / f"{method}_{Path(config).stem}_s{seed}"
    saved = run / "args.json"
    if (run / "final_model.zip").exists():
        budget = json.loads(saved.read_text()).get("timesteps")
        if budget != args.timesteps:
            raise ValueError(f"{run} holds a finished run with a budget of {budget} samples, not {args.timesteps}; "
                             f"use another --runs directory or the same --timesteps")
        print(f"  reuse {run}")
        return run
    print(f"  train {run} ({args.timesteps} samples)", flush=True)
    return train(TrainArgs(algo=method, config=config, seed=seed, timesteps=args.timesteps, out=str(run),
                           resume=run.exists() and any(run.iterdir()), n_envs=args.n_envs,
                           progress_bar=args.progress_bar, hyperparams=dict(args.hyperparams)))


def _evaluate_method(args: CompareArgs, method: str, config: str, runs: Path, protocol: EvalProtocol,
                     evaluations: Path) -> MethodResult:
    """Evaluate one method on one config; every evaluation is also written as a small JSON file
    (``<method>.json`` or ``<method>_s<seed>.json``) from which the table can be regenerated."""
    from containergym_marl.policies import RuleBasedAgents, RuleBasedController
    from containergym_marl.training.runs import policy_from_run

    evaluations.mkdir(parents=True, exist_ok=True)
    if method in RULE_BASED:
        cls = RuleBasedController if method == "rule_based" else RuleBasedAgents
        result = evaluate(cls(PlantParams.from_config(load_config(config))), config, protocol)
        (evaluations / f"{method}.json").write_text(result.to_json())
        return MethodResult(config, method, VIEWS[method], [], [result])
    per_seed = []
    for seed in args.seeds:
        run = _train_or_reuse(args, method, config, seed, runs)
        per_seed.append(evaluate(policy_from_run(run, "best"), config, protocol))
        (evaluations / f"{method}_s{seed}.json").write_text(per_seed[-1].to_json())
    return MethodResult(config, method, VIEWS.get(method, "centralised"), list(args.seeds), per_seed)


def _rows(results: list[MethodResult], reps: int, rng: np.random.Generator) -> list[dict]:
    rows = []
    for res in results:
        order = res.ranked()
        best, median = res.per_seed[order[0]], res.per_seed[order[(len(order) - 1) // 2]]
        scores = res.seed_means[:, None]
        row = {
            "config": res.config,
            "method": res.method,
            "view": res.view,
            "seeds": len(res.seeds) if res.seeds else 0,
            "best_mean": float(best.returns.mean()),
            "best_std": float(best.returns.std()),
            "median_mean": float(median.returns.mean()),
            "median_std": float(median.returns.std()),
        }
        point, low, high = st.stratified_bootstrap_ci(scores, st.iqm, reps=reps, rng=rng)
        row.update(iqm=point, iqm_low=low, iqm_high=high)
        s = best.summary()
        row.update(overflow_rate=s["overflow_rate"], emptyings=s["emptyings_mean"],
                   good_share=s["good_emptying_share"], denied=s["denied_requests_mean"],
                   pu_utilisation=s["pu_utilisation"])
        rows.append(row)
    return rows


def _improvements(results: list[MethodResult], reps: int, rng: np.random.Generator) -> list[dict]:
    by_key = {(r.config, r.method): r for r in results}
    out = []
    for config in dict.fromkeys(r.config for r in results):
        for dec, cen in PAIRS:
            if (config, dec) in by_key and (config, cen) in by_key:
                # Per-episode returns of rule-based policies stand in for seeds (they have none).
                x = _scores_for_improvement(by_key[(config, dec)])
                y = _scores_for_improvement(by_key[(config, cen)])
                p, low, high = st.probability_of_improvement_ci(x, y, reps=reps, rng=rng)
                out.append({"config": config, "decentralised": dec, "centralised": cen,
                            "probability": p, "low": low, "high": high, "unit": _unit(by_key[(config, dec)])})
    return out


def _scores_for_improvement(res: MethodResult) -> np.ndarray:
    if res.seeds:
        return res.seed_means[:, None]
    return res.per_seed[0].returns[:, None]


def _unit(res: MethodResult) -> str:
    return "training seeds" if res.seeds else "test episodes"


def _markdown(rows: list[dict], improvements: list[dict], args: CompareArgs) -> str:
    lines = [
        f"Test cumulative reward (paper protocol: δ = 120 s, T = 600, {args.episodes} episodes; "
        f"learned methods: {len(args.seeds)} training seeds × {args.timesteps:,} samples). Best / median: the "
        "best and the median policy over seeds, mean ± std over test episodes. IQM: interquartile mean of "
        "the per-seed mean returns, [95 % stratified-bootstrap CI].",
        "",
        "| config | method | view | seeds | best | median | IQM [95 % CI] | overflow rate | emptyings | "
        "r ≥ 0.75 | denied req. | PU busy |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        seeds = r["seeds"] or "–"
        lines.append(
            f"| {r['config']} | {r['method']} | {r['view']} | {seeds} | {r['best_mean']:.2f} ± {r['best_std']:.2f} | "
            f"{r['median_mean']:.2f} ± {r['median_std']:.2f} | {r['iqm']:.2f} [{r['iqm_low']:.2f}, {r['iqm_high']:.2f}] | "
            f"{r['overflow_rate']:.2f} | {r['emptyings']:.1f} | {_num(r['good_share'])} | {r['denied']:.1f} | "
            f"{r['pu_utilisation']:.2f} |"
        )
    for config in dict.fromkeys(r["config"] for r in rows):
        for algo, (best, median) in PAPER_TABLE_1.get(config, {}).items():
            lines.append(f"| {config} | paper {algo.upper()} | centralised | 15 | {best[0]:.2f} ± {best[1]:.2f} | "
                         f"{median[0]:.2f} ± {median[1]:.2f} | – | – | – | – | – | – |")
    if improvements:
        lines += ["", "Probability of improvement (decentralised over centralised), [95 % bootstrap CI]:", ""]
        for imp in improvements:
            lines.append(f"- {imp['config']}: P({imp['decentralised']} > {imp['centralised']}) = "
                         f"{imp['probability']:.2f} [{imp['low']:.2f}, {imp['high']:.2f}] (over {imp['unit']})")
    return "\n".join(lines) + "\n"


def _num(x: float) -> str:
    return "–" if x is None or (isinstance(x, float) and np.isnan(x)) else f"{x:.2f}"


def _figures(results: list[MethodResult], out: Path, protocol: EvalProtocol) -> list[Path]:
    from containergym_marl.evaluation import plots

    fig_dir = out / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for config in dict.fromkeys(r.config for r in results):
        cfg = load_config(config)
        best = {r.method: r.per_seed[r.ranked()[0]] for r in results if r.config == config}
        records = {m: res.records for m, res in best.items()}
        stem = fig_dir / Path(config).stem
        plots.plot_emptying_volume_ecdfs(records, f"{stem}_emptying_volume_ecdfs", config=cfg)
        plots.plot_reward_ecdf(records, f"{stem}_reward_ecdf")
        written += [Path(f"{stem}_emptying_volume_ecdfs"), Path(f"{stem}_reward_ecdf")]
        for method, rec_list in records.items():
            plots.plot_episode(rec_list[0], f"{stem}_episode_{method}", config=cfg)
            plots.plot_pu_timeline(rec_list[0], f"{stem}_pu_timeline_{method}", config=cfg)
            written += [Path(f"{stem}_episode_{method}"), Path(f"{stem}_pu_timeline_{method}")]
        for name in cfg.container_names:
            plots.plot_reward_function(cfg, name, f"{stem}_reward_function_{name}")
            written.append(Path(f"{stem}_reward_function_{name}"))
    return written


def compare(args: CompareArgs) -> dict:
    """Run the comparison; returns the table rows and improvements (also written to ``args.out``)."""
    _validate(args)
    start = time.perf_counter()
    out = Path(args.out)
    runs = Path(args.runs) if args.runs else out / "runs"
    out.mkdir(parents=True, exist_ok=True)
    protocol = EvalProtocol(episodes=args.episodes)
    results = []
    for config in args.configs:
        print(f"{config}:", flush=True)
        for method in args.methods:
            results.append(_evaluate_method(args, method, config, runs, protocol,
                                            out / "evaluations" / Path(config).stem))
    rng = np.random.default_rng(0)  # bootstrap resampling only; fixed for reproducible tables
    rows = _rows(results, args.bootstrap_reps, rng)
    improvements = _improvements(results, args.bootstrap_reps, rng)
    table = _markdown(rows, improvements, args)
    (out / "table.md").write_text(table)
    with (out / "table.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    report = {"args": asdict(args), "rows": rows, "improvements": improvements,
              "seed_means": {f"{r.config}/{r.method}": r.seed_means.tolist() for r in results}}
    (out / "table.json").write_text(json.dumps(report, indent=2))
    if args.figures:
        report["figures"] = [str(p) for p in _figures(results, out, protocol)]
    print(table)
    print(f"written to {out}/ (table.md, table.csv, table.json{', figures/' if args.figures else ''}) "
          f"in {time.perf_counter() - start:.0f} s")
    return report
