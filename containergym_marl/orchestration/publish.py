"""Copy what a comparison produced into the repository (every run with its policies, every
evaluation, the best and median model of each (row, method), the table), and bring it back.

    containergym-marl publish --runs RUNS --compare OUT --to results/paper_rows
    containergym-marl publish --runs RUNS --compare OUT --to results/paper_rows --restore

RUNS is compare's ``--runs`` folder, OUT its ``--out`` folder (MAPPO runs of
``baselines/sweep_mappo_rows.sh`` go to the same two); ``--methods A B`` publishes only those methods'
runs and evaluations (a runs folder shared with methods still training). An evaluation that compare
made of a run is published only if it is of the model that run now ships (its hash; otherwise an
error naming the file, before anything is written). For every finished run (its final model) it
copies ``args.json``, ``run.json``, ``config.toml``, ``metrics.csv``, ``curve.json``, the best, the
final and, where its curve picked one, the validated model (``best_model.zip`` …, or ``.pt``: the file
names of the algorithm's registry entry; the policy the evaluations use is the validated model, else
the best, :func:`~containergym_marl.evaluation.run_policies.evaluated_which`) to ``<to>/runs/<run>/``
(~330 kB an SB3 run);
with ``--with-checkpoints``, every interrupted SB3 run too, with only its newest intact checkpoint,
so that a later session on another machine resumes it (``--restore``; an interrupted MAPPO run,
~15 minutes of training, is not published). Every evaluation file of OUT goes to
``<to>/evaluations/<config>/``; for each (config, method) with at least ``--min-seeds`` evaluated
seeds, every seed's policy is evaluated on 100 validation episodes (``<to>/validation/``), and the
policy of its best and of its median seed by mean validation return (the table's rule) goes to
``<to>/models/<config>/<method>_{best,median}.zip`` (``.pt`` for MAPPO) with
``<method>.json`` naming the seeds and their returns (git stores each of these once: they are the
runs' own files), each with a model card (``<method>_{best,median}.md``, Hugging Face's format) and,
for a native actor-critic, its weights as ``.safetensors`` (:mod:`~containergym_marl.orchestration.model_cards`).
Every seed's policy and every rule-based controller is then evaluated on 200 fresh
episodes (``<to>/fresh/``, seeds 30000-30199, used for nothing else). Finally ``<to>/table.{md,csv,json}`` is rebuilt from the evaluation files alone
(``python -m containergym_marl.evaluation.table <to> --out <to>`` does the same), ``<to>/compute.md``
sums the finished runs' training time per row and per method (their CPU time where they recorded it,
else their wall time). With ``--readme README.md`` the README shows a
compact table of IQMs (rows × methods) between its results-table markers, and with
``--docs docs/results.md`` the generated blocks of the results page are rewritten (the compact table,
the full table, one table per row); tests check that both show the committed files. Rerunning it is
safe: files are replaced atomically, nothing else is touched.

    containergym-marl publish --pages-only --readme README.md --docs docs/results.md

rewrites only the README's table and the results page from what ``--to`` holds now.

``--restore`` goes the other way before a sweep is rerun on a fresh machine: runs of ``<to>/runs``
that RUNS lacks or holds less far trained are copied there, evaluations OUT lacks are copied to
OUT, so that ``compare`` reuses the finished runs and evaluations and resumes the rest. It checks
a published run before it reads it: only the files the manifest lists are copied (any other file,
hidden ones aside, is refused), each a regular file of the listed size, then of the listed sha256
(read in blocks).

A results folder may come from someone else: neither direction follows a symbolic link in RUNS,
OUT or the results folder (:mod:`containergym_marl.files`' rule; a link is an error naming it,
raised before anything is written), and each copy into a run folder holds that run's lock
(:class:`~containergym_marl.rundir.RunLock`: a run that a process trains is an error naming it, and
the lock is held until the run's last file is copied).
"""

from __future__ import annotations

import json
import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

