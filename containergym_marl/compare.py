"""The benchmark's main job: compare decentralised and centralised policies, with tables and figures.

    containergym-marl compare                                   # the shipped policies, evaluated: minutes
    containergym-marl compare --train                           # a quick training look: 30k samples per run
    containergym-marl compare --configs n5_m2_dt120 n11_m2_dt120 --methods rule_based rule_based_agents \\
        ppo shared_ppo shared_ppo_team --seeds 1 2 3 --timesteps paper   # the paper's budgets: hours

**Shipped policies** (the default: no ``--train`` and no training option, that is none of
``--timesteps``, ``--seeds``, ``--runs``, ``--n-envs``, ``--hp``, ``--checkpoint-every``): nothing is
trained. The repository publishes the comparison's runs in ``results/paper_rows/runs/``
(``baselines/publish_results.py``; ``--shipped`` names another such folder, which is only read).
On every row of :data:`PAPER_ROWS` it evaluates the rule-based controllers and, for each learned
method of :data:`PAPER_METHODS` with finished shipped runs (a readable ``final_model.zip``; runs
published with only a checkpoint are still training and are skipped), the best model of its best
seed, ranked by the published evaluations (``<shipped>/evaluations/``); a seed without a published
evaluation of the same model, plant and protocol is evaluated too. The other seeds' published
evaluations complete the table (median, IQM), so it reads as the sweep's own. Rows without shipped
policies are named.

**Training** (``--train``, or any training option): for every configuration it trains (or reuses)
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
import re
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from containergym_marl.config import load_config
from containergym_marl.evaluation import table as tables
from containergym_marl.files import atomic_write_text
from containergym_marl.methods import COMPARABLE, METHODS, PAIRS, Method
from containergym_marl.rundir import run_name


#: Which figures compare draws: none; the headline figures (:data:`HEADLINE_ROW`, or the first row
#: compared: the reward and emptying-volume ECDFs and one episode of each method's best policy); or
#: all of them for every row (also PU timelines and the reward functions).
FIGURE_SETS = ("none", "headline", "all")
#: The row whose figures are the headline ones (the contention row: 11 containers, 2 PUs).
HEADLINE_ROW = "n11_m2_dt120"
#: The samples per run of ``compare --train`` (a look in minutes, not a result).
QUICK_TIMESTEPS = 30_000
#: The rows of the comparison the repository publishes (baselines/sweep_paper_rows.sh): the paper's
#: eight configurations and the 16-container plant, in the table's order.
PAPER_ROWS = ("n5_m2_dt60", "n5_m2_dt120", "n5_m5_dt60", "n5_m5_dt120", "n11_m2_dt60", "n11_m2_dt120",
              "n11_m11_dt60", "n11_m11_dt120", "n16_m2_dt120")
#: Its methods: the rule-based controllers, centralised PPO and shared PPO (individual and team rewards).
PAPER_METHODS = ("rule_based", "rule_based_agents", "ppo", "shared_ppo", "shared_ppo_team")
#: Where the repository publishes the comparison's runs and evaluations (baselines/publish_results.py).
SHIPPED = "results/paper_rows"


@dataclass
class CompareArgs:
    """A comparison of methods on plant configurations (see the module docstring).

    ``timesteps`` None: the paper's budget of each config (2M samples for n = 5, 5M for n >= 11).
    ``n_envs`` None: each algorithm's default. ``address`` None: ``$RAY_ADDRESS`` if set, else a
    local Ray instance with ``num_cpus`` CPUs (None: all cores).

    ``shipped`` set (a folder that baselines/publish_results.py wrote, e.g. :data:`SHIPPED`): train
    nothing and evaluate the finished runs published there instead (see the module docstring);
    ``timesteps``, ``seeds``, ``runs``, ``n_envs``, ``checkpoint_every`` and ``hyperparams`` are then
    unused (each run was trained as its args.json says), and ``timesteps`` must stay None.
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
    figures: str = "headline"  # one of FIGURE_SETS
    reevaluate: bool = False
    address: str | None = None
    num_cpus: int | None = None
    max_retries: int = 3
    hyperparams: dict = field(default_factory=dict)  # extra SB3 arguments for every learned method
    shipped: str | None = None  # evaluate the finished runs published in this folder; train nothing


