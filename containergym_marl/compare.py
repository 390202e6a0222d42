"""The benchmark's main job: compare decentralised and centralised policies, with tables and figures.

    containergym-marl compare                                   # a quick look: 30k samples per run, minutes
    containergym-marl compare --configs n5_m2_dt120 n11_m2_dt120 --methods rule_based rule_based_agents \\
        ppo shared_ppo shared_ppo_team --seeds 1 2 3 --timesteps paper   # the paper's budgets: hours

For every configuration it trains (or reuses) each learned method for each seed, evaluates every
policy with the paper's test protocol (δ = 120 s, T = 600, ``--episodes`` episodes, best model of
each run) and writes, to ``--out``:

* ``table.md`` / ``table.csv`` / ``table.json``: the paper's Table 1 shape plus the IQM over seeds
  with a bootstrap CI and the probability that each decentralised method beats its centralised
  counterpart (see :mod:`containergym_marl.evaluation.table`, which also regenerates the table from
  the evaluation files alone: ``python -m containergym_marl.evaluation.table OUT``);
* ``evaluations/<config>/``: every evaluation as a small JSON file;
* ``figures/``: episode rollouts, ECDFs, PU timelines and reward functions of the best seed of each method.

Methods (:data:`METHODS`): ``rule_based`` (centralised) and ``rule_based_agents`` (decentralised)
controllers; ``planner`` and ``planner_agents``, the rollout planner through each view
(:mod:`containergym_marl.policies.planner`, default settings); ``ppo``, ``trpo``, ``dqn``,
``maskable_ppo`` (centralised, SB3); ``shared_ppo`` (one PPO policy shared by the container agents,
individual rewards) and ``shared_ppo_team`` (the same with the team reward). Runs are
``<runs>/<method>_<config>_s<seed>/`` and train on the config as it is (the δ = 60 rows at
δ = 60 s); ``--timesteps paper`` gives each config the paper's budget (2M samples for n = 5, 5M for
n >= 11).

Execution on Ray (:mod:`containergym_marl.sweep`): one task per training run (one CPU each, torch
one thread), one per evaluation; tables and figures in the driver. By default compare starts a
local Ray instance with this machine's cores (``--num-cpus`` to change); ``--address`` (or
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

import argparse
import json
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from containergym_marl.config import load_config
from containergym_marl.evaluation import table as tables
from containergym_marl.files import atomic_write_text


@dataclass(frozen=True)
class Method:
    """A method of the comparison: a rule-based controller (``policy``, a class of
    containergym_marl.policies) or a training algorithm (``algo``, TrainArgs.algo) with its
    ``train`` settings; ``counterpart`` is the centralised method a decentralised one is compared with.
    Its view is the policy's or the algorithm's own (``training.algorithms.view_of``)."""

    name: str
    algo: str | None = None
    policy: str | None = None
    train: tuple[tuple[str, Any], ...] = ()
    counterpart: str | None = None

    @property
    def learned(self) -> bool:
        return self.algo is not None


#: The methods compare knows, by name.
METHODS: dict[str, Method] = {m.name: m for m in (
    Method("rule_based", policy="RuleBasedController"),
    Method("rule_based_agents", policy="RuleBasedAgents", counterpart="rule_based"),
    Method("planner", policy="RolloutPlanner"),
    Method("planner_agents", policy="PlannerAgents", counterpart="planner"),
    Method("ppo", algo="ppo"),
    Method("trpo", algo="trpo"),
    Method("dqn", algo="dqn"),
    Method("maskable_ppo", algo="maskable_ppo"),
    Method("shared_ppo", algo="shared_ppo", train=(("reward_mode", "individual"),),
           counterpart="ppo"),
    Method("shared_ppo_team", algo="shared_ppo", train=(("reward_mode", "team"),),
           counterpart="ppo"),
)}
#: (decentralised, centralised) pairs whose probability of improvement the table reports.
PAIRS = tuple((m.name, m.counterpart) for m in METHODS.values() if m.counterpart)
#: The samples per run of the quick default of the ``compare`` command (a look in minutes, not a result).
QUICK_TIMESTEPS = 30_000


@dataclass
class CompareArgs:
    """A comparison of methods on plant configurations (see the module docstring).

    ``timesteps`` None: the paper's budget of each config (2M samples for n = 5, 5M for n >= 11).
    ``n_envs`` None: each algorithm's default. ``address`` None: ``$RAY_ADDRESS`` if set, else a
    local Ray instance with ``num_cpus`` CPUs (None: all cores).
    """

    configs: list[str] = field(default_factory=lambda: ["n5_m2_dt120"])
    methods: list[str] = field(default_factory=lambda: ["rule_based", "rule_based_agents", "ppo", "shared_ppo"])
    seeds: list[int] = field(default_factory=lambda: [1, 2, 3])
    timesteps: int | None = None
    episodes: int = 15
    out: str = "results/compare"
    runs: str | None = None
    n_envs: int | None = None
    checkpoint_every: int = 200_000
    bootstrap_reps: int = 2000
    figures: bool = True
    reevaluate: bool = False
    address: str | None = None
    num_cpus: int | None = None
    max_retries: int = 3
    hyperparams: dict = field(default_factory=dict)  # extra SB3 arguments for every learned method


def _validate(args: CompareArgs) -> None:
    unknown = [m for m in args.methods if m not in METHODS]
    if unknown:
        raise ValueError(f"methods: unknown method(s) {unknown}; choose from {list(METHODS)}")
    for what in ("configs", "methods", "seeds"):
        values = getattr(args, what)
        repeated = sorted({v for v in values if values.count(v) > 1}, key=str)
        if repeated:
            raise ValueError(f"{what}: {', '.join(map(str, repeated))} given more than once")
    for c in args.configs:
        load_config(c)  # ConfigError for unknown names, before any work
    if any(METHODS[m].learned for m in args.methods) and not args.seeds:
        raise ValueError("seeds: at least one training seed is needed")
    if args.timesteps is not None and args.timesteps <= 0:
        raise ValueError(f"timesteps: expected a positive budget, got {args.timesteps}")
    if args.episodes <= 0:
        raise ValueError(f"episodes: expected at least one test episode, got {args.episodes}")


def budget(args: CompareArgs, config: str) -> int:
    """Samples per training run on ``config``: ``args.timesteps``, or the paper's budget."""
    if args.timesteps is not None:
        return int(args.timesteps)
    from containergym_marl.training.algorithms import paper_budget

    return paper_budget(load_config(config).n_containers)