from containergym_marl.algorithms import get_algorithm
from containergym_marl.core.dynamics import DEFAULT_ARBITRATION
from containergym_marl.evaluation import metrics
from containergym_marl.evaluation import table as tables
from containergym_marl.files import atomic_write, atomic_write_text, open_file, refuse_links, refuse_links_in
from containergym_marl.manifest import check_file, is_covered, read_manifest, write_manifest
from containergym_marl.methods import METHODS, PAIRS, TWINS
from containergym_marl.options import option
from containergym_marl.orchestration import model_cards
from containergym_marl.rundir import (
    checkpoint_files,
    checkpoints,
    clear_run,
    MODELS,
    latest_intact_checkpoint,
    model_file,
    model_suffix,
    read_run_summary,
    run_args,
    run_name,
    run_status,
    RunLock,
)

SMALL_FILES = ("args.json", "run.json", "config.toml", "metrics.csv", "curve.json")


def _copy(src: Path, dst: Path, within: Path) -> None:
    """Copy the regular file ``src`` (not a link) to ``dst`` crash-safe, in blocks; no component of
    ``dst`` below ``within`` (the folder written) may be a link."""
    def write(tmp: Path) -> None:
        with open(tmp, "wb") as out:
            shutil.copyfileobj(f, out)

    with open_file(src, "rb") as f:
        atomic_write(dst, write, within)


def _trained_samples(run: Path) -> int:
    """How far a run got: its budget when finished, else its newest checkpoint's samples (0: none)."""
    if run_status(run) == "finished":
        return int(json.loads((run / "args.json").read_text())["timesteps"])
    found = checkpoints(run)
    return found[0][0] if found else 0


def _copy_run(run: Path, to: Path) -> bool:
    """Copy the run to ``<to>/runs/<run>`` under that folder's lock: its small files and policies;
    for an unfinished run, its newest intact checkpoint only (SB3 runs: a MAPPO run's BenchMARL
    folder, checkpoints included, stays behind), and only when it got at least as far as the copy
    there. Returns whether it copied."""
    dst = refuse_links(to / "runs" / run.name, to)
    with RunLock(dst):  # a RunError naming the holder when a process trains there
        finished = run_status(run) == "finished"
        if not finished and _trained_samples(run) < _trained_samples(dst):
            return False
        for name in SMALL_FILES + tuple(model_file(run, which) for which in MODELS):
            if (run / name).is_file():
                _copy(run / name, dst / name, to)
        keep = set()
        if not finished and (steps := latest_intact_checkpoint(run)) is not None:
            for path in checkpoint_files(run, steps, model_suffix(run)).values():
                if path.is_file():
                    _copy(path, dst / "checkpoints" / path.name, to)
                    keep.add(path.name)
        for old in (dst / "checkpoints").glob("*") if (dst / "checkpoints").is_dir() else []:
            if old.name not in keep:  # an older checkpoint, or any once the run has finished
                old.unlink()
        if (dst / "checkpoints").is_dir() and not keep:
            (dst / "checkpoints").rmdir()
    return True


def _run_method(run: Path) -> str | None:
    """The method a run trained, as compare names it (its algorithm and reward mode); None when its
    arguments do not name a registered algorithm (a MAPPO run of its own script)."""
    try:
        saved = run_args(run)
        return get_algorithm(saved["algo"]).method_name(saved.get("reward_mode"))
    except (OSError, KeyError, ValueError):
        return None


def _check_evaluated_models(evaluations: list[Path], runs: Path) -> None:
    """A ValueError naming the file, when an evaluation made by compare of a run in ``runs`` is not of the
    model that run now has its seed stand for (evaluated_files: the validated model where its curve picked
    one, else the best): the table would show numbers of another model than the one shipped."""
    from containergym_marl.evaluation.run_policies import evaluated_files
    from containergym_marl.orchestration.plan import model_sha256, run_files  # the hash compare records

    for path in evaluations:
        try:
            made = json.loads(path.read_text()).get("compare") or {}
        except (ValueError, AttributeError):
            raise ValueError(f"{str(path)!r} is not an evaluation file (a JSON object); nothing was written") from None
        if not made.get("model_sha256") or not made.get("run"):
            continue  # a controller's evaluation, or one made before compare recorded its model
        name = made["run"]
        if not isinstance(name, str) or Path(name).name != name or name in (".", ".."):
            raise ValueError(f"{str(path)!r} names the run {name!r}, not a folder's name in {str(runs)!r}; "
                             f"nothing was written")
        run = runs / name
        if run_status(run) != "finished":
            continue
        model = run / evaluated_files(run)[-1]
        if (sha := model_sha256(run_files(run))) != made["model_sha256"]:
            raise ValueError(f"{str(path)!r} evaluates a model of {run.name} with sha256 {made['model_sha256'][:12]}…, "
                             f"but the run's {model.name} has {sha[:12]}…: evaluate it again (compare) before "
                             f"publishing; nothing was written")