def _validate(args: CompareArgs) -> None:
    if args.figures not in FIGURE_SETS:
        raise ValueError(f"figures: expected one of {FIGURE_SETS}, got {args.figures!r}")
    unknown = [m for m in args.methods if m not in METHODS]
    if unknown:
        raise ValueError(f"methods: unknown method(s) {unknown}; choose from {list(COMPARABLE)}")
    by_script = [f"{m} (trained by {METHODS[m].algorithm.trainer})" for m in args.methods if m not in COMPARABLE]
    if by_script:
        raise ValueError(f"methods: compare does not train {', '.join(by_script)}; choose from {list(COMPARABLE)}")
    for what in ("configs", "methods", "seeds"):
        values = getattr(args, what)
        repeated = sorted({v for v in values if values.count(v) > 1}, key=str)
        if repeated:
            raise ValueError(f"{what}: {', '.join(map(str, repeated))} given more than once")
    for c in args.configs:
        load_config(c)  # ConfigError for unknown names, before any work
    if args.shipped is not None:
        if args.timesteps is not None or args.runs is not None:
            raise ValueError("shipped: the shipped policies are evaluated as they were trained; "
                             "timesteps and runs are for training (leave shipped unset to train)")
        if not Path(args.shipped).is_dir():
            raise FileNotFoundError(
                f"shipped policies: no folder {args.shipped!r} (the repository publishes them in {SHIPPED}/; "
                f"run from the repository's root, name the folder with --shipped, or train with --train)")
    elif any(METHODS[m].learned for m in args.methods) and not args.seeds:
        raise ValueError("seeds: at least one training seed is needed")
    if args.timesteps is not None and args.timesteps <= 0:
        raise ValueError(f"timesteps: expected a positive budget, got {args.timesteps}")
    if args.episodes <= 0:
        raise ValueError(f"episodes: expected at least one test episode, got {args.episodes}")


def budget(args: CompareArgs, config: str) -> int:
    """Samples per training run on ``config``: ``args.timesteps``, or the paper's budget."""
    if args.timesteps is not None:
        return int(args.timesteps)
    from containergym_marl.algorithms import paper_budget

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
                     "hyperparams": dict(args.hyperparams), **method.train_settings()}
            for seed in args.seeds:
                run = run_name(name, config, seed)
                specs.append(RunSpec(run, name, method.algo, config, seed, budget(args, config),
                                     str(runs / run), train))
    return sorted(specs, key=lambda s: -s.timesteps)


def _fingerprint(args: CompareArgs, config: str, method: Method, run: str | None, model_sha: str | None,
                 timesteps: int | None = None) -> dict:
    """What an evaluation depends on besides the code: stored with it, compared to reuse it.
    ``timesteps``: the run's budget (default: this comparison's budget of ``config``)."""
    from containergym_marl.evaluation import EvalProtocol
    from containergym_marl.manifest import sha256_bytes

    plant = EvalProtocol(episodes=args.episodes).plant(config)
    if method.learned and timesteps is None:
        timesteps = budget(args, config)
    return {"run": run, "timesteps": timesteps if method.learned else None,
            "model_sha256": model_sha, "plant_sha256": sha256_bytes(plant.to_toml().encode()),
            "arbitration": method.arbitration}


def _cached(path: Path, fingerprint: dict, protocol: dict) -> dict | None:
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
    except ValueError:
        return None
    return data if data.get("compare") == fingerprint and data.get("protocol") == protocol else None


def _figure_configs(args: CompareArgs) -> list[str]:
    """The configs whose figures this comparison draws (``args.figures``)."""
    if args.figures == "none":
        return []
    if args.figures == "all":
        return list(args.configs)
    return [next((c for c in args.configs if _stem(c) == HEADLINE_ROW), args.configs[0])]