def _stem(config: str) -> str:
    return Path(config).stem


def run_specs(args: CompareArgs, runs: Path) -> list:
    """The training runs of the comparison, longest first (better packing on the cluster)."""
    from containergym_marl.sweep import RunSpec

    specs = []
    for config in args.configs:
        for name in args.methods:
            method = METHODS[name]
            if not method.learned:
                continue
            train = {"n_envs": args.n_envs, "checkpoint_every": args.checkpoint_every,
                     "hyperparams": dict(args.hyperparams), **dict(method.train)}
            for seed in args.seeds:
                run = f"{name}_{_stem(config)}_s{seed}"
                specs.append(RunSpec(run, name, method.algo, config, seed, budget(args, config),
                                     str(runs / run), train))
    return sorted(specs, key=lambda s: -s.timesteps)


def _fingerprint(args: CompareArgs, config: str, method: Method, run: str | None, model_sha: str | None) -> dict:
    """What an evaluation depends on besides the code: stored with it, compared to reuse it."""
    from containergym_marl.evaluation import EvalProtocol
    from containergym_marl.sweep import sha256

    plant = EvalProtocol(episodes=args.episodes).plant(config)
    return {"run": run, "timesteps": budget(args, config) if method.learned else None,
            "model_sha256": model_sha, "plant_sha256": sha256(plant.to_toml().encode()),
            "arbitration": dict(method.train).get("arbitration", "fullest")}


def _cached(path: Path, fingerprint: dict, protocol: dict) -> dict | None:
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
    except ValueError:
        return None
    return data if data.get("compare") == fingerprint and data.get("protocol") == protocol else None


def _figures(records: dict[str, dict[str, list]], out: Path) -> list[Path]:
    """The paper's figures for each config from ``records[config][method]`` (episode records)."""
    from containergym_marl.evaluation import plots

    fig_dir = out / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for config, by_method in records.items():
        cfg = load_config(config)
        stem = fig_dir / _stem(config)
        plots.plot_emptying_volume_ecdfs(by_method, f"{stem}_emptying_volume_ecdfs", config=cfg)
        plots.plot_reward_ecdf(by_method, f"{stem}_reward_ecdf")
        written += [Path(f"{stem}_emptying_volume_ecdfs"), Path(f"{stem}_reward_ecdf")]
        for method, rec_list in by_method.items():
            plots.plot_episode(rec_list[0], f"{stem}_episode_{method}", config=cfg)
            plots.plot_pu_timeline(rec_list[0], f"{stem}_pu_timeline_{method}", config=cfg)
            written += [Path(f"{stem}_episode_{method}"), Path(f"{stem}_pu_timeline_{method}")]
        for name in cfg.container_names:
            plots.plot_reward_function(cfg, name, f"{stem}_reward_function_{name}")
            written.append(Path(f"{stem}_reward_function_{name}"))
    return written


