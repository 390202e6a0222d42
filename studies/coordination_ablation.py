"""How much of the imitation's gap to the planner is information, and how much is learning (issue 38, item 2).

    python studies/coordination_ablation.py                  # 4 observations x 3 rows x 5 seeds, paper budget
    python studies/coordination_ablation.py --observations local global --workers 2
    python studies/coordination_ablation.py --report         # the table from the files there, nothing run
    python studies/coordination_ablation.py --smoke          # every observation, one row and seed, tiny budget

**Question.** ``dagger_agents`` (DAgger imitation of ``planner_agents`` by one network shared by the
container agents) reaches 85–93 % of the planner on the contended rows (:data:`ROWS`). Is the rest
missing information (an agent sees only its own container, the PU timers and three shares of the
others) or the learning (the network, the imitation, the planner's own sampling noise, which no
observation predicts)? Students that differ only in what they see, each trained by the same DAgger
at ``dagger_agents``' settings with ``--hp observation=<variant>``
(:data:`~containergym_marl.core.observations.OBSERVATIONS`, documented entry by entry in
:mod:`containergym_marl.core.observations`):

* ``local``: today's observation;
* ``global``: it plus the normalised global state (every container's v / v_max, every PU's timer): an
  oracle, the upper bound of what imitation reaches with this network;
* ``history4``: the last 4 observations stacked (0 before the episode's start): memory;
* ``broadcast``: it plus which containers requested in the last step and which were emptied: one
  public signal the plant could broadcast to every agent.

Reading: the share that ``global`` gains over ``local`` is what information can buy this network at
most; what ``global`` still lacks to 100 % is learning. ``history4`` and ``broadcast`` say how much of
the information gap memory or one broadcast closes while execution stays decentralised.

**Protocol.** Each observation x row x seed (:data:`SEEDS`, 101–105: no published run uses them) is
one run at the paper's budget (5M agent samples at n >= 11) under the row's own training settings
(the δ = 60 s row at δ = 60 s). Each run's best model (the paper's choice) is evaluated on the
*validation* episodes (δ = 120 s, T = 600, seeds 20000–20029; never the test seeds 10000–10014 or the
fresh ones), and ``planner_agents`` on the same episodes. The table (``--out``/table.md, table.json):
per observation and row, the validation mean return as a share of ``planner_agents``' (mean over
seeds, their range, the IQM), the overflowing episodes, the training cost per seed, and the decision
time per plant step (the policy's ``act`` for all agents, one torch thread, one validation episode).

**Plan, execute, report.** The runs and evaluations of each observation are a compare plan
(:func:`~containergym_marl.orchestration.plan.training_plan`: run names, budgets, finished runs and
evaluations of an unchanged model, plant and protocol reused), its runs under ``--runs``/<observation>/,
its evaluation files under ``--out``/<observation>/evaluations/, ``planner_agents``' under
``--out``/reference/. They run here on ``--workers`` processes without Ray
(:func:`~containergym_marl.orchestration.tasks.train_run`: a run's lock, resumed from its newest
checkpoint; :func:`~containergym_marl.orchestration.tasks.evaluate_policy`). Rerun the same command to
continue after an interruption. Writes only ``--out`` (results/coordination_ablation) and the run
directories (``--runs``, git-ignored like every study's runs).

**Cost.** 60 runs of 5M samples. ``dagger_agents`` with the local observation took 236–285 s of one
core per run on these rows (``results/dagger_rows/rows.md``), 148–184 s of it the planner's labelling,
which does not depend on the observation. Timed side by side here (3 iterations, 135k samples at
n = 11, 197k at n = 16, on a loaded machine), the rest costs +1 % with ``global``, +15 % with
``broadcast`` and +30 % (n = 11) / +18 % (n = 16) with ``history4`` (4x the observation in the
network's input and in the data set). So about 4.5 core-hours in all (on a loaded machine twice
that), plus about 5 minutes of evaluations. ``history4``'s data set of 1M samples holds 400 MB
(n = 11) to 480 MB (n = 16), in memory and in the newest checkpoint.
"""

from __future__ import annotations

