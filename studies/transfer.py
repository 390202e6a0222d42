"""Does a policy shared by the container agents carry over to larger plants? (issue 40, item 3)

    python studies/transfer.py                    # 2 methods x 2 source plants x 5 seeds, then every target
    python studies/transfer.py --no-in-domain --centralised   # zero-shot and the controllers only
    python studies/transfer.py --report           # the table from the files there, nothing run
    python studies/transfer.py --smoke            # one method, one seed, tiny budget, two small targets

**Question.** A centralised controller's input and action space grow with n, so it is retrained for
every plant; one policy shared by the container agents acts on a fixed-size observation and could in
principle run on a plant of any size. With the ``portable`` observation (14 entries on every plant,
:mod:`containergym_marl.core.observations`) the same network runs on all of them: trained on the paper's
contended plants (:data:`SOURCES`), how does it do on the larger plants built from the 16-container
plant (``configs/scaled.py``), zero-shot, next to the same method trained on that plant, a centralised
PPO trained on that plant, the rule-based controllers and the planner there?

**Protocol.** Each method (:data:`METHODS`, ``--hp observation=portable``) x source plant x seed
(:data:`SEEDS`, 101-105: no published run uses them) is one run at the paper's budget; with
``--in-domain`` (the default) each method is also trained on every target plant, and each
``--centralised`` method (:data:`CENTRALISED`, the controller's view, retrained for every plant) on
every plant. Each run's validated model (its sample-efficiency curve's pick on validation episodes,
seeds 20000+; nothing is chosen on the episodes reported) is evaluated on ``--episodes`` *fresh* episodes (δ = 120 s, T = 600, seeds
30000+, used for nothing else) of the plant it was trained on and, for the shared methods trained on a
source plant, of every target plant. The controllers (:data:`CONTROLLERS`) are evaluated on the same
episodes of every plant, ``planner_agents`` on the first ``--planner-episodes`` of them (its decision
takes about 10 ms at n = 128: ``benchmarks/scaling.py``). Each policy's decision time per plant step
(all agents at once for the container agents, one torch thread, ``--timing-steps`` steps from the first
fresh episode on; the first seed's model) is measured once per model (``--out``/decision_time.json). The
table (``--out``/table.md, table.json): per plant and policy, the mean return per container (mean over
seeds [min, max]), the share of overflowing episodes and the median decision time, of every method whose
evaluations ``--out`` holds (a call for one method keeps the others' cells).

**Plan, execute, report.** The trainings and the source-plant evaluations are compare plans
(:func:`~containergym_marl.orchestration.plan.training_plan`: run names, budgets, finished runs and
unchanged evaluations reused), the controllers' evaluations too; a zero-shot evaluation is the same
evaluation task (:func:`~containergym_marl.orchestration.tasks.evaluate_policy`) on a target plant,
kept under ``--out``/zero_shot/<method>_from_<source>/<target>/ with the model's SHA-256 and evaluated
again when the model changes. They run on ``--workers`` processes without Ray; rerun the same command to
continue after an interruption. Writes only ``--out`` (results/transfer) and the run directories
(``--runs``, git-ignored).

**Cost.** Zero-shot alone (``--no-in-domain --centralised``, nothing after it): 20 runs of the
paper's 5M samples (``fast_shared_ppo`` about 5 minutes of one core each, ``dagger_agents`` about 5),
then per model 6 targets x 200 episodes of a learned policy (seconds to a minute each), and the
planner: 30 episodes of 600 steps on each plant; about 4 core-hours. Training the two methods on the 6
targets adds 60 runs, ``fast_ppo`` on the 8 plants 40 (5M samples each): about 8 core-hours more.
"""

from __future__ import annotations

import argparse
import json
import os
from concurrent.futures import as_completed
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from containergym_marl.evaluation.table import evaluation_key
from containergym_marl.files import atomic_write_text
from containergym_marl.orchestration.compare_args import CompareArgs
from containergym_marl.orchestration.stopping import exit_on_sigterm, worker_pool