def _figures(records: dict[str, dict[str, list]], out: Path, every: bool = False, stream=None) -> list[Path]:
    """The paper's figures for each config from ``records[config][method]`` (episode records): the
    reward and emptying-volume ECDFs and an episode of each method; ``every`` adds each method's PU
    timeline and each container's reward function. One progress line per config."""
    from containergym_marl.evaluation import plots

    fig_dir = out / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for config, by_method in records.items():
        started = time.perf_counter()
        cfg = load_config(config)
        stem = fig_dir / _stem(config)
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
        print(f"figures: {_stem(config)}: {len(drawn)} drawn in {time.perf_counter() - started:.0f}s "
              f"({len(written)} so far)", file=stream or sys.stdout, flush=True)
    return written


@dataclass
class _Plan:
    """What a compare call has to do, found from the files alone (no Ray)."""

    specs: list  # every training run (RunSpec)
    finished: set[str]  # runs finished with the same budget: reused
    to_train: list  # RunSpecs to start or resume
    evaluations: dict[tuple[str, str], dict]  # (config, file stem) -> reused evaluation JSON
    to_evaluate: list  # (EvalSpec, source): source a RunSpec to wait for, a finished run's files, or None
    seeds: dict[tuple[str, str], list[int]] = field(default_factory=dict)  # (config, learned method) -> its seeds
    budgets: dict[str, int] = field(default_factory=dict)  # run name -> its budget in samples
    shipped: "_Shipped | None" = None  # what the shipped folder offers (shipped policies only)


def _eval_spec(args: CompareArgs, config: str, name: str, seed: int | None):
    from containergym_marl.sweep import EvalSpec

    method = METHODS[name]
    return EvalSpec(tables.evaluation_key(name, seed), name, config, args.episodes, seed=seed,
                    arbitration=method.arbitration)


def _run_files(run_dir: str | Path) -> dict[str, dict[str, bytes]]:
    from containergym_marl.evaluation.runs import evaluated_files

    run = Path(run_dir)
    return {"files": {f: (run / f).read_bytes() for f in evaluated_files(run)}}


def _model_sha(source: dict[str, dict[str, bytes]]) -> str:
    from containergym_marl.evaluation.runs import evaluated_model
    from containergym_marl.manifest import sha256_bytes

    return sha256_bytes(evaluated_model(source["files"]))


def _plan(args: CompareArgs, out: Path, runs: Path) -> _Plan:
    from containergym_marl.evaluation import EvalProtocol
    from containergym_marl.sweep import check_budget

    protocol = asdict(EvalProtocol(episodes=args.episodes))
    specs = run_specs(args, runs)
    finished = {s.name for s in specs if check_budget(s)}  # raises for a finished run with another budget
    by_run = {s.name: s for s in specs}
    plan = _Plan(specs, finished, [s for s in specs if s.name not in finished], {}, [],
                 seeds={(c, m): list(args.seeds) for c in args.configs for m in args.methods if METHODS[m].learned},
                 budgets={s.name: s.timesteps for s in specs})
    for config in args.configs:
        for name in args.methods:
            method = METHODS[name]
            for seed in args.seeds if method.learned else [None]:
                spec = _eval_spec(args, config, name, seed)
                if seed is None:
                    fingerprint, source = _fingerprint(args, config, method, None, None), None
                elif (run := by_run[run_name(name, config, seed)]).name in finished:
                    source = _run_files(run.run_dir)
                    model_sha = _model_sha(source)
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


# ---- the shipped policies -------------------------------------------------------------------------
@dataclass
class _Shipped:
    """What a shipped folder offers a comparison, from its files alone."""

    folder: Path
    learned: dict[str, dict[str, list[int]]] = field(default_factory=dict)  # config -> method -> finished seeds
    best: dict[tuple[str, str], int] = field(default_factory=dict)  # (config, method) -> best published seed
    published: dict[tuple[str, str], dict] = field(default_factory=dict)  # (config, key) -> published evaluation
    training: list[str] = field(default_factory=list)  # runs published unfinished (skipped), with how far
    unusable: list[str] = field(default_factory=list)  # finished runs that cannot be evaluated, with why
    missing: list[str] = field(default_factory=list)  # configs without any shipped learned policy
    copied: list[str] = field(default_factory=list)  # published evaluations copied into --out by this call

    def lines(self, methods: list[str]) -> list[str]:
        """What is shipped, skipped and missing, in words."""
        out = []
        for config, by_method in self.learned.items():
            what = []
            for method, seeds in by_method.items():
                best = self.best.get((config, method))
                what.append(f"{method} (seed{'s' * (len(seeds) > 1)} {', '.join(map(str, seeds))}"
                            + (f"; best s{best}" if best is not None and len(seeds) > 1 else "") + ")")
            out.append(f"shipped policies on {config}: {', '.join(what)}")
        if self.training:
            out.append("skipped, still training (published with a checkpoint, no final model yet): "
                       + ", ".join(self.training))
        if self.unusable:
            out.append("skipped: " + "; ".join(self.unusable))
        learned = [m for m in methods if METHODS[m].learned]
        if learned and self.missing:
            rule_based = [m for m in methods if not METHODS[m].learned]
            out.append(f"no shipped policies yet on {', '.join(self.missing)}"
                       + (f" ({' and '.join(rule_based)} only)" if rule_based else "")
                       + ": the paper-rows sweep is still training them")
        return out