def publish(runs: Path, compare_out: Path, to: Path, min_seeds: int = 3, with_checkpoints: bool = False,
            readme: Path | None = None, pages: tuple[Path, ...] = (), methods: tuple[str, ...] = ()) -> dict:
    """Publish a comparison into ``to``: every finished run of ``runs`` (its small files and models;
    an interrupted one's newest checkpoint with ``with_checkpoints``), the evaluations of
    ``compare_out``, the best and median model of each (row, method) with at least ``min_seeds``
    seeds, picked on validation episodes, the table, and the generated blocks of ``readme`` and
    ``pages``; with ``methods``, only the runs and evaluations of these methods. An evaluation of a
    run that is not of the model the run ships is an error before anything is written. Returns what
    was published, by kind."""
    for folder in (runs, compare_out, to):  # before anything is written: no link followed in any
        refuse_links_in(folder)
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"methods: unknown method(s) {unknown}; choose from {tuple(METHODS)}")
    chosen = [run for run in sorted(p for p in runs.iterdir() if p.is_dir() and not p.name.startswith("."))
              if not methods or _run_method(run) in methods]
    evaluations = [path for path in sorted((compare_out / "evaluations").glob("*/*.json"))
                   if not methods or tables.parse_evaluation_key(path.stem)[0] in methods]
    _check_evaluated_models(evaluations, runs)
    done = {"runs": [], "interrupted": [], "evaluations": 0, "models": []}
    for run in chosen:
        status = run_status(run)
        if status == "finished":
            _copy_run(run, to)
            done["runs"].append(run.name)
        elif status == "interrupted" and with_checkpoints and latest_intact_checkpoint(run) is not None:
            if _copy_run(run, to):
                done["interrupted"].append(run.name)
    for path in evaluations:
        _copy(path, to / "evaluations" / path.parent.name / path.name, to)
        done["evaluations"] += 1
    if not any((to / "evaluations").glob("*/*.json")):
        write_manifest(to)
        return done  # runs only (a sweep still training): no table yet
    return {**done, **republish(to, min_seeds, readme, pages)}


def republish(to: Path, min_seeds: int = 3, readme: Path | None = None, pages: tuple[Path, ...] = ()) -> dict:
    """What ``publish`` does once the runs and evaluations are in ``to``: every published policy on
    the validation episodes (where missing or its model changed), the best and median models picked
    there, every policy on the fresh episodes, the table, its figures over seeds and rows
    (:func:`~containergym_marl.evaluation.aggregate_plots.draw_aggregate_figures`, in ``figures/``),
    the compute note, the manifest and the pages."""
    from containergym_marl.evaluation.run_policies import evaluated_files

    refuse_links_in(to)
    done = {"models": [], "validation": evaluate_selection(to, min_seeds)}  # where best and median are picked
    to_card = []  # (card file, what it describes) of every shipped model
    for group in tables.load_evaluations(to):
        if len(group.seeds) < min_seeds:
            continue  # a rule-based controller (nothing to ship), or a row still training
        runs_of = [to / "runs" / run_name(group.method, group.config, seed) for seed in group.seeds]
        if not all(run_status(r) == "finished" for r in runs_of):
            continue
        means = group.seed_means
        picked = {"best": group.best, "median": group.median}
        folder = to / "models" / group.config
        files, weights, cards = {}, {}, {}
        for which, i in picked.items():
            model = runs_of[i] / evaluated_files(runs_of[i])[-1]  # the model its evaluations evaluated
            files[which] = f"{group.method}_{which}{model.suffix}"
            _copy(model, folder / files[which], to)
            shipped = {"model": files[which]}
            if model_cards.is_actor_critic(run_args(runs_of[i])["algo"]):
                weights[which] = f"{group.method}_{which}.safetensors"
                model_cards.write_safetensors(folder / files[which], folder / weights[which])
                shipped["safetensors"] = weights[which]
            cards[which] = f"{group.method}_{which}.md"
            to_card.append((folder / cards[which], {
                "method": group.method, "config": group.config, "view": group.view, "which": which,
                "seed": group.seeds[i], "seeds": len(group.seeds), "picked_on": group.selected_on,
                "run": runs_of[i], "files": shipped}))
        atomic_write_text(folder / f"{group.method}.json", json.dumps({
            "config": group.config, "method": group.method, "view": group.view,
            "best_seed": group.seeds[picked["best"]], "median_seed": group.seeds[picked["median"]],
            "seed_mean_returns": {str(s): float(m) for s, m in zip(group.seeds, means)},
            "picked_on": group.selected_on,
            "files": files, **({"safetensors": weights} if weights else {}), "cards": cards,
        }, indent=2) + "\n", within=to)
        done["models"].append(f"{group.config}/{group.method}")
    done["fresh"] = evaluate_fresh(to, min_seeds)
    for path, fields in to_card:  # after the fresh episodes, whose numbers the cards show
        model_cards.write_card(to, path, **fields)
    table = tables.build_table(tables.load_evaluations(to), PAIRS)
    table.write(to, {"source": "containergym-marl publish"})
    from containergym_marl.evaluation.aggregate_plots import draw_aggregate_figures  # matplotlib: only here

    done["figures"] = [str(p.relative_to(to)) for p in draw_aggregate_figures(to, pairs=TWINS + PAIRS)]
    atomic_write_text(to / "compute.md", training_compute(to / "runs"))
    write_manifest(to)
    if readme is not None or pages:
        write_pages(to, ([readme] if readme is not None else []) + list(pages))
    return done