#: The shared policies that transfer: the native shared PPO and the imitation of the planner.
METHODS = ("fast_shared_ppo", "dagger_agents")
#: The paper's contended plants they are trained on.
SOURCES = ("n11_m2_dt120", "n16_m2_dt120")
#: The larger plants (configs/scaled.py): PUs in proportion, then scarce.
TARGETS = ("n32_m4_dt120", "n64_m8_dt120", "n128_m16_dt120", "n32_m3_dt120", "n64_m6_dt120", "n128_m12_dt120")
CONTROLLERS = ("rule_based", "rule_based_agents")
#: The controller's view, retrained for every plant: what the shared policies are compared with.
CENTRALISED = ("fast_ppo",)
PLANNER = "planner_agents"
#: Training cost is counted to this share of the rule's validation return (issue 40, item 4).
RULE, RULE_SHARE = "rule_based_agents", 0.9
SEEDS = (101, 102, 103, 104, 105)
OBSERVATION = "portable"


@dataclass
class Args:
    methods: list[str] = field(default_factory=lambda: list(METHODS))
    sources: list[str] = field(default_factory=lambda: list(SOURCES))
    targets: list[str] = field(default_factory=lambda: list(TARGETS))
    seeds: list[int] = field(default_factory=lambda: list(SEEDS))
    timesteps: int | None = None  # None: the paper's budget of each source plant
    episodes: int = 200  # fresh episodes (seeds 30000 on)
    planner_episodes: int = 30  # the first fresh episodes, for planner_agents
    workers: int = os.cpu_count() or 1
    out: str = "results/transfer"
    runs: str = "runs/transfer"
    n_envs: int | None = None
    hyperparams: dict = field(default_factory=dict)  # further settings of every method (smoke: tiny)
    in_domain: bool = True  # the methods trained on every target plant too
    centralised: list[str] = field(default_factory=lambda: list(CENTRALISED))  # trained on every plant
    timing_steps: int = 300  # plant steps of each policy's decision-time measurement
    figure: str | None = None  # the figure of the training cost against n; None: --out/cost_to_rule.png
    report: bool = False
    smoke: bool = False

    def for_smoke(self) -> "Args":
        return replace(self, methods=["fast_shared_ppo"], sources=["n5_m2_dt120"], targets=["n11_m2_dt120",
                       "n32_m4_dt120"], seeds=[SEEDS[0]], timesteps=2_000, episodes=2, planner_episodes=1, workers=1,
                       n_envs=2, hyperparams={"n_steps": 16, "minibatch_size": 64}, timing_steps=5,
                       out=self.out if self.out != Args.out else "runs/transfer_smoke/results",
                       runs=self.runs if self.runs != Args.runs else "runs/transfer_smoke/runs")

    def validate(self) -> None:
        """Refuse bad values before anything runs or is written (a ValueError naming the field)."""
        for name in ("methods", "sources", "targets", "seeds"):
            items = getattr(self, name)
            if not items or len(set(items)) != len(items):
                raise ValueError(f"{name}: expected distinct entries, got {items}")
        from containergym_marl.methods import METHODS as REGISTERED

        choices = [m for m, d in REGISTERED.items() if d.trained_here and d.view == "centralised"]
        if not set(self.centralised) <= set(choices) or len(set(self.centralised)) != len(self.centralised):
            raise ValueError(f"centralised: expected distinct centralised methods that compare trains, got "
                             f"{self.centralised}; choose from {choices}")
        if self.timing_steps < 1:
            raise ValueError(f"timing_steps: expected at least 1, got {self.timing_steps}")
        if not set(self.methods) <= set(METHODS):
            raise ValueError(f"methods: {sorted(set(self.methods) - set(METHODS))} are not shared container-agent "
                             f"policies with the portable observation; choose from {METHODS}")
        if set(self.sources) & set(self.targets):
            raise ValueError(f"targets: {sorted(set(self.sources) & set(self.targets))} are source plants too")
        if "observation" in self.hyperparams:
            raise ValueError(f"hyperparams: the observation is {OBSERVATION!r}, the one that fits every plant")
        if self.episodes < 1 or not 1 <= self.planner_episodes <= self.episodes or self.workers < 1:
            raise ValueError(f"episodes, planner_episodes, workers: expected 1 <= planner_episodes <= episodes and "
                             f"workers >= 1, got {self.episodes}, {self.planner_episodes}, {self.workers}")
        for args in self.plans().values():
            args.validate()  # unknown methods or plants, budgets
        from containergym_marl.algorithms import get_algorithm

        plans = self.plans()
        for method in self.methods:
            get_algorithm(method).trainer().settings(plans[method].hyperparams)
        for method in self.centralised:
            get_algorithm(method).trainer().settings(plans["centralised"].hyperparams)

    def plans(self) -> dict[str, CompareArgs]:
        """The compare plans by folder: each method's trainings (their curves, and their evaluations where
        trained), the centralised methods', the controllers' evaluations on every plant, the planner's,
        and the rule's on the validation episodes of the curves."""
        plants = [*self.sources, *self.targets]
        common = dict(protocol="fresh", figures="none")
        plans = {method: CompareArgs(methods=[method], configs=plants if self.in_domain else list(self.sources),
                                     seeds=list(self.seeds),
                                     timesteps=self.timesteps, episodes=self.episodes, n_envs=self.n_envs,
                                     hyperparams={**self.hyperparams, "observation": OBSERVATION}, curves=True,
                                     out=str(Path(self.out) / method), runs=str(Path(self.runs) / method), **common)
                 for method in self.methods}
        if self.centralised:
            plans["centralised"] = CompareArgs(methods=list(self.centralised), configs=plants, seeds=list(self.seeds),
                                               timesteps=self.timesteps, episodes=self.episodes, n_envs=self.n_envs,
                                               hyperparams=dict(self.hyperparams), curves=True,
                                               out=str(Path(self.out) / "centralised"),
                                               runs=str(Path(self.runs) / "centralised"), **common)
        plans["controllers"] = CompareArgs(methods=list(CONTROLLERS), configs=plants, episodes=self.episodes,
                                           out=str(Path(self.out) / "controllers"),
                                           runs=str(Path(self.runs) / "controllers"), **common)
        plans["planner"] = CompareArgs(methods=[PLANNER], configs=plants, episodes=self.planner_episodes,
                                       out=str(Path(self.out) / "planner"), runs=str(Path(self.runs) / "planner"),
                                       **common)
        # the rule on the validation episodes the runs' curves are measured on: the training cost's yardstick
        plans["rules_validation"] = CompareArgs(methods=[RULE], configs=plants, protocol="validation", figures="none",
                                                out=str(Path(self.out) / "rules_validation"),
                                                runs=str(Path(self.runs) / "rules_validation"))
        return plans