@dataclass
class _Plan:
    """What a compare call has to do, found from the files alone (no Ray)."""

    specs: list  # every training run (RunSpec)
    finished: set[str]  # runs finished with the same budget: reused
    to_train: list  # RunSpecs to start or resume
    evaluations: dict[tuple[str, str], dict]  # (config, file stem) -> reused evaluation JSON
    to_evaluate: list  # (EvalSpec, source): source a RunSpec to wait for, a finished run's files, or None


def _eval_spec(args: CompareArgs, config: str, name: str, seed: int | None):
    from containergym_marl.sweep import EvalSpec

    method = METHODS[name]
    return EvalSpec(name if seed is None else f"{name}_s{seed}", name, config, args.episodes, policy=method.policy,
                    seed=seed, arbitration=dict(method.train).get("arbitration", "fullest"))


def _run_files(run_dir: str | Path) -> dict[str, dict[str, bytes]]:
    run = Path(run_dir)
    return {"files": {f: (run / f).read_bytes() for f in ("args.json", "best_model.zip")}}


def _plan(args: CompareArgs, out: Path, runs: Path) -> _Plan:
    from containergym_marl.evaluation import EvalProtocol
    from containergym_marl.sweep import check_budget, sha256

    protocol = asdict(EvalProtocol(episodes=args.episodes))
    specs = run_specs(args, runs)
    finished = {s.name for s in specs if check_budget(s)}  # raises for a finished run with another budget
    by_run = {s.name: s for s in specs}
    plan = _Plan(specs, finished, [s for s in specs if s.name not in finished], {}, [])
    for config in args.configs:
        for name in args.methods:
            method = METHODS[name]
            for seed in args.seeds if method.learned else [None]:
                spec = _eval_spec(args, config, name, seed)
                if seed is None:
                    fingerprint, source = _fingerprint(args, config, method, None, None), None
                elif (run := by_run[f"{name}_{_stem(config)}_s{seed}"]).name in finished:
                    source = _run_files(run.run_dir)
                    model_sha = sha256(source["files"]["best_model.zip"])
                    fingerprint = _fingerprint(args, config, method, run.name, model_sha)
                else:
                    fingerprint, source = None, run  # trained in this sweep: evaluated after
                path = out / "evaluations" / _stem(config) / f"{spec.key}.json"
                cached = None if args.reevaluate or fingerprint is None else _cached(path, fingerprint, protocol)
                if cached is not None:
                    plan.evaluations[(config, spec.key)] = cached
                else:
                    plan.to_evaluate.append((spec, source))
    return plan


def _save_evaluation(args: CompareArgs, out: Path, spec, result, model_sha: str | None) -> dict:
    """The evaluation as JSON (EvaluationResult.to_json plus compare's fingerprint), written to
    ``<out>/evaluations/<config>/<key>.json``."""
    run = None if spec.seed is None else f"{spec.method}_{_stem(spec.config)}_s{spec.seed}"
    data = json.loads(result.to_json())
    data["compare"] = _fingerprint(args, spec.config, METHODS[spec.method], run, model_sha)
    path = out / "evaluations" / _stem(spec.config) / f"{spec.key}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(data, indent=2) + "\n")
    return data