def _published_policies(to: Path, min_seeds: int):
    """(group, seed, run or None) of every published policy: each finished run of a (row, method)
    with at least ``min_seeds`` seeds, and each policy without training seeds (run None)."""
    for group in tables.load_evaluations(to / "evaluations"):
        if not group.seeds:
            yield group, None, None
            continue
        if len(group.seeds) < min_seeds:
            continue
        for seed in group.seeds:
            run = to / "runs" / run_name(group.method, group.config, seed)
            if run_status(run) == "finished":
                yield group, seed, run


def _evaluate_into(to: Path, folder: str, protocol, min_seeds: int, runs_only: bool) -> list[str]:
    """Every published policy on ``protocol``'s episodes, into ``<to>/<folder>/<config>/<key>.json``
    with the sha256 of the model evaluated (a rule: its name), evaluated again only when that model
    or the protocol changes. Learned policies are evaluated all episodes at once
    (:func:`~containergym_marl.evaluation.batched.evaluate_batched`, one torch thread), rules one
    episode after another. Returns what was evaluated."""
    from dataclasses import asdict

    from containergym_marl.core.params import PlantParams
    from containergym_marl.evaluation import evaluate
    from containergym_marl.evaluation.batched import evaluate_batched
    from containergym_marl.evaluation.run_policies import (
        evaluated_files,
        evaluated_model,
        evaluated_which,
        policy_from_run,
    )
    from containergym_marl.manifest import sha256_bytes
    from containergym_marl.methods import CONTROLLERS

    done = []
    for group, seed, run in _published_policies(to, min_seeds):
        if run is None and (runs_only or group.method not in CONTROLLERS):
            continue
        path = to / folder / group.config / f"{tables.evaluation_key(group.method, seed)}.json"
        if run is not None:
            key = sha256_bytes(evaluated_model({name: (run / name).read_bytes() for name in evaluated_files(run)}))
        else:
            key = group.method
        if path.is_file():
            old = json.loads(path.read_text())
            if old.get("model_sha256") == key and old.get("protocol") == asdict(protocol):
                continue
        if run is not None:
            import torch

            threads = torch.get_num_threads()
            torch.set_num_threads(1)  # small networks: one thread is fastest, and fair to a busy machine
            try:
                saved = run_args(run)
                result = evaluate_batched(policy_from_run(run, evaluated_which(run)), group.config, protocol,
                                          arbitration=saved.get("arbitration", DEFAULT_ARBITRATION))
            finally:
                torch.set_num_threads(threads)
        else:
            controller = CONTROLLERS[group.method](PlantParams.from_config(protocol.plant(group.config)))
            result = evaluate(controller, group.config, protocol, keep_records=False)
        atomic_write_text(path, compact_evaluation(json.loads(result.to_json()), key), within=to)
        done.append(f"{group.config}/{tables.evaluation_key(group.method, seed)}")
    return done