def zero_shot_path(args: Args, method: str, source: str, target: str, seed: int) -> Path:
    return Path(args.out) / "zero_shot" / f"{method}_from_{source}" / target / f"{evaluation_key(method, seed)}.json"


def _evaluate(job: tuple) -> tuple:
    """An evaluation task in a worker process: (job, the evaluation, its model's SHA-256)."""
    from containergym_marl.orchestration.plan import run_files
    from containergym_marl.orchestration.tasks import RunSpec, evaluate_policy

    _, spec, source = job
    if isinstance(source, (RunSpec, str)):  # trained by this call, or a finished run: its files now
        source = run_files(source.run_dir if isinstance(source, RunSpec) else source)
    return (job, *evaluate_policy(spec, source))


def zero_shot_jobs(args: Args, plans: dict) -> list[tuple]:
    """(("zero_shot", method, source, target), spec, run dir) of every finished run and target whose
    evaluation is missing or was made of another model."""
    from containergym_marl.orchestration.plan import model_sha256, run_files
    from containergym_marl.orchestration.tasks import EvalSpec
    from containergym_marl.rundir import run_name

    protocol = plans["controllers"].eval_protocol()
    jobs = []
    for method in args.methods:
        runs = Path(plans[method].runs).resolve()
        for source in args.sources:
            for seed in args.seeds:
                run = runs / run_name(method, source, seed)
                if not (run / "run.json").is_file():
                    continue
                sha = model_sha256(run_files(run))
                for target in args.targets:
                    path = zero_shot_path(args, method, source, target, seed)
                    if path.is_file() and json.loads(path.read_text()).get("source", {}).get("model_sha256") == sha:
                        continue
                    spec = EvalSpec(key=evaluation_key(method, seed), method=method, config=target, protocol=protocol,
                                    seed=seed)
                    jobs.append((("zero_shot", method, source, target), spec, str(run)))
    return jobs