def compare(args: CompareArgs, stream=None) -> dict:
    """Run the comparison; returns the table rows, the improvements and what the sweep did (also
    written to ``args.out``: table.*, sweep.json, evaluations/, figures/). Raises SweepError when
    tasks failed after Ray's retries; KeyboardInterrupt leaves every run resumable."""
    from containergym_marl.sweep import Cluster, SweepError, estimate_rate, execute, format_duration, write_files

    stream = stream or sys.stdout

    def say(text: str = "") -> None:
        print(text, file=stream, flush=True)

    _validate(args)
    start = time.perf_counter()
    out = Path(args.out).resolve()
    runs = Path(args.runs).resolve() if args.runs else out / "runs"
    plan = _plan(args, out, runs)  # 1. from the files alone
    evaluations = dict(plan.evaluations)
    started = sum(Path(s.run_dir).is_dir() for s in plan.to_train)
    say(f"compare: {len(args.configs)} config(s) × {len(args.methods)} method(s); {len(plan.specs)} training "
        f"run(s): {len(plan.finished)} finished, {len(plan.to_train)} to train ({started} of them started before); "
        f"{len(plan.to_evaluate) + len(evaluations)} evaluation(s), {len(evaluations)} reused")
    out.mkdir(parents=True, exist_ok=True)
    report: dict[str, Any] = {"ray": None, "trained": [], "reused": sorted(plan.finished), "evaluated": [],
                              "evaluations_reused": sorted(f"{_stem(c)}/{k}" for c, k in evaluations)}
    records: dict[str, dict[str, list]] = {}

    cluster = Cluster(args.address, args.num_cpus, args.max_retries)
    try:  # 2. the job graph on Ray: trainings, their evaluations, then the figures' records
        if plan.to_train or plan.to_evaluate:
            report["ray"] = cluster.describe()
            say(f"Ray: {report['ray']}")
            if plan.to_train:
                samples = sum(s.timesteps - _resume_point(s) for s in plan.to_train)
                rate, slots = estimate_rate(runs), min(cluster.cpus(), len(plan.to_train))
                say(f"training: {samples:,} samples in {len(plan.to_train)} run(s), about "
                    f"{format_duration(samples / (rate * slots))} at ~{rate:,.0f} samples/s per run, {slots} at a time")
            def save(spec, value) -> None:  # each evaluation is written as it lands
                result, model_sha = value
                evaluations[(spec.config, spec.key)] = _save_evaluation(args, out, spec, result, model_sha)
                report["evaluated"].append(f"{_stem(spec.config)}/{spec.key}")

            done = execute(cluster, plan.to_train, plan.to_evaluate, stream=stream,
                           on_run_done=lambda spec, result: write_files(spec.run_dir, result["files"]),
                           on_evaluation_done=save)
            for name, result in done.runs.items():
                report["trained"].append({**{k: v for k, v in result.items() if k != "files"},
                                          "attempts": done.attempts.get(name, 1)})
            if done.failures:
                raise SweepError(f"{len(done.failures)} task(s) failed: "
                                 + "; ".join(f"{k}: {v}" for k, v in done.failures.items())
                                 + ". Finished runs and evaluations are kept; rerun the same command to retry.")
        groups = _groups(args, evaluations)
        if args.figures:
            records = _figure_records(args, groups, runs, cluster, stream)
    except KeyboardInterrupt:
        say(f"\ninterrupted: finished runs are kept, the others resume from their last checkpoint when the "
            f"same command runs again (runs: {runs}/)")
        raise
    finally:
        cluster.close()

    # 3. Table and figures in the driver.
    table = tables.build_table(groups, PAIRS, args.bootstrap_reps)
    meta = {"args": _jsonable(asdict(args))}
    paths = table.write(out, meta)
    figures = [str(p) for p in _figures(records, out)] if args.figures else []
    report["wall_s"] = round(time.perf_counter() - start, 1)
    atomic_write_text(out / "sweep.json", json.dumps({**meta, **report}, indent=2) + "\n")
    say()
    say(table.markdown)
    say(f"table: {paths[0]} (also table.csv, table.json); what the sweep did: {out / 'sweep.json'}; "
        f"evaluations: {out / 'evaluations'}/"
        + (f"; figures: {out / 'figures'}/ ({len(figures)} figures, PNG and SVG)" if figures else "")
        + f"; runs: {runs}/")
    say(f"compare took {format_duration(report['wall_s'])}: {len(report['trained'])} run(s) trained or resumed, "
        f"{len(plan.finished)} reused, {len(report['evaluated'])} evaluation(s) run, "
        f"{len(report['evaluations_reused'])} reused")
    return {**meta, "rows": table.rows, "improvements": table.improvements, "seed_means": table.seed_means,
            "figures": figures, "sweep": report}


def _resume_point(spec) -> int:
    from containergym_marl.training.runs import latest_checkpoint

    ckpt = latest_checkpoint(Path(spec.run_dir)) if Path(spec.run_dir).is_dir() else None
    return ckpt[1] if ckpt else 0


def _jsonable(x):
    return json.loads(json.dumps(x, default=str))


def _groups(args: CompareArgs, evaluations: dict[tuple[str, str], dict]) -> list[tables.MethodEvaluations]:
    groups = []
    for config in args.configs:
        for name in args.methods:
            if METHODS[name].learned:
                found = [(s, evaluations[(config, f"{name}_s{s}")]) for s in sorted(args.seeds)]
                groups.append(tables.MethodEvaluations(_stem(config), name, [s for s, _ in found],
                                                       [d for _, d in found]))
            else:
                groups.append(tables.MethodEvaluations(_stem(config), name, [], [evaluations[(config, name)]]))
    return groups


