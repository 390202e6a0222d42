"""The benchmark's main job: compare decentralised and centralised policies, with tables and figures.

    containergym-marl compare                                   # the shipped policies, evaluated: minutes
    containergym-marl compare --train                           # a quick training look: 30k samples per run
    containergym-marl compare --configs n5_m2_dt120 n11_m2_dt120 --methods rule_based rule_based_agents \\
        ppo shared_ppo shared_ppo_team --seeds 1 2 3 --timesteps paper   # the paper's budgets: hours

**Shipped policies** (the default: no ``--train``; a training option without it is refused):
nothing is trained. The repository publishes the comparison's runs in ``results/paper_rows/runs/``
(``containergym-marl publish``; ``--shipped`` names another such folder, which is only read).
On every row of :data:`PAPER_ROWS` it evaluates the rule-based controllers and, for each learned
method of :data:`PAPER_METHODS` with finished shipped runs (a readable final model; runs
published with only a checkpoint are still training and are skipped), the best model of its best
seed, ranked by the published evaluations (``<shipped>/evaluations/``); a seed without a published
evaluation of the same model, plant and protocol is evaluated too. The other seeds' published
evaluations complete the table (median, IQM), so it reads as the sweep's own. Rows without shipped
policies are named.

**Training** (``--train``): for every configuration it trains (or reuses)
each learned method for each seed, evaluates every
policy with the paper's test protocol (δ = 120 s, T = 600, ``--episodes`` episodes, best model of
each run) and writes the same files. Before it trains it says how long that will take.

Both write, to ``--out``:

* ``table.md`` / ``table.csv`` / ``table.json``: the paper's Table 1 shape plus the IQM over seeds
  with a bootstrap CI and the probability that each decentralised method beats its centralised
  counterpart (see :mod:`containergym_marl.evaluation.table`, which also regenerates the table from
  the evaluation files alone: ``python -m containergym_marl.evaluation.table OUT``);
* ``evaluations/<config>/``: every evaluation as a small JSON file;
* ``figures/``: episode rollouts, ECDFs, PU timelines and reward functions of the best seed of each method.

Methods: those of :mod:`containergym_marl.methods` that compare runs (:data:`~containergym_marl.methods.COMPARABLE`):
the rule-based controllers, the rollout planners through each view, and the learned methods that
``containergym-marl train`` trains (SB3's and the native PPO's; ``--hp`` takes the algorithm's
settings). MAPPO is trained by ``baselines/train_mappo.py`` (BenchMARL, the clients extra), which
writes ``mappo_s<seed>.json`` evaluation files that the table reads beside these. Runs are
``<runs>/<method>_<config>_s<seed>/`` and train on the config as it is (the δ = 60 rows at
δ = 60 s); ``--timesteps paper`` gives each config the paper's budget (2M samples for n = 5, 5M for
n >= 11).

Execution on Ray (:mod:`containergym_marl.orchestration.sweep`): one task per training run (one CPU each, torch
one thread), one per evaluation; tables and figures in the driver. By default compare starts a
local Ray instance with this machine's cores (``--num-cpus`` to change; its servers listen on
every interface, which Ray 2.60 does not let a caller change, and refuse any client without the
token Ray keeps in ``~/.ray/auth_token``: Ray's token authentication, on by default for a new local
instance); ``--address`` (or
``RAY_ADDRESS``) runs the same sweep on an existing cluster. A live line shows runs done /
running / queued, evaluations, the ETA and each running run's samples/s.

Resuming: rerunning the same command reuses finished runs (a readable ``final_model.zip`` with the
same budget, checked by the driver without any Ray work), resumes interrupted ones from their last
checkpoint (``--checkpoint-every`` samples apart), retries a run whose worker dies (``--max-retries``)
and never retrains or overwrites a finished run. Ctrl-C stops the sweep and leaves every run
resumable. Evaluations are reused too when the model (sha256), the plant and the protocol are
unchanged; ``--reevaluate`` redoes them (after a change to the simulator, say).

A cluster in two commands. Every machine needs this package with its ``train`` and ``sweep``
extras, the versions of the driver's (``pip install -c constraints.txt -e '.[train,sweep]'``); Ray
>= 2.59 checks a token between nodes, so export the same ``RAY_AUTH_MODE=token`` and
``RAY_AUTH_TOKEN=<secret>`` (e.g. from ``ray get-auth-token --generate``) on every machine first::

    ray start --head --port 6379 --include-dashboard=false       # 1. on the head; on each other machine:
                                                                 #    ray start --address HEAD_IP:6379
    containergym-marl compare --address HEAD_IP:6379 --runs /shared/runs --timesteps paper \
        --configs ... --methods ... --seeds 1 2 3                # 2. on the head (the driver)

``ray status --address HEAD_IP:6379`` lists the nodes and their CPUs; ``ray stop`` on each machine
ends the cluster (it stops every Ray process of that machine).

Storage: ``--runs`` (default ``<out>/runs``) is resolved to an absolute path, and each training
task writes its run directory at that path on the node that runs it (so it must be writable on
every node). Best is a path every node
reaches (NFS or similar): then checkpoints are shared too and an interrupted run resumes on any
node. Without shared storage the sweep still completes: every training task returns its run's
small files (args, metrics, best and final model; no checkpoints or TensorBoard logs) to the
driver, which writes them into its own ``--runs``, so the table, the figures and reruns on the
driver work; only resuming an interrupted run needs the node that holds its checkpoints.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

from containergym_marl.evaluation import table as tables
from containergym_marl.files import atomic_write_text
from containergym_marl.methods import METHODS, PAIRS
from containergym_marl.orchestration.cluster import Cluster, SweepError
from containergym_marl.orchestration.compare_args import CompareArgs
from containergym_marl.orchestration.figures import draw_figures, figure_configs, figure_records
from containergym_marl.orchestration.plan import (
    config_stem,
    evaluation_fingerprint,
    evaluation_path,
    resume_point,
    training_plan,
)
from containergym_marl.orchestration.sweep_progress import estimate_rate
from containergym_marl.orchestration.shipped import shipped_plan, shipped_report, shipped_summary
from containergym_marl.orchestration.sweep import execute
from containergym_marl.progress_bar import format_duration
from containergym_marl.rundir import run_name, write_files


def save_evaluation(args: CompareArgs, out: Path, spec, result, model_sha: str | None,
                     timesteps: int | None = None) -> dict:
    """The evaluation as JSON (EvaluationResult.to_json plus compare's fingerprint), written to
    ``<out>/evaluations/<config>/<key>.json``."""
    run = None if spec.seed is None else run_name(spec.method, spec.config, spec.seed)
    data = json.loads(result.to_json())
    data["compare"] = evaluation_fingerprint(args, spec.config, METHODS[spec.method], run, model_sha, timesteps)
    path = evaluation_path(out, spec.config, spec.key)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(data, indent=2) + "\n")
    return data


def compare(args: CompareArgs, stream=None) -> dict:
    """Run the comparison; returns the table rows, the improvements and what the sweep did (also
    written to ``args.out``: table.*, sweep.json, evaluations/, figures/). Raises SweepError when
    tasks failed after Ray's retries; KeyboardInterrupt leaves every run resumable.

    With ``args.shipped`` it trains nothing and evaluates the shipped policies (module docstring)."""

    stream = stream or sys.stdout

    def say(text: str = "") -> None:
        print(text, file=stream, flush=True)

    args.validate()
    start = time.perf_counter()
    out = Path(args.out).resolve()
    if args.shipped is not None:  # 1. from the files alone
        plan = shipped_plan(args, out)
        runs = Path(args.shipped).resolve() / "runs"
        say(f"compare: the shipped policies of {args.shipped}/, evaluated on the {args.protocol} episodes "
            f"({args.eval_protocol().episodes} each); nothing is trained (--train trains, see --help)")
        for line in plan.shipped.lines(args.methods):
            say(f"  {line}")
        copied = len(plan.shipped.copied)
        say(f"compare: {len(args.configs)} config(s) × {len(args.methods)} method(s); "
            f"{len(plan.to_evaluate) + len(plan.evaluations)} evaluation(s): {len(plan.to_evaluate)} to run, "
            f"{len(plan.evaluations) - copied} reused from {args.out}/, {copied} published ones of the "
            f"shipped runs that are not their row's best")
    else:
        runs = Path(args.runs).resolve() if args.runs else out / "runs"
        plan = training_plan(args, out, runs)
        started = sum(Path(s.run_dir).is_dir() for s in plan.to_train)
        say(f"compare: {len(args.configs)} config(s) × {len(args.methods)} method(s); {len(plan.specs)} training "
            f"run(s): {len(plan.finished)} finished, {len(plan.to_train)} to train ({started} of them started "
            f"before); {len(plan.to_evaluate) + len(plan.evaluations)} evaluation(s), {len(plan.evaluations)} reused")
    evaluations = dict(plan.evaluations)
    out.mkdir(parents=True, exist_ok=True)
    report: dict[str, Any] = {"ray": None, "trained": [], "reused": sorted(plan.finished), "evaluated": [],
                              "evaluations_reused": sorted(f"{config_stem(c)}/{k}" for c, k in evaluations)}
    records: dict[str, dict[str, list]] = {}
    # Shipped policies: the evaluations keep their episode records for the figures (mostly one per
    # (config, method)); a training sweep evaluates every seed, so its figures evaluate the best again.
    figure_rows = figure_configs(args)
    keep = bool(figure_rows) and args.shipped is not None
    kept: dict[tuple[str, str], list] = {}

    cluster = Cluster(args.address, args.num_cpus, args.max_retries)
    try:  # 2. the job graph on Ray: trainings, their evaluations, then the figures' records
        if plan.to_train or plan.to_evaluate:
            report["ray"] = cluster.describe()
            say(f"Ray: {report['ray']}")
            if plan.to_train:
                samples = sum(s.timesteps - resume_point(s) for s in plan.to_train)
                rate, slots = estimate_rate(runs), min(cluster.cpus(), len(plan.to_train))
                say(f"training: {samples:,} samples in {len(plan.to_train)} run(s), about "
                    f"{format_duration(samples / (rate * slots))} at ~{rate:,.0f} samples/s per run, {slots} at a time")

            def save(spec, value) -> None:  # each evaluation is written as it lands
                result, model_sha = value
                run = None if spec.seed is None else run_name(spec.method, spec.config, spec.seed)
                evaluations[(spec.config, spec.key)] = save_evaluation(args, out, spec, result, model_sha,
                                                                        plan.budgets.get(run))
                report["evaluated"].append(f"{config_stem(spec.config)}/{spec.key}")
                if keep and spec.config in figure_rows:
                    kept[(spec.config, spec.key)] = result.records

            done = execute(cluster, plan.to_train, plan.to_evaluate, stream=stream, keep_records=keep,
                           on_run_done=lambda spec, result: write_files(spec.run_dir, result["files"]),
                           on_evaluation_done=save)
            for name, result in done.runs.items():
                report["trained"].append({**{k: v for k, v in result.items() if k != "files"},
                                          "attempts": done.attempts.get(name, 1)})
            if done.failures:
                raise SweepError(f"{len(done.failures)} task(s) failed: "
                                 + "; ".join(f"{k}: {v}" for k, v in done.failures.items())
                                 + ". Finished runs and evaluations are kept; rerun the same command to retry.")
        groups = table_groups(args, evaluations, plan.seeds)
        if figure_rows:
            records = figure_records(args, [g for g in groups if g.config in map(config_stem, figure_rows)], runs,
                                      cluster, stream, kept)
    except KeyboardInterrupt:
        if plan.shipped is not None:
            say(f"\ninterrupted: the evaluations done so far are kept in {out / 'evaluations'}/ and reused when "
                f"the same command runs again")
        else:
            say(f"\ninterrupted: finished runs are kept, the others resume from their last checkpoint when the "
                f"same command runs again (runs: {runs}/)")
        raise
    finally:
        cluster.close()

    # 3. Table and figures in the driver.
    table = tables.build_table(groups, PAIRS, args.bootstrap_reps)
    meta = {"args": _jsonable(asdict(args))}
    paths = table.write(out, meta)
    figures = [str(p) for p in draw_figures(records, out, args.figures == "all", stream)]
    report["wall_s"] = round(time.perf_counter() - start, 1)
    if plan.shipped is not None:
        report["shipped"] = shipped_report(plan.shipped, evaluations, report["evaluated"])
    atomic_write_text(out / "sweep.json", json.dumps({**meta, **report}, indent=2) + "\n")
    say()
    tables.print_table(table, stream, shipped=plan.shipped is not None)
    if plan.shipped is not None:
        say()
        for line in shipped_summary(plan.shipped, report["shipped"], args.methods):
            say(line)
    n_evaluations = len(list((out / "evaluations").glob("*/*.json")))
    say()
    say(f"files ({out}/):")
    say(f"  table: {paths[0]} (also table.csv, table.json)")
    say(f"  evaluations: {out / 'evaluations'}/ ({n_evaluations} files, one per policy and row)")
    if figures:
        say(f"  figures: {out / 'figures'}/ ({len(figures)} figures, PNG and SVG)")
    say(f"  what this call did: {out / 'sweep.json'}")
    if plan.shipped is None:
        say(f"  runs: {runs}/")
    elif plan.finished:
        say(f"  shipped runs (only read): {runs}/")
    if plan.shipped is not None:
        say(f"compare took {format_duration(report['wall_s'])}: {len(report['evaluated'])} evaluation(s) run, "
            f"{len(report['evaluations_reused'])} reused; nothing trained")
    else:
        say(f"compare took {format_duration(report['wall_s'])}: {len(report['trained'])} run(s) trained or resumed, "
            f"{len(plan.finished)} reused, {len(report['evaluated'])} evaluation(s) run, "
            f"{len(report['evaluations_reused'])} reused")
    return {**meta, "rows": table.rows, "improvements": table.improvements, "seed_means": table.seed_means,
            "figures": figures, "sweep": report}



def _jsonable(x):
    return json.loads(json.dumps(x, default=str))


def table_groups(args: CompareArgs, evaluations: dict[tuple[str, str], dict],
            seeds: dict[tuple[str, str], list[int]]) -> list[tables.MethodEvaluations]:
    """The table's groups: a learned method with the seeds it has on a config (none: no row)."""
    groups = []
    for config in args.configs:
        for name in args.methods:
            if METHODS[name].learned:
                found = [(s, evaluations[(config, tables.evaluation_key(name, s))])
                         for s in sorted(seeds.get((config, name), []))]
                if found:
                    groups.append(tables.MethodEvaluations(config_stem(config), name, [s for s, _ in found],
                                                           [d for _, d in found]))
            else:
                groups.append(tables.MethodEvaluations(config_stem(config), name, [], [evaluations[(config, name)]]))
    return groups