def execute(args: Args) -> list[str]:
    """Train what the plans need, then every evaluation still missing (source plants, zero-shot targets,
    controllers), ``args.workers`` at a time; returns what failed (a rerun retries it)."""
    from containergym_marl.orchestration.compare import save_evaluation
    from containergym_marl.orchestration.plan import training_plan
    from containergym_marl.orchestration.tasks import RunSpec, train_run
    from containergym_marl.rundir import run_name

    compare_args = args.plans()
    plans = {name: training_plan(c, Path(c.out).resolve(), Path(c.runs).resolve()) for name, c in compare_args.items()}
    to_train = [spec for plan in plans.values() for spec in plan.to_train]
    print(f"transfer: {len(to_train)} run(s) to train", flush=True)
    failed: list[str] = []
    with worker_pool(args.workers) as pool:
        trainings = {pool.submit(train_run, spec): spec for spec in to_train}
        for future in as_completed(trainings):
            spec = trainings[future]
            try:
                print(f"trained {spec.name}: {future.result()['wall_s']:.0f} s", flush=True)
            except Exception as exc:  # noqa: BLE001 - one failed run must not stop the others
                failed.append(f"training {spec.name}: {type(exc).__name__}: {exc}")
        untrained = {trainings[f].run_dir for f in trainings if f.exception() is not None}
        jobs = [(("plan", name), spec, source) for name, plan in plans.items() for spec, source in plan.to_evaluate
                if not (isinstance(source, RunSpec) and source.run_dir in untrained)]
        jobs += zero_shot_jobs(args, compare_args)
        print(f"transfer: {len(jobs)} evaluation(s) to run", flush=True)
        for future in as_completed([pool.submit(_evaluate, job) for job in jobs]):
            try:
                (where, spec, _), result, model_sha = future.result()
            except Exception as exc:  # noqa: BLE001
                failed.append(f"evaluation: {type(exc).__name__}: {exc}")
                continue
            if where[0] == "plan":
                c = compare_args[where[1]]
                save_evaluation(c, Path(c.out).resolve(), spec, result, model_sha,
                                None if spec.seed is None else c.budget(spec.config))
            else:
                _, method, source, target = where
                data = json.loads(result.to_json())
                data["source"] = {"config": source, "run": run_name(method, source, spec.seed), "model_sha256": model_sha}
                path = zero_shot_path(args, method, source, target, spec.seed)
                path.parent.mkdir(parents=True, exist_ok=True)
                atomic_write_text(path, json.dumps(data, indent=2) + "\n")
            print(f"evaluated {spec.key} on {spec.config} ({where[0]}): {result.returns.mean():.2f}", flush=True)
    for message in failed:
        print(f"FAILED {message}", flush=True)
    return failed


# ---- decision times --------------------------------------------------------------------------------
def _timed(job: tuple) -> tuple:
    """(label/plant, model sha, timing) of a controller (run None) or of a run's evaluated model on a plant."""
    from containergym_marl.core.params import PlantParams
    from containergym_marl.evaluation.decision_time import decision_time
    from containergym_marl.evaluation.run_policies import evaluated_which, policy_from_run
    from containergym_marl.methods import get_method

    key, plant, run, sha, protocol, steps = job
    config = protocol.plant(plant)
    policy = (get_method(key.split("/")[0]).controller(PlantParams.from_config(config)) if run is None
              else policy_from_run(run, evaluated_which(run)))
    return key, sha, decision_time(policy, config, steps, protocol.first_seed)