import argparse
import json
import os
from concurrent.futures import as_completed
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from containergym_marl.core.observations import OBSERVATIONS
from containergym_marl.evaluation.table import evaluation_key
from containergym_marl.files import atomic_write_text
from containergym_marl.orchestration.compare_args import PAPER_ROWS, CompareArgs
from containergym_marl.orchestration.stopping import exit_on_sigterm, worker_pool

#: The students' observations: what each sees besides the default (``portable`` is for transfer between
#: plants, studies/transfer.py, and sees less rather than more).
STUDENT_OBSERVATIONS = ("local", "global", "history4", "broadcast")
#: The rows where the imitation stays furthest below the planner (85–93 %, issue 38): contention, m = 2.
ROWS = ("n11_m2_dt60", "n11_m2_dt120", "n16_m2_dt120")
#: Training seeds of the study; the published runs use 1-15.
SEEDS = (101, 102, 103, 104, 105)
STUDENT, REFERENCE = "dagger_agents", "planner_agents"
REFERENCE_FOLDER = "reference"
#: Plant steps over which a policy's decision is timed (one validation episode).
TIMED_STEPS = 600


@dataclass
class Args:
    observations: list[str] = field(default_factory=lambda: list(STUDENT_OBSERVATIONS))
    rows: list[str] = field(default_factory=lambda: list(ROWS))
    seeds: list[int] = field(default_factory=lambda: list(SEEDS))
    timesteps: int | None = None  # None: the paper's budget of each row
    episodes: int = 30  # validation episodes (seeds 20000 on)
    workers: int = os.cpu_count() or 1
    out: str = "results/coordination_ablation"  # the study's results
    runs: str = "runs/coordination_ablation"  # its run directories (git-ignored)
    n_envs: int | None = None  # None: dagger_agents' default (64 simulations)
    hyperparams: dict = field(default_factory=dict)  # further DAgger settings of every student (smoke: tiny)
    report: bool = False  # only the table, from the files there
    smoke: bool = False

    def for_smoke(self) -> "Args":
        return replace(self, rows=["n5_m2_dt120"], seeds=[SEEDS[0]], timesteps=2_000, episodes=2, workers=1,
                       n_envs=2, hyperparams={"n_steps": 16, "minibatch_size": 64},
                       out=self.out if self.out != Args.out else "runs/coordination_ablation_smoke/results",
                       runs=self.runs if self.runs != Args.runs else "runs/coordination_ablation_smoke/runs")

    def validate(self) -> None:
        """Refuse bad values before anything runs or is written (a ValueError naming the field)."""
        bad = [o for o in self.observations if o not in OBSERVATIONS]
        if bad or not self.observations:
            raise ValueError(f"observations: unknown {bad} or none; choose from {OBSERVATIONS}")
        if "observation" in self.hyperparams:
            raise ValueError("hyperparams: observation is what the study varies (--observations)")
        for name in ("rows", "seeds", "observations"):
            items = getattr(self, name)
            if len(set(items)) != len(items):
                raise ValueError(f"{name}: an entry is given more than once: {items}")
        if self.episodes < 1 or self.workers < 1:
            raise ValueError(f"episodes, workers: expected >= 1, got {self.episodes}, {self.workers}")
        from containergym_marl.algorithms import get_algorithm

        for name, args in self.plans().items():
            args.validate()  # unknown rows, repeated seeds, budgets, episodes
            if name != REFERENCE_FOLDER:  # the students' DAgger settings, as train parses them
                get_algorithm(STUDENT).trainer().settings(args.hyperparams)

    def plans(self) -> dict[str, CompareArgs]:
        """One compare plan per observation (its students) and one for the reference, by folder name."""
        common = dict(configs=list(self.rows), seeds=list(self.seeds), timesteps=self.timesteps,
                      protocol="validation", episodes=self.episodes, n_envs=self.n_envs, figures="none")
        plans = {REFERENCE_FOLDER: CompareArgs(methods=[REFERENCE], out=str(Path(self.out) / REFERENCE_FOLDER),
                                               runs=str(Path(self.runs) / REFERENCE_FOLDER), **common)}
        for observation in self.observations:
            plans[observation] = CompareArgs(methods=[STUDENT], out=str(Path(self.out) / observation),
                                             runs=str(Path(self.runs) / observation),
                                             hyperparams={**self.hyperparams, "observation": observation}, **common)
        return plans


