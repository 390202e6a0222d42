"""The comparison's figures: which rows get them, the episode records they need (kept from the
evaluations, or the best policies evaluated again on Ray) and drawing them in the driver."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from containergym_marl.config import load_config
from containergym_marl.orchestration.compare_args import HEADLINE_ROW, CompareArgs
from containergym_marl.orchestration.plan import eval_spec, run_files
from containergym_marl.orchestration.cluster import SweepError
from containergym_marl.orchestration.sweep import execute
from containergym_marl.rundir import config_stem, run_name


def figure_configs(args: CompareArgs) -> list[str]:
    """The configs whose figures this comparison draws (``args.figures``)."""
    if args.figures == "none":
        return []
    if args.figures == "all":
        return list(args.configs)
    return [next((c for c in args.configs if config_stem(c) == HEADLINE_ROW), args.configs[0])]


def draw_figures(records: dict[str, dict[str, list]], out: Path, every: bool = False, stream=None) -> list[Path]:
    """The paper's figures for each config from ``records[config][method]`` (episode records): the
    reward and emptying-volume ECDFs and an episode of each method; ``every`` adds each method's PU
    timeline and each container's reward function. One progress line per config."""

    from containergym_marl.evaluation import plots  # matplotlib, only when figures are drawn

    fig_dir = out / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for config, by_method in records.items():
        started = time.perf_counter()
        cfg = load_config(config)
        stem = fig_dir / config_stem(config)
        plots.plot_emptying_volume_ecdfs(by_method, f"{stem}_emptying_volume_ecdfs", config=cfg)
        plots.plot_reward_ecdf(by_method, f"{stem}_reward_ecdf", config=cfg)
        drawn = [Path(f"{stem}_emptying_volume_ecdfs"), Path(f"{stem}_reward_ecdf")]
        for method, rec_list in by_method.items():
            plots.plot_episode(rec_list[0], f"{stem}_episode_{method}", config=cfg)
            drawn.append(Path(f"{stem}_episode_{method}"))
            if every:
                plots.plot_pu_timeline(rec_list[0], f"{stem}_pu_timeline_{method}", config=cfg)
                drawn.append(Path(f"{stem}_pu_timeline_{method}"))
        if every:
            for name in cfg.container_names:
                plots.plot_reward_function(cfg, name, f"{stem}_reward_function_{name}")
                drawn.append(Path(f"{stem}_reward_function_{name}"))
        written += drawn
        print(f"figures: {config_stem(config)}: {len(drawn)} drawn in {time.perf_counter() - started:.0f}s "
              f"({len(written)} so far)", file=stream or sys.stdout, flush=True)
    return written



def figure_records(args: CompareArgs, groups, runs: Path, cluster, stream,
                    kept: dict[tuple[str, str], list] | None = None) -> dict[str, dict[str, list]]:
    """Episode records of the best policy of each (config, method): those ``kept`` from this call's
    evaluations, the others evaluated again on Ray with records kept."""

    config_of = {config_stem(c): c for c in args.configs}
    kept = kept or {}
    jobs, records = [], {}
    for g in groups:
        seed = g.seeds[g.best] if g.seeds else None
        spec = eval_spec(args, config_of[g.config], g.method, seed)
        if kept.get((spec.config, spec.key)):
            records.setdefault(spec.config, {})[spec.method] = kept[(spec.config, spec.key)]
            continue
        source = None if seed is None else run_files(runs / run_name(g.method, g.config, seed))
        jobs.append((spec, source))
    if not jobs:
        return _in_table_order(groups, records)
    print(f"figures: evaluating the best policy of {len(jobs)} (config, method) pair(s) again, keeping the records",
          file=stream, flush=True)
    done = execute(cluster, [], jobs, keep_records=True, stream=stream)
    if done.failures:
        raise SweepError("figure evaluations failed: " + "; ".join(f"{k}: {v}" for k, v in done.failures.items()))
    for spec, _ in jobs:
        result, _sha = done.evaluations[(spec.config, spec.key)]
        records.setdefault(spec.config, {})[spec.method] = result.records
    return _in_table_order(groups, records)


def _in_table_order(groups, records: dict[str, dict[str, list]]) -> dict[str, dict[str, list]]:
    """``records[config][method]`` with configs and methods in the order of ``groups``."""
    config_of = {config_stem(c): c for c in records}
    ordered: dict[str, dict[str, list]] = {}
    for g in groups:
        config = config_of.get(g.config)
        if config is not None and g.method in records[config]:
            ordered.setdefault(config, {})[g.method] = records[config][g.method]
    return ordered