def _figure_records(args: CompareArgs, groups, runs: Path, cluster, stream) -> dict[str, dict[str, list]]:
    """Episode records of the best policy of each (config, method), evaluated again on Ray with records kept."""
    from containergym_marl.sweep import SweepError, execute

    config_of = {_stem(c): c for c in args.configs}
    jobs = []
    for g in groups:
        seed = g.seeds[g.best] if g.seeds else None
        source = None if seed is None else _run_files(runs / f"{g.method}_{g.config}_s{seed}")
        jobs.append((_eval_spec(args, config_of[g.config], g.method, seed), source))
    print(f"figures: evaluating the best policy of {len(jobs)} (config, method) pair(s) again, keeping the records",
          file=stream, flush=True)
    done = execute(cluster, [], jobs, keep_records=True, stream=stream)
    if done.failures:
        raise SweepError("figure evaluations failed: " + "; ".join(f"{k}: {v}" for k, v in done.failures.items()))
    records: dict[str, dict[str, list]] = {}
    for spec, _ in jobs:
        result, _sha = done.evaluations[(spec.config, spec.key)]
        records.setdefault(spec.config, {})[spec.method] = result.records
    return records


# ---- the command line (containergym-marl compare) -----------------------------------------------
def _timesteps(text: str) -> int | None:
    if text == "paper":
        return None
    try:
        value = int(float(text)) if "e" in text.lower() else int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of samples or 'paper', got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive number of samples, got {value}")
    return value


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    """Shows every option's default, unless its help already says what the default is."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        return text if "default" in text else super()._get_help_string(action)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``containergym-marl compare``."""
    from containergym_marl.config import list_configs

    d = CompareArgs()
    parser.add_argument("--configs", nargs="+", default=d.configs, metavar="CONFIG",
                        help=f"plant configurations: built-in ({', '.join(list_configs())}) or paths")
    parser.add_argument("--methods", nargs="+", default=d.methods, choices=list(METHODS), metavar="METHOD",
                        help=f"methods to compare, from: {', '.join(METHODS)}")
    parser.add_argument("--seeds", nargs="+", type=int, default=d.seeds, metavar="SEED",
                        help="training seeds of every learned method (distinct)")
    parser.add_argument("--timesteps", type=_timesteps, default=QUICK_TIMESTEPS, metavar="N|paper",
                        help="samples per training run; 'paper' = the paper's budget of each config "
                             "(2M for n=5, 5M for n>=11); the default, %(default)s, is a quick look in minutes, "
                             "far from a result")
    parser.add_argument("--episodes", type=int, default=d.episodes, help="test episodes per evaluation")
    parser.add_argument("--out", default=d.out, help="tables, evaluations and figures")
    parser.add_argument("--runs", default=None,
                        help="run directories (default <out>/runs); on a cluster, a path every node reaches")
    parser.add_argument("--address", default=None,
                        help="Ray cluster to run on (default: $RAY_ADDRESS, else a new local Ray instance)")
    parser.add_argument("--num-cpus", type=int, default=None,
                        help="CPUs of the local Ray instance, one training at a time each (default: all cores)")
    parser.add_argument("--max-retries", type=int, default=d.max_retries,
                        help="Ray retries of a task whose worker dies (a retried training resumes)")
    parser.add_argument("--checkpoint-every", type=int, default=d.checkpoint_every,
                        help="samples between checkpoints (what an interruption can lose)")
    parser.add_argument("--n-envs", type=int, default=None, help="parallel simulations per run (default: "
                                                                 "the algorithm's, 8; DQN 1)")
    parser.add_argument("--hp", nargs="*", default=[], metavar="KEY=VALUE",
                        help="extra SB3 hyperparameters for every learned method")
    parser.add_argument("--bootstrap-reps", type=int, default=d.bootstrap_reps,
                        help="bootstrap replicates of every confidence interval")
    parser.add_argument("--reevaluate", action="store_true",
                        help="evaluate again even where an evaluation of the same model, plant and protocol exists")
    parser.add_argument("--no-figures", action="store_true", help="write no figures (they are on by default)")


def args_from_namespace(ns: argparse.Namespace, hyperparams: dict) -> CompareArgs:
    return CompareArgs(configs=ns.configs, methods=ns.methods, seeds=ns.seeds, timesteps=ns.timesteps,
                       episodes=ns.episodes, out=ns.out, runs=ns.runs, n_envs=ns.n_envs,
                       checkpoint_every=ns.checkpoint_every, bootstrap_reps=ns.bootstrap_reps,
                       figures=not ns.no_figures, reevaluate=ns.reevaluate, address=ns.address,
                       num_cpus=ns.num_cpus, max_retries=ns.max_retries, hyperparams=hyperparams)