# ---- plan and execution ---------------------------------------------------------------------------
def plan_all(args: Args) -> dict:
    """Each folder's compare plan, from the files alone."""
    from containergym_marl.orchestration.plan import training_plan

    return {name: training_plan(c, Path(c.out).resolve(), Path(c.runs).resolve()) for name, c in args.plans().items()}


def _evaluate(job: tuple) -> tuple:
    """An evaluation task in a worker process: (folder, spec, the evaluation and its model's sha)."""
    from containergym_marl.orchestration.plan import run_files
    from containergym_marl.orchestration.tasks import RunSpec, evaluate_policy

    folder, spec, source = job
    if isinstance(source, RunSpec):  # trained by this call: its files now
        source = run_files(source.run_dir)
    return (folder, spec, *evaluate_policy(spec, source))


def execute(args: Args, plans: dict) -> list[str]:
    """Train what the plans still need, then evaluate what they still need, ``args.workers`` at a
    time; returns what failed (the rest is done and kept: a rerun retries the failed part)."""
    from containergym_marl.orchestration.compare import save_evaluation
    from containergym_marl.orchestration.tasks import RunSpec, train_run

    to_train = [spec for plan in plans.values() for spec in plan.to_train]
    print(f"coordination ablation: {sum(len(p.specs) for p in plans.values())} run(s), {len(to_train)} to train; "
          f"{sum(len(p.to_evaluate) for p in plans.values())} evaluation(s) to run", flush=True)
    failed: list[str] = []
    compare_args = args.plans()
    with worker_pool(args.workers) as pool:
        trainings = {pool.submit(train_run, spec): spec for spec in to_train}
        for future in as_completed(trainings):
            spec = trainings[future]
            where = f"{Path(spec.run_dir).parent.name}/{spec.name}"  # observation/run
            try:
                result = future.result()
                print(f"trained {where} ({result['state']}): {result['wall_s']:.0f} s", flush=True)
            except Exception as exc:  # noqa: BLE001 - one failed run must not stop the others
                failed.append(f"training {where}: {type(exc).__name__}: {exc}")
                print(f"FAILED {failed[-1]}", flush=True)
        untrained = {trainings[f].run_dir for f in trainings if f.exception() is not None}
        jobs = [(name, spec, source) for name, plan in plans.items() for spec, source in plan.to_evaluate
                if not (isinstance(source, RunSpec) and source.run_dir in untrained)]
        evaluations = {pool.submit(_evaluate, job): job for job in jobs}
        for future in as_completed(evaluations):
            folder, spec, _ = evaluations[future]
            try:
                _, _, result, model_sha = future.result()
            except Exception as exc:  # noqa: BLE001
                failed.append(f"evaluation {folder}/{spec.config}/{spec.key}: {type(exc).__name__}: {exc}")
                print(f"FAILED {failed[-1]}", flush=True)
                continue
            c = compare_args[folder]
            budget = None if spec.seed is None else c.budget(spec.config)
            save_evaluation(c, Path(c.out).resolve(), spec, result, model_sha, budget)
            print(f"evaluated {folder}/{spec.config}/{spec.key}: {result.returns.mean():.2f}", flush=True)
    return failed


# ---- the report ------------------------------------------------------------------------------------
def decision_time(policy, row: str) -> dict:
    """Wall time of ``policy.act`` per plant step (all agents at once, one torch thread) over one
    validation episode of ``row`` (continued into the next where it ends early): median, mean, p99."""
    from containergym_marl.evaluation.decision_time import decision_time as timed
    from containergym_marl.evaluation.protocol import VALIDATION

    return timed(policy, VALIDATION.plant(row), TIMED_STEPS, VALIDATION.first_seed)


def _timed(job: tuple) -> tuple:
    """(key, model sha, timing) of the reference on a row, or of a run's best model."""
    from containergym_marl.config import load_config
    from containergym_marl.core.params import PlantParams
    from containergym_marl.evaluation.run_policies import policy_from_run
    from containergym_marl.methods import get_method

    key, row, run, sha = job
    policy = (get_method(REFERENCE).controller(PlantParams.from_config(load_config(row))) if run is None
              else policy_from_run(run, "best"))
    return key, sha, decision_time(policy, row)


