"""The shipped policies: what a folder of published runs (containergym-marl publish) offers a
comparison, planned from its files alone, and whether the policies evaluated now return what their
published evaluations say."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from containergym_marl.evaluation import table as tables
from containergym_marl.files import atomic_write_text
from containergym_marl.manifest import check as manifest_check
from containergym_marl.manifest import read_manifest
from containergym_marl.methods import METHODS
from containergym_marl.orchestration.compare_args import CompareArgs
from containergym_marl.orchestration.plan import (
    Plan,
    Shipped,
    cached_evaluation,
    config_stem,
    eval_spec,
    evaluation_path,
    evaluation_fingerprint,
    model_sha256,
    run_files,
)
from containergym_marl.rundir import checkpoints, finished_budget, model_file, run_name, seeded_runs


def shipped_plan(args: CompareArgs, out: Path) -> Plan:
    """The evaluations of the shipped policies: every rule-based controller; for each learned
    method, the best published seed and every finished seed without a published evaluation of the
    same model, plant and protocol are evaluated, the other seeds' published evaluations reused.
    Reads the shipped folder only."""

    folder = Path(args.shipped)
    manifest = read_manifest(folder)
    protocol = asdict(args.eval_protocol())
    shipped = Shipped(folder)
    plan = Plan([], set(), [], {}, [], shipped=shipped)

    def use(config: str, spec, fingerprint: dict, source, published: dict | None = None) -> None:
        path = evaluation_path(out, config, spec.key)
        cached = None if args.reevaluate else cached_evaluation(path, fingerprint, protocol)
        if cached is not None:
            plan.evaluations[(config, spec.key)] = cached
        elif published is not None:  # a published evaluation of this very model: copied into --out
            data = {**published, "copied_from": str(evaluation_path(folder, config, spec.key))}
            path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(path, json.dumps(data, indent=2) + "\n")
            plan.evaluations[(config, spec.key)] = data
            shipped.copied.append(f"{config_stem(config)}/{spec.key}")
        else:
            plan.to_evaluate.append((spec, source))

    for config in args.configs:
        stem = config_stem(config)
        for name in args.methods:
            method = METHODS[name]
            if not method.learned:
                use(config, eval_spec(args, config, name, None), evaluation_fingerprint(args, config, method, None, None), None)
                continue
            found = []  # (seed, files, fingerprint, published evaluation or None)
            for seed, run in seeded_runs(folder / "runs", name, config):
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
                files = run_files(run)
                for file_name, data in files["files"].items():  # never a model changed after publication
                    manifest_check(folder, f"runs/{run.name}/{file_name}", data, manifest)
                fingerprint = evaluation_fingerprint(args, config, method, run.name, model_sha256(files),
                                                     timesteps=trained)
                published = cached_evaluation(evaluation_path(folder, config, tables.evaluation_key(name, seed)),
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
                spec = eval_spec(args, config, name, seed)
                if published is not None:
                    shipped.published[(config, spec.key)] = published
                use(config, spec, fingerprint, files, None if seed == best or args.reevaluate else published)
        if not shipped.learned.get(stem):
            shipped.missing.append(stem)
    return plan



def shipped_report(shipped: Shipped, evaluations: dict[tuple[str, str], dict], evaluated: list[str]) -> dict:
    """What the shipped folder offered, and whether the policies evaluated now return what their
    published evaluations say (the same returns, episode by episode)."""
    fresh = {f"{config_stem(c)}/{k}": (c, k) for c, k in evaluations}
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


def shipped_summary(shipped: Shipped, report: dict, methods: list[str]) -> list[str]:
    """What compare says of the shipped policies it evaluated: reproduced, differing, skipped, missing."""
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