#: What a validation or fresh evaluation file keeps of each episode (hundreds of them per policy; the
#: test evaluations keep every metric): what the table reads.
COMPACT_EPISODE = ("seed", "cumulative_reward", "steps", "overflow")


def compact_evaluation(data: dict, model_sha256: str) -> str:
    """An evaluation's JSON with :data:`COMPACT_EPISODE` of each episode, its summary over all of
    them and the sha256 of the model evaluated, on as few bytes as JSON allows."""
    data = {**data, "episodes": [{k: e[k] for k in COMPACT_EPISODE} for e in data["episodes"]],
            "model_sha256": model_sha256}
    return json.dumps(data, separators=(",", ":")) + "\n"


def evaluate_selection(to: Path, min_seeds: int = 3) -> list[str]:
    """Every published seed's policy on the validation episodes its (row, method)'s best and median
    seed are picked on (:data:`~containergym_marl.evaluation.protocol.SELECTION`: 100 episodes, seeds
    20000-20099), into ``<to>/validation/``."""
    from containergym_marl.evaluation.protocol import SELECTION

    return _evaluate_into(to, tables.VALIDATION_FOLDER, SELECTION, min_seeds, runs_only=True)


def evaluate_fresh(to: Path, min_seeds: int = 3) -> list[str]:
    """Every published seed's policy, and every rule-based controller, on the fresh episodes
    (:data:`~containergym_marl.evaluation.protocol.FRESH`: 200 episodes, seeds 30000-30199, used for
    nothing else), into ``<to>/fresh/``."""
    from containergym_marl.evaluation.protocol import FRESH

    return _evaluate_into(to, tables.FRESH_FOLDER, FRESH, min_seeds, runs_only=False)


def training_compute(runs: Path) -> str:
    """What training the finished runs under ``runs`` took, per row and per method: each run's CPU
    seconds (``run.json``'s ``cpu_time_s``, all segments of a resumed run) where it recorded them, else
    its wall time. Each run trains on one core."""
    per_row: dict[str, list[float]] = {}
    per_method: dict[str, list[float]] = {}
    by_wall = 0
    for run in sorted(p for p in runs.iterdir() if p.is_dir()) if runs.is_dir() else []:
        if run_status(run) != "finished":
            continue
        args, summary = run_args(run), read_run_summary(run) or {}
        seconds = summary.get("cpu_time_s")
        if seconds is None:
            seconds, by_wall = summary.get("wall_time_s") or 0.0, by_wall + 1
        per_row.setdefault(args["config"], []).append(float(seconds))
        per_method.setdefault(get_algorithm(args["algo"]).method_name(args.get("reward_mode")), []).append(
            float(seconds))

    def listed(groups: dict[str, list[float]], key) -> str:
        return " · ".join(f"{name}: {len(v)} run{'' if len(v) == 1 else 's'}, {sum(v) / 3600:.1f} h"
                          for name, v in sorted(groups.items(), key=lambda kv: key(kv[0])))

    order = {name: k for k, name in enumerate(METHODS)}
    total_runs = sum(len(v) for v in per_row.values())
    total_h = sum(sum(v) for v in per_row.values()) / 3600
    measured = ("the CPU time of each run's training process (run.json's cpu_time_s)" if not by_wall else
                "the wall time of each run (run.json's wall_time_s), which a busy machine inflates"
                if by_wall == total_runs else
                f"the CPU time of each run's training process (run.json's cpu_time_s), or its wall time for the "
                f"{by_wall} that predate it (wall_time_s, which a busy machine inflates)")
    return (f"Training compute of the {total_runs} finished runs published here: {total_h:.1f} core-hours, "
            f"{measured}; each run trains on one core. Per row: {listed(per_row, tables.config_sort_key)}.\n\n"
            f"Per method: {listed(per_method, lambda name: (order.get(name, len(order)), name))}.\n")


#: The columns of the compact table, in order (a method without any published evaluation is left out):
#: the rules, the paper's PPO baselines as the package trains them (15 seeds a row), SB3's runs of the
#: same methods at the paper's settings (the reproduction), MAPPO, the imitations of the planner, and
#: the rollout planner through the container agents' view: its cheap setting, and the reference (with the
#: deadline check, which overflowed in none of 1,000 fresh episodes of each contended plant).
COMPACT_METHODS = ("rule_based", "rule_based_agents", "fast_ppo", "fast_shared_ppo", "fast_shared_ppo_team",
                   "ppo", "shared_ppo", "shared_ppo_team", "mappo", "dagger_agents", "dagger_ppo_agents",
                   "planner_agents", "planner_agents_shielded")