def decision_times(args: Args, plans: dict) -> dict:
    """The decision time of ``planner_agents`` and of each observation's first seed's model on every
    row, cached in ``--out``/decision_time.json by model (measured again when the model changes)."""
    from containergym_marl.rundir import run_name

    path = Path(args.out) / "decision_time.json"
    known = json.loads(path.read_text()) if path.is_file() else {}
    jobs = []
    for name, plan in plans.items():
        for row in args.rows:
            if name == REFERENCE_FOLDER:
                jobs.append((f"{REFERENCE}/{row}", row, None, None))
                continue
            evaluation = plan.evaluations.get((row, evaluation_key(STUDENT, args.seeds[0])))
            if evaluation is not None:
                run = Path(args.plans()[name].runs).resolve() / run_name(STUDENT, row, args.seeds[0])
                jobs.append((f"{name}/{row}", row, str(run), evaluation["compare"]["model_sha256"]))
    jobs = [j for j in jobs if j[0] not in known or known[j[0]]["model_sha256"] != j[3]]
    with worker_pool(args.workers) as pool:
        for key, sha, timing in pool.map(_timed, jobs):
            known[key] = {"model_sha256": sha, **timing}
            atomic_write_text(path, json.dumps(known, indent=1, sort_keys=True) + "\n")
    return known


def summarise(args: Args, plans: dict, timing: dict) -> dict:
    """Per observation and row: each seed's validation return and its share of planner_agents' on
    the same episodes, the shares' mean, range and IQM, overflowing episodes, cost and decision time."""
    from containergym_marl.evaluation.stats import iqm
    from containergym_marl.rundir import read_run_summary, run_name

    reference = plans[REFERENCE_FOLDER].evaluations
    entries, references = [], []
    for row in args.rows:
        ref = reference.get((row, evaluation_key(REFERENCE, None)))
        if ref is None:
            continue
        ref_seeds = [e["seed"] for e in ref["episodes"]]
        ref_return = float(np.mean([e["cumulative_reward"] for e in ref["episodes"]]))
        references.append({"row": row, "return": ref_return, "episodes": len(ref_seeds),
                           "overflowing_episodes": sum(bool(e["overflow"]) for e in ref["episodes"]),
                           "decision_time": timing.get(f"{REFERENCE}/{row}")})
        for observation in args.observations:
            runs = []
            for seed in args.seeds:
                ev = plans[observation].evaluations.get((row, evaluation_key(STUDENT, seed)))
                if ev is None:
                    continue
                if [e["seed"] for e in ev["episodes"]] != ref_seeds:
                    raise ValueError(f"{observation}/{row}/s{seed}: evaluated on other episodes than {REFERENCE}")
                returns = [e["cumulative_reward"] for e in ev["episodes"]]
                run = Path(args.plans()[observation].runs).resolve() / run_name(STUDENT, row, seed)
                summary = read_run_summary(run) or {}
                runs.append({"seed": seed, "return": float(np.mean(returns)),
                             "share": float(np.mean(returns)) / ref_return,
                             "overflowing_episodes": sum(bool(e["overflow"]) for e in ev["episodes"]),
                             "episodes": len(returns), "samples": summary.get("timesteps"),
                             "wall_s": summary.get("wall_time_s"),
                             "label_cpu_s": (summary.get("imitation") or {}).get("label_cpu_s")})
            if not runs:
                continue
            shares = [r["share"] for r in runs]
            entries.append({"observation": observation, "row": row, "seeds": len(runs), "runs": runs,
                            "return_mean": float(np.mean([r["return"] for r in runs])),
                            "share_mean": float(np.mean(shares)), "share_min": min(shares),
                            "share_max": max(shares), "share_iqm": iqm(shares),
                            "overflowing_episodes": sum(r["overflowing_episodes"] for r in runs),
                            "episodes": sum(r["episodes"] for r in runs),
                            "decision_time": timing.get(f"{observation}/{row}")})
    return {"question": "the imitation's gap to planner_agents: information or learning (issue 38, item 2)",
            "student": STUDENT, "reference": REFERENCE, "protocol": "validation", "args": asdict(args),
            "references": references, "entries": entries}


def _ms(timing: dict | None) -> str:
    return f"{timing['ms_median']:.3f}" if timing else "–"