def _shipped_runs(folder: Path, config: str, method: str) -> list[tuple[int, Path]]:
    """(seed, run directory) of ``method`` on ``config`` in ``folder/runs``, by seed."""
    pattern = re.compile(rf"^{re.escape(method)}_{re.escape(_stem(config))}_s(\d+)$")
    runs = folder / "runs"
    found = [(int(m.group(1)), p) for p in (runs.iterdir() if runs.is_dir() else []) if p.is_dir()
             and (m := pattern.match(p.name))]
    return sorted(found)


def _shipped_plan(args: CompareArgs, out: Path) -> _Plan:
    """The evaluations of the shipped policies: every rule-based controller; for each learned
    method, the best published seed and every finished seed without a published evaluation of the
    same model, plant and protocol are evaluated, the other seeds' published evaluations reused.
    Reads the shipped folder only."""
    from containergym_marl.evaluation import EvalProtocol
    from containergym_marl.manifest import sha256_bytes
    from containergym_marl.rundir import finished_budget
    from containergym_marl.manifest import check as manifest_check
    from containergym_marl.manifest import read_manifest
    from containergym_marl.rundir import checkpoints, model_file

    folder = Path(args.shipped)
    manifest = read_manifest(folder)
    protocol = asdict(EvalProtocol(episodes=args.episodes))
    shipped = _Shipped(folder)
    plan = _Plan([], set(), [], {}, [], shipped=shipped)

    def use(config: str, spec, fingerprint: dict, source, published: dict | None = None) -> None:
        path = out / "evaluations" / _stem(config) / f"{spec.key}.json"
        cached = None if args.reevaluate else _cached(path, fingerprint, protocol)
        if cached is not None:
            plan.evaluations[(config, spec.key)] = cached
        elif published is not None:  # a published evaluation of this very model: copied into --out
            data = {**published, "copied_from": str(folder / "evaluations" / _stem(config) / f"{spec.key}.json")}
            path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(path, json.dumps(data, indent=2) + "\n")
            plan.evaluations[(config, spec.key)] = data
            shipped.copied.append(f"{_stem(config)}/{spec.key}")
        else:
            plan.to_evaluate.append((spec, source))

    for config in args.configs:
        stem = _stem(config)
        for name in args.methods:
            method = METHODS[name]
            if not method.learned:
                use(config, _eval_spec(args, config, name, None), _fingerprint(args, config, method, None, None), None)
                continue
            found = []  # (seed, files, fingerprint, published evaluation or None)
            for seed, run in _shipped_runs(folder, config, name):
                trained = finished_budget(run)
                if trained is None:
                    ckpt = checkpoints(run)
                    try:
                        of = f" of {int(json.loads((run / 'args.json').read_text())['timesteps']):,}"
                    except (OSError, ValueError, KeyError, TypeError):
                        of = ""
                    shipped.training.append(f"{run.name}" + (f" ({ckpt[0][0]:,}{of} samples)" if ckpt else ""))
                    continue
                saved = json.loads((run / "args.json").read_text())
                if saved.get("algo") != method.algo:
                    shipped.unusable.append(f"{run.name} was trained as {saved.get('algo')}, not as {name}")
                    continue
                if (differ := [f"{k}={saved.get(k)}" for k, v in method.train_settings().items() if saved.get(k) != v]):
                    shipped.unusable.append(f"{run.name} was trained with {', '.join(differ)}, not as {name}")
                    continue
                best_name = model_file(run, "best")
                if not (run / best_name).is_file():
                    shipped.unusable.append(f"{run.name} has no best model (no training episode finished)")
                    continue
                files = _run_files(run)
                for file_name, data in files["files"].items():  # never a model changed after publication
                    manifest_check(folder, f"runs/{run.name}/{file_name}", data, manifest)
                fingerprint = _fingerprint(args, config, method, run.name, sha256_bytes(files["files"][best_name]),
                                           timesteps=trained)
                published = _cached(folder / "evaluations" / stem / f"{tables.evaluation_key(name, seed)}.json",
                                    fingerprint, protocol)
                found.append((seed, files, fingerprint, published))
                plan.budgets[run.name] = trained
            if not found:
                continue
            shipped.learned.setdefault(stem, {})[name] = [seed for seed, *_ in found]
            plan.seeds[(config, name)] = [seed for seed, *_ in found]
            plan.finished |= {run_name(name, stem, seed) for seed, *_ in found}
            means = {seed: float(np.mean([e["cumulative_reward"] for e in p["episodes"]]))
                     for seed, _, _, p in found if p is not None}
            best = max(means, key=lambda s: (means[s], -s)) if means else None  # the table's rule: ties -> first seed
            if best is not None:
                shipped.best[(stem, name)] = best
            for seed, files, fingerprint, published in found:
                spec = _eval_spec(args, config, name, seed)
                if published is not None:
                    shipped.published[(config, spec.key)] = published
                use(config, spec, fingerprint, files, None if seed == best or args.reevaluate else published)
        if not shipped.learned.get(stem):
            shipped.missing.append(stem)
    return plan