def _table_json(to: Path) -> dict:
    return json.loads((to / "table.json").read_text())


def compact_table(to: Path) -> str:
    """One row per config, one column per method: the IQM over training seeds of the mean test return
    (with the number of seeds), the mean test return for the rule-based controllers and the planner."""
    rows = _table_json(to)["rows"]
    by_key = {(r["config"], r["method"]): r for r in rows}
    configs = list(dict.fromkeys(r["config"] for r in rows))
    methods = [m for m in COMPACT_METHODS if any(r["method"] == m for r in rows)]
    header = ["row", *(f"`{m}`" for m in methods)]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for config in configs:
        cells = [f"`{config}`"]
        for m in methods:
            r = by_key.get((config, m))
            cells.append("–" if r is None else f"{r['iqm']:.1f}" + (f" ({r['seeds']})" if r["seeds"] else ""))
        lines.append("| " + " | ".join(cells) + " |")
    runs = sum(r["seeds"] for r in rows)
    planner = any(m.startswith("planner") for m in methods)
    note = (f"Test return (the paper's protocol: δ = 120 s, T = 600, 15 episodes). Learned methods: interquartile "
            f"mean over training seeds of each seed's mean test return, seeds in brackets ({runs} evaluated "
            f"policies); rule-based controllers" + (" and the rollout planner" if planner else "")
            + ": mean over the test episodes. Generated by `containergym-marl publish` from "
            "`results/paper_rows/table.json`.")
    return "\n".join(lines) + "\n\n" + note + "\n"


def readme_block(to: Path) -> str:
    """What the README shows between its results-table markers: the compact table."""
    return compact_table(to)


def _overflowing_seeds(group) -> int:
    return sum(any(e["overflow"] for e in ev["episodes"]) for ev in group.evaluations)


def row_block(to: Path, config: str, evaluations: list | None = None) -> str:
    """The results page's table of one row: every method with its seeds' spread, the best seed's
    behaviour, the paper's PPO and the probabilities of improvement. ``evaluations``: the folder's
    loaded evaluations (:func:`~containergym_marl.evaluation.table.load_evaluations`), read when not given."""
    data = _table_json(to)
    evaluations = tables.load_evaluations(to / "evaluations") if evaluations is None else evaluations
    groups = {g.method: g for g in evaluations if g.config == config}
    shown = metrics.shown_in("row")
    headers = ["method", "view", "seeds", "IQM [95 % CI]", "median seed", "lowest – highest seed",
               "seeds with an overflowing test episode", *(("best seed: " if i == 0 else "") + m.label
                                                           for i, m in enumerate(shown))]
    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    for r in (r for r in data["rows"] if r["config"] == config):
        g = groups[r["method"]]
        means = g.seed_means
        seeded = bool(r["seeds"])
        lines.append(
            f"| `{r['method']}` | {r['view']} | {r['seeds'] or '–'} | "
            + (f"{r['iqm']:.2f} [{r['iqm_low']:.2f}, {r['iqm_high']:.2f}]" if seeded else f"{r['iqm']:.2f}")
            + f" | {r['median_mean']:.2f} | "
            + (f"{means.min():.2f} – {means.max():.2f}" if seeded else "–") + " | "
            + (f"{_overflowing_seeds(g)} of {len(means)}" if seeded else "–")
            + "".join(f" | {tables.format_value(r[m.column], m.fmt)}" for m in shown) + " |")
    paper = tables.PAPER_TABLE_1.get(config, {}).get("ppo")
    if paper:
        lines += ["", f"The paper's PPO on this row (15 seeds): best seed {paper[0][0]:.2f}, median seed {paper[1][0]:.2f}."]
    imps = [i for i in data["improvements"] if i["config"] == config]
    if imps:
        lines += ["", "Probability of improvement [95 % bootstrap CI]: " + "; ".join(
            f"P(`{i['decentralised']}` > `{i['centralised']}`) = {i['probability']:.2f} [{i['low']:.2f}, "
            f"{i['high']:.2f}] (over {i['unit']})" for i in imps) + "."]
    return "\n".join(lines) + "\n"