def timing_jobs(args: Args, plans: dict) -> list[tuple]:
    """One decision-time job per (policy, plant) of the table: each controller and the planner, each
    method's first seed's model where it was trained and zero-shot from each source, each centralised
    method's first seed's; keyed ``<label>/<plant>`` as the table's cells are."""
    from containergym_marl.orchestration.plan import model_sha256, run_files
    from containergym_marl.rundir import run_name

    protocol, seed = plans["controllers"].eval_protocol(), args.seeds[0]
    jobs = []
    for plant in [*args.sources, *args.targets]:
        for name in [*CONTROLLERS, PLANNER]:
            jobs.append((f"{name}/{plant}", plant, None, None, protocol, args.timing_steps))
        runs = [(label, plan.runs, m, plant) for label, plan, m in trained_here(args, plans, plant)]
        runs += [(f"{m} from {source}", plans[m].runs, m, source) for m in args.methods for source in args.sources
                 if plant in args.targets]
        for label, folder, method, trained_on in runs:
            run = Path(folder).resolve() / run_name(method, trained_on, seed)
            if (run / "run.json").is_file():
                jobs.append((f"{label}/{plant}", plant, str(run), model_sha256(run_files(run)), protocol,
                             args.timing_steps))
    return jobs


def decision_times(args: Args, plans: dict) -> dict:
    """Every policy's decision time on every plant, cached in ``--out``/decision_time.json by model and
    number of steps (measured again when either changes)."""
    path = Path(args.out) / "decision_time.json"
    known = json.loads(path.read_text()) if path.is_file() else {}
    jobs = [j for j in timing_jobs(args, plans)
            if j[0] not in known or (known[j[0]]["model_sha256"], known[j[0]]["steps"]) != (j[3], j[5])]
    print(f"transfer: {len(jobs)} decision time(s) to measure", flush=True)
    with worker_pool(args.workers) as pool:
        for key, sha, timing in pool.map(_timed, jobs):
            known[key] = {"model_sha256": sha, **timing}
            atomic_write_text(path, json.dumps(known, indent=1, sort_keys=True) + "\n")
    return known


# ---- training cost ---------------------------------------------------------------------------------
def trained_here(args: Args, plans: dict, plant: str) -> list[tuple[str, CompareArgs, str]]:
    """(label, compare plan, method) of every method trained on ``plant``."""
    found = [(f"{m} (trained here)", plans[m], m) for m in args.methods if plant in plans[m].configs]
    return found + [(f"{m} (trained here)", plans["centralised"], m) for m in args.centralised]


def keep_curves(args: Args, plans: dict) -> int:
    """Copy each finished run's curve, samples and training time to ``--out``/curves/<run>.json, where the
    report reads them (the run folders are not kept); returns how many were copied."""
    from containergym_marl.rundir import read_run_summary, run_name

    copied = 0
    for plant in [*args.sources, *args.targets]:
        for _, plan, method in trained_here(args, plans, plant):
            for seed in args.seeds:
                run = Path(plan.runs).resolve() / run_name(method, plant, seed)
                summary = read_run_summary(run) if run.is_dir() else None
                if summary is None or not (run / "curve.json").is_file():
                    continue
                kept = {"run": run.name, "timesteps": summary["timesteps"], "wall_time_s": summary["wall_time_s"],
                        "curve": json.loads((run / "curve.json").read_text())}
                atomic_write_text(Path(args.out) / "curves" / f"{run.name}.json", json.dumps(kept, indent=1) + "\n")
                copied += 1
    return copied


def cost_to_rule(args: Args, plans: dict, plant: str, method: str) -> dict | None:
    """What training ``method`` on ``plant`` cost until its validation curve first reached
    :data:`RULE_SHARE` of the rule's validation return: per seed, the samples and the CPU seconds (the
    run's training time in that proportion: one core a run), None for a seed that never did."""
    from containergym_marl.rundir import run_name

    rule = _evaluation(Path(plans["rules_validation"].out) / "evaluations" / plant / f"{RULE}.json")
    if rule is None:
        return None
    target = RULE_SHARE * rule["summary"]["return_mean"]
    seeds = {}
    for seed in args.seeds:
        kept = _evaluation(Path(args.out) / "curves" / f"{run_name(method, plant, seed)}.json")
        if kept is None:
            continue
        reached = [p["samples"] for p in sorted(kept["curve"]["points"], key=lambda p: p["samples"])
                   if p["return_mean"] >= target]
        samples = reached[0] if reached else None
        seeds[str(seed)] = None if samples is None else {
            "samples": samples, "cpu_s": kept["wall_time_s"] * samples / kept["timesteps"]}
    if not seeds:
        return None
    hit = [v for v in seeds.values() if v is not None]
    return {"share": RULE_SHARE, "rule_validation_return": rule["summary"]["return_mean"], "seeds": seeds,
            "reached": len(hit), "runs": len(seeds),
            "samples_median": float(np.median([v["samples"] for v in hit])) if hit else None,
            "cpu_s_median": float(np.median([v["cpu_s"] for v in hit])) if hit else None}