def _save_evaluation(args: CompareArgs, out: Path, spec, result, model_sha: str | None,
                     timesteps: int | None = None) -> dict:
    """The evaluation as JSON (EvaluationResult.to_json plus compare's fingerprint), written to
    ``<out>/evaluations/<config>/<key>.json``."""
    run = None if spec.seed is None else run_name(spec.method, spec.config, spec.seed)
    data = json.loads(result.to_json())
    data["compare"] = _fingerprint(args, spec.config, METHODS[spec.method], run, model_sha, timesteps)
    path = out / "evaluations" / _stem(spec.config) / f"{spec.key}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(data, indent=2) + "\n")
    return data


def compare(args: CompareArgs, stream=None) -> dict:
    """Run the comparison; returns the table rows, the improvements and what the sweep did (also
    written to ``args.out``: table.*, sweep.json, evaluations/, figures/). Raises SweepError when
    tasks failed after Ray's retries; KeyboardInterrupt leaves every run resumable.

    With ``args.shipped`` it trains nothing and evaluates the shipped policies (module docstring)."""
    from containergym_marl.rundir import write_files
    from containergym_marl.sweep import Cluster, SweepError, estimate_rate, execute, format_duration

    stream = stream or sys.stdout

    def say(text: str = "") -> None:
        print(text, file=stream, flush=True)

    _validate(args)
    start = time.perf_counter()
    out = Path(args.out).resolve()
    if args.shipped is not None:  # 1. from the files alone
        plan = _shipped_plan(args, out)
        runs = Path(args.shipped).resolve() / "runs"
        say(f"compare: the shipped policies of {args.shipped}/, evaluated with the paper's test protocol "
            f"({args.episodes} episodes each); nothing is trained (--train trains, see --help)")
        for line in plan.shipped.lines(args.methods):
            say(f"  {line}")
        copied = len(plan.shipped.copied)
        say(f"compare: {len(args.configs)} config(s) × {len(args.methods)} method(s); "
            f"{len(plan.to_evaluate) + len(plan.evaluations)} evaluation(s): {len(plan.to_evaluate)} to run, "
            f"{len(plan.evaluations) - copied} reused from {args.out}/, {copied} published ones of the "
            f"shipped runs that are not their row's best")
    else:
        runs = Path(args.runs).resolve() if args.runs else out / "runs"
        plan = _plan(args, out, runs)
        started = sum(Path(s.run_dir).is_dir() for s in plan.to_train)
        say(f"compare: {len(args.configs)} config(s) × {len(args.methods)} method(s); {len(plan.specs)} training "
            f"run(s): {len(plan.finished)} finished, {len(plan.to_train)} to train ({started} of them started "
            f"before); {len(plan.to_evaluate) + len(plan.evaluations)} evaluation(s), {len(plan.evaluations)} reused")
    evaluations = dict(plan.evaluations)
    out.mkdir(parents=True, exist_ok=True)
    report: dict[str, Any] = {"ray": None, "trained": [], "reused": sorted(plan.finished), "evaluated": [],
                              "evaluations_reused": sorted(f"{_stem(c)}/{k}" for c, k in evaluations)}
    records: dict[str, dict[str, list]] = {}
    # Shipped policies: the evaluations keep their episode records for the figures (mostly one per
    # (config, method)); a training sweep evaluates every seed, so its figures evaluate the best again.
    figure_configs = _figure_configs(args)
    keep = bool(figure_configs) and args.shipped is not None
    kept: dict[tuple[str, str], list] = {}

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
                run = None if spec.seed is None else run_name(spec.method, spec.config, spec.seed)
                evaluations[(spec.config, spec.key)] = _save_evaluation(args, out, spec, result, model_sha,
                                                                        plan.budgets.get(run))
                report["evaluated"].append(f"{_stem(spec.config)}/{spec.key}")
                if keep and spec.config in figure_configs:
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
        groups = _groups(args, evaluations, plan.seeds)
        if figure_configs:
            records = _figure_records(args, [g for g in groups if g.config in map(_stem, figure_configs)], runs,
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
    figures = [str(p) for p in _figures(records, out, args.figures == "all", stream)]
    report["wall_s"] = round(time.perf_counter() - start, 1)
    if plan.shipped is not None:
        report["shipped"] = _shipped_report(plan.shipped, evaluations, report["evaluated"])
    atomic_write_text(out / "sweep.json", json.dumps({**meta, **report}, indent=2) + "\n")
    say()
    tables.print_table(table, stream, shipped=plan.shipped is not None)
    if plan.shipped is not None:
        say()
        for line in _shipped_summary(plan.shipped, report["shipped"], args.methods):
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


def _shipped_report(shipped: _Shipped, evaluations: dict[tuple[str, str], dict], evaluated: list[str]) -> dict:
    """What the shipped folder offered, and whether the policies evaluated now return what their
    published evaluations say (the same returns, episode by episode)."""
    fresh = {f"{_stem(c)}/{k}": (c, k) for c, k in evaluations}
    reproduced, differ = [], []
    for name in evaluated:
        key = fresh.get(name)
        if key is None or key not in shipped.published:
            continue
        now = [e["cumulative_reward"] for e in evaluations[key]["episodes"]]
        then = [e["cumulative_reward"] for e in shipped.published[key]["episodes"]]
        (reproduced if np.allclose(now, then, rtol=0, atol=1e-6) else differ).append(name)
    return {"folder": str(shipped.folder), "policies": shipped.learned,
            "best_seeds": {f"{c}/{m}": s for (c, m), s in shipped.best.items()},
            "still_training": shipped.training, "unusable": shipped.unusable,
            "without_shipped_policies": shipped.missing, "reproduced": reproduced, "differ": differ}


def _shipped_summary(shipped: _Shipped, report: dict, methods: list[str]) -> list[str]:
    lines = []
    if (n := len(report["reproduced"])) == 1:
        lines.append("The 1 shipped policy evaluated now returns what its published evaluation says, "
                     "episode by episode.")
    elif n:
        lines.append(f"The {n} shipped policies evaluated now return what their published evaluations say, "
                     f"episode by episode.")
    if report["differ"]:
        lines.append(f"Evaluated now, {', '.join(report['differ'])} return(s) other than the published evaluation "
                     f"(in {shipped.folder}/evaluations/): the simulator or the libraries changed since.")
    lines += [line[0].upper() + line[1:] + "." for line in shipped.lines(methods) if not line.startswith("shipped")]
    return lines


def _resume_point(spec) -> int:
    from containergym_marl.rundir import latest_checkpoint

    ckpt = latest_checkpoint(Path(spec.run_dir)) if Path(spec.run_dir).is_dir() else None
    return ckpt[1] if ckpt else 0


def _jsonable(x):
    return json.loads(json.dumps(x, default=str))


def _groups(args: CompareArgs, evaluations: dict[tuple[str, str], dict],
            seeds: dict[tuple[str, str], list[int]]) -> list[tables.MethodEvaluations]:
    """The table's groups: a learned method with the seeds it has on a config (none: no row)."""
    groups = []
    for config in args.configs:
        for name in args.methods:
            if METHODS[name].learned:
                found = [(s, evaluations[(config, tables.evaluation_key(name, s))])
                         for s in sorted(seeds.get((config, name), []))]
                if found:
                    groups.append(tables.MethodEvaluations(_stem(config), name, [s for s, _ in found],
                                                           [d for _, d in found]))
            else:
                groups.append(tables.MethodEvaluations(_stem(config), name, [], [evaluations[(config, name)]]))
    return groups


def _figure_records(args: CompareArgs, groups, runs: Path, cluster, stream,
                    kept: dict[tuple[str, str], list] | None = None) -> dict[str, dict[str, list]]:
    """Episode records of the best policy of each (config, method): those ``kept`` from this call's
    evaluations, the others evaluated again on Ray with records kept."""
    from containergym_marl.sweep import SweepError, execute

    config_of = {_stem(c): c for c in args.configs}
    kept = kept or {}
    jobs, records = [], {}
    for g in groups:
        seed = g.seeds[g.best] if g.seeds else None
        spec = _eval_spec(args, config_of[g.config], g.method, seed)
        if kept.get((spec.config, spec.key)):
            records.setdefault(spec.config, {})[spec.method] = kept[(spec.config, spec.key)]
            continue
        source = None if seed is None else _run_files(runs / run_name(g.method, g.config, seed))
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
    config_of = {_stem(c): c for c in records}
    ordered: dict[str, dict[str, list]] = {}
    for g in groups:
        config = config_of.get(g.config)
        if config is not None and g.method in records[config]:
            ordered.setdefault(config, {})[g.method] = records[config][g.method]
    return ordered


# ---- the command line (containergym-marl compare) -----------------------------------------------
#: What ``--timesteps paper`` gives on the command line (CompareArgs.timesteps None: the paper's budget).
PAPER_BUDGET = "paper"
#: The options that train: any of them (or --train) makes ``compare`` train instead of evaluating the
#: shipped policies (argparse destinations).
TRAINING_OPTIONS = ("timesteps", "seeds", "runs", "n_envs", "hp", "checkpoint_every")


def _timesteps(text: str) -> int | str:
    if text == PAPER_BUDGET:
        return PAPER_BUDGET
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
    what = parser.add_argument_group(
        "what to compare", "without --train, compare evaluates the shipped policies and trains nothing")
    what.add_argument("--configs", nargs="+", default=None, metavar="CONFIG",
                      help=f"plant configurations: built-in ({', '.join(list_configs())}) or paths (default: the "
                           f"paper rows, {' '.join(PAPER_ROWS)}, for the shipped policies; {' '.join(d.configs)} "
                           f"with --train)")
    what.add_argument("--methods", nargs="+", default=None, choices=list(COMPARABLE), metavar="METHOD",
                      help=f"methods to compare, from: {', '.join(COMPARABLE)} (default: {' '.join(PAPER_METHODS)} "
                           f"for the shipped policies; {' '.join(d.methods)} with --train)")
    what.add_argument("--episodes", type=int, default=d.episodes, help="test episodes per evaluation")
    what.add_argument("--out", default=d.out, help="tables, evaluations and figures")
    what.add_argument("--shipped", default=None, metavar="DIR",
                      help=f"the folder of published runs whose policies are evaluated, only read (default: "
                           f"{SHIPPED}, the repository's; baselines/publish_results.py writes such folders)")
    train = parser.add_argument_group(
        "training", "--train trains (or reuses the finished runs of --runs) instead of evaluating the shipped\n"
                    "policies; the other options here need it. compare says how long it will take before it starts")
    train.add_argument("--train", action="store_true",
                       help=f"train the learned methods: {QUICK_TIMESTEPS:,} samples per run unless --timesteps, "
                            f"a quick look in minutes, far from a result (default: evaluate the shipped policies)")
    train.add_argument("--timesteps", type=_timesteps, default=None, metavar="N|paper",
                       help="samples per training run; 'paper' = the paper's budget of each config "
                            f"(2M for n=5, 5M for n>=11) (default with --train: {QUICK_TIMESTEPS})")
    train.add_argument("--seeds", nargs="+", type=int, default=None, metavar="SEED",
                       help=f"training seeds of every learned method, distinct "
                            f"(default: {' '.join(map(str, d.seeds))})")
    train.add_argument("--runs", default=None,
                       help="run directories (default <out>/runs); on a cluster, a path every node reaches")
    train.add_argument("--checkpoint-every", type=int, default=None,
                       help=f"samples between checkpoints, what an interruption can lose (default: "
                            f"{d.checkpoint_every})")
    train.add_argument("--n-envs", type=int, default=None, help="parallel simulations per run (default: "
                                                                "the algorithm's, 8; DQN 1)")
    train.add_argument("--hp", nargs="*", default=None, metavar="KEY=VALUE",
                       help="extra SB3 hyperparameters for every learned method (default: none)")
    ray = parser.add_argument_group("execution")
    ray.add_argument("--address", default=None,
                     help="Ray cluster to run on (default: $RAY_ADDRESS, else a new local Ray instance)")
    ray.add_argument("--num-cpus", type=int, default=None,
                     help="CPUs of the local Ray instance, one training at a time each (default: all cores)")
    ray.add_argument("--max-retries", type=int, default=d.max_retries,
                     help="Ray retries of a task whose worker dies (a retried training resumes)")
    ray.add_argument("--bootstrap-reps", type=int, default=d.bootstrap_reps,
                     help="bootstrap replicates of every confidence interval")
    ray.add_argument("--reevaluate", action="store_true",
                     help="evaluate again even where an evaluation of the same model, plant and protocol exists")
    ray.add_argument("--figures", choices=FIGURE_SETS, default=d.figures,
                     help=f"figures to draw: none, the headline ones ({HEADLINE_ROW}, or the first row: reward and "
                          f"emptying-volume ECDFs, an episode of each method) or all, for every row")
    ray.add_argument("--no-figures", dest="figures", action="store_const", const="none",
                     help="the same as --figures none")


def args_from_namespace(ns: argparse.Namespace, hyperparams: dict) -> CompareArgs:
    """CompareArgs of a parsed ``compare`` command line: the shipped policies, or training with
    ``--train`` (each unset option then keeps CompareArgs' default). A training option without
    ``--train`` is refused rather than taken as a wish to train."""
    d = CompareArgs()
    common = dict(episodes=ns.episodes, out=ns.out, bootstrap_reps=ns.bootstrap_reps, figures=ns.figures,
                  reevaluate=ns.reevaluate, address=ns.address, num_cpus=ns.num_cpus, max_retries=ns.max_retries)
    given = [f"--{n.replace('_', '-')}" for n in TRAINING_OPTIONS if getattr(ns, n) is not None]
    if not ns.train:
        if given:
            raise ValueError(f"{', '.join(given)}: training options; add --train to train (without it compare "
                             f"evaluates the shipped policies and trains nothing)")
        return CompareArgs(configs=ns.configs or list(PAPER_ROWS), methods=ns.methods or list(PAPER_METHODS),
                           timesteps=None, shipped=ns.shipped or SHIPPED, **common)
    if ns.shipped is not None:
        raise ValueError(f"--shipped evaluates published runs and trains nothing; drop {', '.join(['--train', *given])} "
                         f"or --shipped")
    timesteps = ns.timesteps if ns.timesteps is not None else QUICK_TIMESTEPS
    return CompareArgs(configs=ns.configs or d.configs, methods=ns.methods or d.methods,
                       seeds=ns.seeds if ns.seeds is not None else d.seeds,
                       timesteps=None if timesteps == PAPER_BUDGET else timesteps, runs=ns.runs, n_envs=ns.n_envs,
                       checkpoint_every=ns.checkpoint_every if ns.checkpoint_every is not None else d.checkpoint_every,
                       hyperparams=hyperparams, **common)
