"""The plan of a training comparison, as data and from the files alone (no Ray): which runs to train
or reuse, which evaluations to run or reuse, and what each evaluation depends on (its fingerprint).

An evaluation is reused when the model (sha256), the plant and the protocol it was made with are
unchanged; it lives at ``<out>/evaluations/<config>/<key>.json`` (:func:`evaluation_path`).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

from containergym_marl.evaluation import table as tables
from containergym_marl.evaluation.run_policies import evaluated_files, evaluated_model
from containergym_marl.manifest import sha256_bytes
from containergym_marl.methods import METHODS, Method
from containergym_marl.orchestration.compare_args import CompareArgs
from containergym_marl.orchestration.tasks import EvalSpec, RunSpec, check_budget
from containergym_marl.rundir import config_stem, latest_checkpoint, run_name


def evaluation_path(out: Path, config: str, key: str) -> Path:
    """Where a comparison writes an evaluation: ``<out>/evaluations/<config>/<key>.json``."""
    return out / "evaluations" / config_stem(config) / f"{key}.json"


def run_specs(args: CompareArgs, runs: Path) -> list[RunSpec]:
    """The training runs of the comparison, longest first (better packing on the cluster)."""

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
                specs.append(RunSpec(run, name, method.algo, config, seed, args.budget(config),
                                     str(runs / run), train, curve=args.curves))
    return sorted(specs, key=lambda s: -s.timesteps)



def evaluation_fingerprint(args: CompareArgs, config: str, method: Method, run: str | None, model_sha: str | None,
                 timesteps: int | None = None) -> dict:
    """What an evaluation depends on besides the code: stored with it, compared to reuse it.
    ``timesteps``: the run's budget (default: this comparison's budget of ``config``)."""

    plant = args.eval_protocol().plant(config)
    if method.learned and timesteps is None:
        timesteps = args.budget(config)
    return {"run": run, "timesteps": timesteps if method.learned else None,
            "model_sha256": model_sha, "plant_sha256": sha256_bytes(plant.to_toml().encode()),
            "arbitration": method.arbitration}


def cached_evaluation(path: Path, fingerprint: dict, protocol: dict) -> dict | None:
    """The evaluation saved at ``path`` when it was made of the same inputs (``fingerprint``) under the
    same ``protocol``; None when there is none, it is unreadable, or it differs (evaluated again)."""
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
    except ValueError:
        return None
    return data if data.get("compare") == fingerprint and data.get("protocol") == protocol else None



@dataclass
class Shipped:
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


@dataclass
class Plan:
    """What a compare call has to do, found from the files alone (no Ray)."""

    specs: list  # every training run (RunSpec)
    finished: set[str]  # runs finished with the same budget: reused
    to_train: list  # RunSpecs to start or resume
    evaluations: dict[tuple[str, str], dict]  # (config, file stem) -> reused evaluation JSON
    to_evaluate: list  # (EvalSpec, source): source a RunSpec to wait for, a finished run's files, or None
    seeds: dict[tuple[str, str], list[int]] = field(default_factory=dict)  # (config, learned method) -> its seeds
    budgets: dict[str, int] = field(default_factory=dict)  # run name -> its budget in samples
    shipped: "Shipped | None" = None  # what the shipped folder offers (shipped policies only)


def eval_spec(args: CompareArgs, config: str, name: str, seed: int | None):
    """The evaluation task of method ``name`` (seed ``seed`` of a learned one) on ``config``."""
    method = METHODS[name]
    return EvalSpec(tables.evaluation_key(name, seed), name, config, args.eval_protocol(), seed=seed,
                    arbitration=method.arbitration)


def run_files(run_dir: str | Path) -> dict[str, dict[str, bytes]]:
    """A finished run's files that its evaluation reads, by name (shipped to the evaluation task)."""
    run = Path(run_dir)
    return {"files": {f: (run / f).read_bytes() for f in evaluated_files(run)}}


def model_sha256(source: dict[str, dict[str, bytes]]) -> str:
    """The SHA-256 of the model file that an evaluation of ``source`` (:func:`run_files`) loads."""
    return sha256_bytes(evaluated_model(source["files"]))


def training_plan(args: CompareArgs, out: Path, runs: Path) -> Plan:
    """What the comparison ``args`` has to train and evaluate, from the files in ``runs`` and ``out``:
    finished runs of the same budget are reused, evaluations whose inputs are unchanged too; a finished
    run with another budget is an error (:func:`~containergym_marl.orchestration.tasks.check_budget`)."""
    protocol = asdict(args.eval_protocol())
    specs = run_specs(args, runs)
    finished = {s.name for s in specs if check_budget(s)}  # raises for a finished run with another budget
    by_run = {s.name: s for s in specs}
    plan = Plan(specs, finished, [s for s in specs if s.name not in finished], {}, [],
                 seeds={(c, m): list(args.seeds) for c in args.configs for m in args.methods if METHODS[m].learned},
                 budgets={s.name: s.timesteps for s in specs})
    for config in args.configs:
        for name in args.methods:
            method = METHODS[name]
            for seed in args.seeds if method.learned else [None]:
                spec = eval_spec(args, config, name, seed)
                if seed is None:
                    wanted, source = evaluation_fingerprint(args, config, method, None, None), None
                elif (run := by_run[run_name(name, config, seed)]).name in finished:
                    source = run_files(run.run_dir)
                    wanted = evaluation_fingerprint(args, config, method, run.name, model_sha256(source))
                else:
                    wanted, source = None, run  # trained in this sweep: evaluated after
                path = evaluation_path(out, config, spec.key)
                cached = None if args.reevaluate or wanted is None else cached_evaluation(path, wanted, protocol)
                if cached is not None:
                    plan.evaluations[(config, spec.key)] = cached
                else:
                    plan.to_evaluate.append((spec, source))
    return plan



def resume_point(spec) -> int:
    """The samples of the run's newest checkpoint (0 when it has none): where its training resumes."""
    ckpt = latest_checkpoint(Path(spec.run_dir)) if Path(spec.run_dir).is_dir() else None
    return ckpt[1] if ckpt else 0