def page_blocks(to: Path) -> dict[str, str]:
    """Every block the publishing step writes into the documentation, by name: ``compact``, ``table``
    (the full table with the training compute) and ``row:<config>`` for each published row."""
    blocks = {"compact": compact_table(to),
              "table": (to / "table.md").read_text().rstrip("\n") + "\n\n" + (to / "compute.md").read_text()}
    evaluations = tables.load_evaluations(to / "evaluations")  # once for every row's block
    for config in dict.fromkeys(r["config"] for r in _table_json(to)["rows"]):
        blocks[f"row:{config}"] = row_block(to, config, evaluations)
    return blocks


PAGE_START = "<!-- generated by containergym-marl publish: {name}; do not edit -->"
_PAGE_START = re.compile(r"^<!-- generated by containergym-marl publish: (?P<name>\S+); do not edit -->$")
PAGE_END = "<!-- end of generated block: {name} -->"


def fill_page(text: str, blocks: dict[str, str]) -> str:
    """``text`` with the content of every generated block (between its start and end markers)
    replaced by ``blocks[name]``; a block the publishing step does not know is an error."""
    lines = text.splitlines(keepends=True)
    out, i = [], 0
    while i < len(lines):
        m = _PAGE_START.match(lines[i].rstrip("\n"))
        out.append(lines[i])
        i += 1
        if not m:
            continue
        name = m["name"]
        end = PAGE_END.format(name=name)
        try:
            j = next(k for k in range(i, len(lines)) if lines[k].rstrip("\n") == end)
        except StopIteration:
            raise ValueError(f"generated block {name!r} has no end marker ({end})") from None
        if name not in blocks:
            raise ValueError(f"generated block {name!r}: unknown (known: {', '.join(blocks)})")
        out += ["\n", blocks[name].rstrip("\n") + "\n", "\n", lines[j]]
        i = j + 1
    return "".join(out)


def write_pages(to: Path, pages: list[Path]) -> None:
    """Fill the generated blocks of each page (the README's results-table block included)."""
    blocks = page_blocks(to)
    for page in pages:
        text = page.read_text()
        if README_START_PREFIX in text:
            show_table_in_readme(page, blocks["compact"], to)
            text = page.read_text()
        new = fill_page(text, blocks)
        if new != text:
            atomic_write_text(page, new)


README_START = "<!-- results table: written by containergym-marl publish from {source}; do not edit -->"
README_START_PREFIX = "<!-- results table:"
README_END = "<!-- end of results table -->"


def show_table_in_readme(readme: Path, table_md: str, source: Path) -> None:
    """Replace the README's results-table block (between its two marker lines) by ``table_md``."""
    text = readme.read_text()
    lines = text.splitlines(keepends=True)
    starts = [i for i, line in enumerate(lines) if line.startswith(README_START_PREFIX)]
    ends = [i for i, line in enumerate(lines) if line.strip() == README_END]
    if len(starts) != 1 or len(ends) != 1 or ends[0] < starts[0]:
        raise ValueError(f"{readme}: expected one results-table block ({README_START_PREFIX} ... --> then "
                         f"{README_END}); found {len(starts)} start and {len(ends)} end marker(s)")
    block = [README_START.format(source=source.as_posix()) + "\n", "\n", table_md.rstrip("\n") + "\n", "\n"]
    atomic_write_text(readme, "".join(lines[:starts[0]] + block + lines[ends[0]:]))


def _published_files(to: Path, src: Path, manifest: dict) -> list[str]:
    """The files of the published run ``src`` (relative to it) that restore copies, each checked
    against the manifest of ``to`` before anything reads it: listed, then its size, then its sha256.
    Hidden files (the run's lock, temporary files) are left behind; any other unlisted one is a
    ManifestError."""
    names = []
    for directory, _folders, files in os.walk(src):  # the caller refused links in ``to``
        for name in files:
            path = Path(directory) / name
            if is_covered(path.relative_to(to).as_posix()):
                check_file(to, path.relative_to(to).as_posix(), manifest)
                names.append(path.relative_to(src).as_posix())
    return sorted(names)