def markdown(report: dict) -> str:
    args = report["args"]
    lines = ["# What the imitation of the planner lacks: information or learning", "",
             f"`{STUDENT}` students that differ only in what each container agent sees (`--hp observation=...`, "
             f"`containergym_marl.core.observations`), trained by the same DAgger, seeds "
             f"{', '.join(map(str, args['seeds']))}, "
             + (f"{args['timesteps']:,} samples per run" if args["timesteps"] else "the paper's budget")
             + f"; each run's best model on {args['episodes']} validation episodes (δ = 120 s, T = 600, seeds "
             f"20000+), beside `{REFERENCE}` on the same episodes. Share: a seed's mean return / "
             f"`{REFERENCE}`'s; mean over seeds [min, max] and IQM. Overflows: overflowing episodes over all "
             f"seeds' episodes. Decision: median wall ms of the policy's act per plant step (all agents, one "
             f"thread). Train: mean wall s per run, of which the planner's labelling CPU s.", "",
             f"| row | `{REFERENCE}` return | overflows | decision ms |", "|---|---|---|---|"]
    for ref in report["references"]:
        lines.append(f"| {ref['row']} | {ref['return']:.2f} | {ref['overflowing_episodes']}/{ref['episodes']} | "
                     f"{_ms(ref['decision_time'])} |")
    lines += ["", "| observation | row | seeds | return | share [min, max] | IQM share | overflows | decision ms | "
              "train s (labelling) |", "|---|---|---|---|---|---|---|---|---|"]
    for e in report["entries"]:
        walls = [r["wall_s"] for r in e["runs"] if r["wall_s"] is not None]
        labels = [r["label_cpu_s"] for r in e["runs"] if r["label_cpu_s"] is not None]
        cost = f"{np.mean(walls):.0f} ({np.mean(labels):.0f})" if walls and labels else "–"
        lines.append(f"| {e['observation']} | {e['row']} | {e['seeds']} | {e['return_mean']:.2f} | "
                     f"{100 * e['share_mean']:.1f} % [{100 * e['share_min']:.1f}, {100 * e['share_max']:.1f}] | "
                     f"{100 * e['share_iqm']:.1f} % | {e['overflowing_episodes']}/{e['episodes']} | "
                     f"{_ms(e['decision_time'])} | {cost} |")
    return "\n".join(lines) + "\n"


def main(args: Args) -> dict:
    if args.smoke:
        args = args.for_smoke()
    args.validate()
    plans = plan_all(args)
    failed = [] if args.report else execute(args, plans)
    if not args.report:
        plans = plan_all(args)  # every evaluation now on file
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    report = summarise(args, plans, decision_times(args, plans))
    atomic_write_text(out / "table.json", json.dumps(report, indent=1) + "\n")
    atomic_write_text(out / "table.md", markdown(report))
    print(markdown(report))
    if failed:  # the table holds what is done; the rest is retried by the same command
        raise SystemExit(f"{len(failed)} task(s) failed: " + "; ".join(failed))
    return report


def parse(argv=None) -> Args:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--observations", nargs="+", default=list(STUDENT_OBSERVATIONS), choices=OBSERVATIONS)
    p.add_argument("--rows", nargs="+", default=list(ROWS), choices=PAPER_ROWS)
    p.add_argument("--seeds", nargs="+", type=int, default=list(SEEDS))
    p.add_argument("--timesteps", type=int, default=None, help="samples per run (default: the paper's budget)")
    p.add_argument("--episodes", type=int, default=Args.episodes, help="validation episodes (seeds 20000 on)")
    p.add_argument("--workers", type=int, default=Args.workers, help="processes, one run or evaluation each")
    p.add_argument("--out", default=Args.out)
    p.add_argument("--runs", default=Args.runs)
    p.add_argument("--report", action="store_true", help="only the table, from the runs and evaluations there")
    p.add_argument("--smoke", action="store_true",
                   help="every observation on n5_m2_dt120, one seed, 2000 samples (2 simulations), 2 episodes")
    return Args(**vars(p.parse_args(argv)))


if __name__ == "__main__":
    exit_on_sigterm()  # stopped by SIGTERM, the study's workers stop with it
    main(parse())