def cost_lines(report: dict) -> dict[tuple[str, str], list[tuple[int, float]]]:
    """(method, share of PUs) -> the (n, median training samples to the rule's share) of its plants, by n:
    m = n/8 as the larger plants' proportional ones, fewer as the scarce ones, more as n11_m2, so that the
    two plants of each size are not joined."""
    from containergym_marl import load_config

    def pus(plant: str) -> str:
        config = load_config(plant)
        n, m = config.n_containers, config.num_processing_units
        return "m = n/8" if 8 * m == n else ("m < n/8" if 8 * m < n else "m > n/8")

    lines: dict[tuple[str, str], list[tuple[int, float]]] = {}
    for e in report["entries"]:
        share = pus(e["plant"])
        for label, cell in e["cells"].items():
            cost = cell.get("cost_to_rule")
            if cost and cost["samples_median"] is not None:
                lines.setdefault((label.replace(" (trained here)", ""), share), []).append((e["n"], cost["samples_median"]))
    return {key: sorted(points) for key, points in lines.items()}


def draw_costs(report: dict, path: Path) -> Path | None:
    """Training samples to the rule's share against the plant's size (log scales): a colour per method, a
    line style per share of PUs (:func:`cost_lines`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lines = cost_lines(report)
    if not lines:
        return None
    colours = {method: f"C{i}" for i, method in enumerate(dict.fromkeys(m for m, _ in lines))}
    styles = {"m = n/8": "-", "m < n/8": "--", "m > n/8": ":"}
    fig, ax = plt.subplots(figsize=(6.5, 4))
    for (method, share), points in lines.items():
        ax.plot([n for n, _ in points], [s for _, s in points], marker="o", color=colours[method],
                linestyle=styles[share], label=f"{method}, {share}")
    ax.set(xscale="log", yscale="log", xlabel="containers n", ylabel="training samples (median over seeds)",
           title=f"Training to {RULE_SHARE:.0%} of {RULE}'s validation return")
    ax.legend(fontsize="small")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


# ---- the report ------------------------------------------------------------------------------------
def _evaluation(path: Path) -> dict | None:
    return json.loads(path.read_text()) if path.is_file() else None


def _cell(evaluations: list[dict], n: int) -> dict:
    per_seed = [float(np.mean([e["cumulative_reward"] for e in ev["episodes"]])) / n for ev in evaluations]
    episodes = [e for ev in evaluations for e in ev["episodes"]]
    return {"seeds": len(evaluations), "return_per_container": float(np.mean(per_seed)),
            "min": min(per_seed), "max": max(per_seed), "episodes": len(episodes),
            "overflow_share": sum(bool(e["overflow"]) for e in episodes) / len(episodes)}


def table_args(args: Args) -> Args:
    """The settings the table is read with: every method of the study (shared, trained on every plant,
    and centralised), whatever this call trained, so that a call for one method keeps the others' cells;
    a cell appears where its files are in ``--out``."""
    return replace(args, methods=list(METHODS), in_domain=True,
                   centralised=list(dict.fromkeys([*CENTRALISED, *args.centralised])))


def summarise(args: Args, timing: dict | None = None) -> dict:
    """Per plant: each policy's mean return per container (over seeds), overflowing share and median
    decision time per plant step (``timing``: :func:`decision_times`; None where not measured), for every
    method whose evaluations are in ``--out`` (:func:`table_args`)."""
    from containergym_marl.config import load_config

    args = table_args(args)
    plans, timing = args.plans(), timing or {}
    entries = []
    for plant in [*args.sources, *args.targets]:
        n = load_config(plant).n_containers
        cells: dict[str, dict] = {}
        for name, folder in ([(m, "controllers") for m in CONTROLLERS] + [(PLANNER, "planner")]):
            ev = _evaluation(Path(plans[folder].out) / "evaluations" / plant / f"{evaluation_key(name, None)}.json")
            if ev is not None:
                cells[name] = _cell([ev], n)
        trained = trained_here(args, plans, plant)
        groups = [(label, [Path(plan.out) / "evaluations" / plant / f"{evaluation_key(method, s)}.json"
                           for s in args.seeds]) for label, plan, method in trained]
        groups += [(f"{m} from {source}", [zero_shot_path(args, m, source, plant, s) for s in args.seeds])
                   for m in args.methods for source in args.sources if plant in args.targets]
        for label, paths in groups:
            found = [ev for p in paths if (ev := _evaluation(p)) is not None]
            if found:
                cells[label] = _cell(found, n)
        for label, cell in cells.items():
            measured = timing.get(f"{label}/{plant}")
            cell["decision_ms_median"] = None if measured is None else measured["ms_median"]
        for label, _, method in trained:
            if label in cells:
                cells[label]["cost_to_rule"] = cost_to_rule(args, plans, plant, method)
        entries.append({"plant": plant, "n": n, "cells": cells})
    labels = {label for e in entries for label in e["cells"]}
    shown = {"methods": [m for m in METHODS if any(label.startswith(f"{m} ") for label in labels)],
             "in_domain": [m for m in METHODS if any(f"{m} (trained here)" in e["cells"] for e in entries
                                                      if e["plant"] in args.targets)],
             "centralised": [m for m in args.centralised if f"{m} (trained here)" in labels]}
    return {"question": "zero-shot transfer of shared container-agent policies to larger plants (issue 40)",
            "observation": OBSERVATION, "protocol": "fresh", "args": asdict(args), "shown": shown, "entries": entries}


def _ms(value: float | None) -> str:
    return "–" if value is None else f"{value:.3g}"


def markdown(report: dict) -> str:
    args, shown = report["args"], report["shown"]
    lines = ["# Shared container-agent policies on plants they were not trained on", "",
             f"Shared container-agent methods ({', '.join(f'`{m}`' for m in shown['methods'])}) trained with "
             f"`--hp observation={OBSERVATION}` on "
             f"{', '.join(args['sources'])}"
             + (f" ({', '.join(f'`{m}`' for m in shown['in_domain'])} also on each larger plant: trained here)"
                if shown["in_domain"] else "")
             + (f"; {', '.join(f'`{m}`' for m in shown['centralised'])} (the controller's view, its own observation) "
                "on every plant" if shown["centralised"] else "")
             + f"; seeds {', '.join(map(str, args['seeds']))}, "
             + (f"{args['timesteps']:,} samples per run" if args["timesteps"] else "the paper's budget")
             + f". Each run's validated model (its curve's pick on validation episodes) on {args['episodes']} fresh episodes (δ = 120 s, T = 600, seeds 30000+) "
             f"of its plant and, trained on a source plant, of every larger one (zero-shot: from …); the rules "
             f"on the same episodes, `{PLANNER}` on the first {args['planner_episodes']}. "
             "Return per container: the mean return / n, mean over seeds [min, max]; overflow: the share of all "
             "episodes that overflowed; decision: the median wall time of one plant step's decision (all agents "
             f"at once, one torch thread, {args['timing_steps']} steps, the first seed's model), in ms.", "",
             "| plant | n | policy | seeds | return per container [min, max] | overflow | decision (ms) |",
             "|---|---|---|---|---|---|---|"]
    for e in report["entries"]:
        for label, c in e["cells"].items():
            spread = f" [{c['min']:.3f}, {c['max']:.3f}]" if c["seeds"] > 1 else ""
            lines.append(f"| {e['plant']} | {e['n']} | {label} | {c['seeds'] if c['seeds'] > 1 else '–'} | "
                         f"{c['return_per_container']:.3f}{spread} | {c['overflow_share']:.2f} | "
                         f"{_ms(c.get('decision_ms_median'))} |")
    lines += ["", f"## Training cost to {RULE_SHARE:.0%} of `{RULE}`'s validation return", "",
              f"Each run trained on the plant: its sample-efficiency curve (each tenth of the budget and the final "
              f"model on 30 validation episodes, seeds 20000+) against `{RULE}` on the same episodes; the samples "
              f"and CPU seconds (its training time in proportion, one core) until the curve first reaches "
              f"{RULE_SHARE:.0%} of the rule's return, median over the seeds that reach it.", "",
              "| plant | n | method | rule's validation return | seeds reaching it | samples (median) | CPU-s (median) |",
              "|---|---|---|---|---|---|---|"]
    for e in report["entries"]:
        for label, c in e["cells"].items():
            cost = c.get("cost_to_rule")
            if cost:
                samples = "–" if cost["samples_median"] is None else f"{cost['samples_median']:,.0f}"
                cpu = "–" if cost["cpu_s_median"] is None else f"{cost['cpu_s_median']:,.0f}"
                lines.append(f"| {e['plant']} | {e['n']} | {label.replace(' (trained here)', '')} | "
                             f"{cost['rule_validation_return']:.2f} | {cost['reached']} of {cost['runs']} | "
                             f"{samples} | {cpu} |")
    return "\n".join(lines) + "\n"


def main(args: Args) -> dict:
    if args.smoke:
        args = args.for_smoke()
    args.validate()
    failed = [] if args.report else execute(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    timing_path = out / "decision_time.json"
    timing = (json.loads(timing_path.read_text()) if timing_path.is_file() else {}) if args.report \
        else decision_times(args, args.plans())
    if not args.report:
        keep_curves(args, args.plans())
    report = summarise(args, timing)
    atomic_write_text(out / "table.json", json.dumps(report, indent=1) + "\n")
    atomic_write_text(out / "table.md", markdown(report))
    draw_costs(report, Path(args.figure) if args.figure else out / "cost_to_rule.png")
    print(markdown(report))
    if failed:
        raise SystemExit(f"{len(failed)} task(s) failed; rerun the same command to retry them")
    return report


def parse(argv=None) -> Args:
    from containergym_marl import list_configs

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    p.add_argument("--sources", nargs="+", default=list(SOURCES), choices=list_configs())
    p.add_argument("--targets", nargs="+", default=list(TARGETS), choices=list_configs())
    p.add_argument("--seeds", nargs="+", type=int, default=list(SEEDS))
    p.add_argument("--timesteps", type=int, default=None, help="samples per run (default: the paper's budget)")
    p.add_argument("--episodes", type=int, default=Args.episodes, help="fresh episodes (seeds 30000 on)")
    p.add_argument("--planner-episodes", type=int, default=Args.planner_episodes)
    p.add_argument("--no-in-domain", dest="in_domain", action="store_false",
                   help="do not train the methods on the target plants (zero-shot only)")
    p.add_argument("--centralised", nargs="*", default=list(CENTRALISED),
                   help="centralised methods trained on every plant (none: --centralised alone)")
    p.add_argument("--timing-steps", type=int, default=Args.timing_steps, help="plant steps of each decision time")
    p.add_argument("--workers", type=int, default=Args.workers, help="processes, one run or evaluation each")
    p.add_argument("--out", default=Args.out)
    p.add_argument("--runs", default=Args.runs)
    p.add_argument("--figure", default=None, help="where to draw the training cost against n (default: "
                                                  "--out/cost_to_rule.png; docs/scale.md shows "
                                                  "docs/figures/transfer_cost_to_rule.png)")
    p.add_argument("--report", action="store_true", help="only the table, from the files there")
    p.add_argument("--smoke", action="store_true", help="fast_shared_ppo on n5_m2_dt120, one seed, 2000 samples, "
                                                        "targets n11_m2_dt120 and n32_m4_dt120, 2 episodes")
    return Args(**vars(p.parse_args(argv)))


if __name__ == "__main__":
    exit_on_sigterm()  # stopped by SIGTERM, the study's workers stop with it
    main(parse())