def restore(to: Path, runs: Path, compare_out: Path) -> dict:
    """Copy published runs into ``runs`` where they are absent or further trained than there, and
    published evaluations into ``compare_out`` where absent. Every published run is checked
    (:func:`_published_files`) before any is read; each run is decided on, cleared and copied while
    holding its lock in ``runs``."""
    for folder in (to, runs, compare_out):  # before anything is read or written: no link followed in any
        refuse_links_in(folder)
    manifest = read_manifest(to)
    published = sorted(p for p in (to / "runs").iterdir() if p.is_dir()) if (to / "runs").is_dir() else []
    checked = {src: _published_files(to, src, manifest) for src in published}
    done = {"runs": [], "evaluations": 0}
    for src, names in checked.items():
        dst = runs / src.name
        with RunLock(dst):  # a RunError naming the holder when a process trains there
            if run_status(dst) != "absent" and _trained_samples(dst) >= _trained_samples(src):
                continue
            clear_run(dst)
            for name in names:
                _copy(src / name, dst / name, runs)
        done["runs"].append(src.name)
    for path in sorted((to / "evaluations").glob("*/*.json")):
        dst = compare_out / "evaluations" / path.parent.name / path.name
        if not dst.is_file():
            _copy(path, dst, compare_out)
            done["evaluations"] += 1
    return done


@dataclass
class PublishArgs:
    """The options of ``containergym-marl publish``."""

    runs: Path | None = option(None, type=Path, help="compare's --runs folder (required unless --pages-only)")
    compare: Path | None = option(None, type=Path, help="compare's --out folder (required unless --pages-only)")
    to: Path = option(Path("results/paper_rows"), type=Path, help="destination in the repository")
    min_seeds: int = option(3, type=int, help="ship models of a (row, method) from this many seeds on")
    with_checkpoints: bool = option(False, action="store_true",
                                    help="also publish interrupted runs with their newest checkpoint (resumable "
                                         "elsewhere)")
    readme: Path | None = option(None, type=Path,
                                 help="also show the compact table in this README, between its results-table markers")
    docs: list[Path] = option(default_factory=list, type=Path, nargs="*", metavar="PAGE",
                              help="also fill the generated blocks of these documentation pages (docs/results.md)")
    pages_only: bool = option(False, action="store_true",
                              help="only rewrite the README's table and the --docs pages from what --to holds now")
    republish: bool = option(False, action="store_true",
                             help="evaluate what --to holds where needed (validation and fresh episodes), pick its "
                                  "best and median models, rebuild its table (and the pages); no --runs or --compare")
    restore: bool = option(False, action="store_true",
                           help="copy published runs and evaluations back into --runs and --compare instead")
    methods: list[str] = option(default_factory=list, nargs="*", metavar="METHOD",
                                help="publish only the runs and evaluations of these methods (a folder that holds "
                                     "others too, e.g. a campaign still training them)")


def run(a: PublishArgs) -> int:
    """``containergym-marl publish``: publish, restore, or rewrite the pages."""
    if a.pages_only:
        write_pages(a.to, ([a.readme] if a.readme else []) + list(a.docs))
        print(f"wrote the generated blocks of {', '.join(str(p) for p in [a.readme, *a.docs] if p)} from {a.to}/")
        return 0
    if a.republish:
        done = republish(a.to, a.min_seeds, a.readme, tuple(a.docs))
        print(f"evaluated {len(done['validation'])} polic(ies) on validation and {len(done['fresh'])} on fresh "
              f"episodes; models of {len(done['models'])} (row, method) pair(s) in {a.to}/")
        return 0
    if a.runs is None or a.compare is None:
        raise ValueError("--runs and --compare are required (unless --pages-only)")
    if a.restore:
        done = restore(a.to, a.runs, a.compare)
        print(f"restored {len(done['runs'])} run(s) and {done['evaluations']} evaluation(s) from {a.to}/")
        return 0
    done = publish(a.runs, a.compare, a.to, a.min_seeds, a.with_checkpoints, a.readme, tuple(a.docs), tuple(a.methods))
    size = sum(p.stat().st_size for p in (a.to / "models").rglob("*") if p.suffix in (".zip", ".pt"))
    print(f"published {len(done['runs'])} finished run(s), {len(done['interrupted'])} interrupted one(s) with "
          f"their newest checkpoint, {done['evaluations']} evaluation(s), models of "
          f"{len(done['models'])} (row, method) pair(s) ({size / 1e6:.1f} MB of models) to {a.to}/")
    return 0
