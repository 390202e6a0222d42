"""The package's own PPO against Stable-Baselines3's, criterion by criterion, from a published folder.

    python studies/baseline_criteria.py                        # results/paper_rows -> results/baseline_criteria
    python studies/baseline_criteria.py --results DIR --out DIR

Reads what ``containergym-marl publish`` wrote: ``table.json`` (each (row, method)'s IQM of the
per-seed mean returns, on the paper's test protocol and on the fresh episodes) and
``fresh/<row>/<method>_s<seed>.json`` (each seed's fresh episodes), and reports, for every method
with an SB3 twin in the registry (``fast_ppo`` and ``ppo``, ``fast_shared_ppo`` and
``shared_ppo``, ``fast_shared_ppo_team`` and ``shared_ppo_team``):

1. on every row, both IQMs on both episode sets, and whether the package's is at least its twin's;
2. on every row, how many of its seeds overflow in a larger share of their fresh episodes than
   ``rule_based_agents`` does on the same episodes;
3. the moonshot: every learned method that learns from rewards alone (no teacher in the registry) set
   against ``rule_based_agents`` row by row on the fresh episodes (its IQM over seeds, and its interval,
   above the rule's mean), a method that carries a fixed rule beside its network marked so.

With ``--best-models``, a package method whose seeds stand by their validated models (the checkpoint
of highest validation return) is also set against its twin as SB3's seeds stand, by their best models
(of highest training return): each seed's best model on the same fresh episodes (batched, cached in
``<out>/best_models/`` by the model's hash), so that the comparison is of the algorithms alone.

A report, not a gate: it exits 0 whatever it finds (its tests check what it counts).
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
REFERENCE = "rule_based_agents"


def twins() -> dict[str, str]:
    """Each package PPO method and its SB3 twin, from the method registry."""
    from containergym_marl.methods import METHODS

    return {name: m.twin for name, m in METHODS.items() if m.twin}


def overflow_rate(path: Path) -> float:
    episodes = json.loads(path.read_text())["episodes"]
    return sum(bool(e["overflow"]) for e in episodes) / len(episodes)


def seed_overflow_rates(fresh: Path, row: str, method: str) -> dict[int, float]:
    """Each seed's fresh-episode overflow rate, from ``fresh/<row>/<method>_s<seed>.json``."""
    pattern = re.compile(rf"^{re.escape(method)}_s(\d+)\.json$")
    found = {int(m.group(1)): p for p in (fresh / row).glob("*.json") if (m := pattern.match(p.name))}
    return {seed: overflow_rate(found[seed]) for seed in sorted(found)}


def model_kinds(fresh: Path, row: str, method: str) -> str:
    """Which model of its runs stands for each seed in the fresh files (their policy labels,
    ``method[s1,validated]``): "validated", "best", or both joined by "+" where the seeds differ."""
    kinds = set()
    for path in (fresh / row).glob(f"{method}_s*.json"):
        label = json.loads(path.read_text()).get("policy", "")
        if re.fullmatch(rf"{re.escape(method)}\[s\d+,(.+)\]", label):
            kinds.add(label.rsplit(",", 1)[1].rstrip("]").split(":")[0])
    return "+".join(sorted(kinds)) or "–"


def best_model_iqm(results: Path, row: str, method: str, cache: Path) -> float | None:
    """The IQM over seeds of each seed's best model's mean return on the fresh episodes, where the
    published files evaluated validated models (else None: they are of best models already)."""
    import hashlib

    from containergym_marl.evaluation.stats import iqm
    from containergym_marl.rundir import run_name

    if "validated" not in model_kinds(results / "fresh", row, method):
        return None
    means = []
    pattern = re.compile(rf"^{re.escape(method)}_s(\d+)\.json$")
    for path in sorted((results / "fresh" / row).glob("*.json")):
        if not (m := pattern.match(path.name)):
            continue
        run = results / "runs" / run_name(method, row, int(m.group(1)))
        sha = hashlib.sha256((run / "best_model.pt").read_bytes()).hexdigest()
        stored = cache / row / path.name
        if stored.is_file() and json.loads(stored.read_text())["model_sha256"] == sha:
            means.append(json.loads(stored.read_text())["return_mean"])
            continue
        import torch

        from containergym_marl.evaluation.batched import evaluate_batched
        from containergym_marl.evaluation.protocol import FRESH
        from containergym_marl.evaluation.run_policies import policy_from_run
        from containergym_marl.files import atomic_write_text

        torch.set_num_threads(1)
        result = evaluate_batched(policy_from_run(run, "best"), row, FRESH)
        entry = {"model_sha256": sha, "return_mean": float(result.returns.mean()),
                 "overflowing_episodes": int(sum(bool(e.overflow) for e in result.episodes)),
                 "episodes": FRESH.episodes, "first_seed": FRESH.first_seed}
        stored.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(stored, json.dumps(entry) + "\n")
        means.append(entry["return_mean"])
    return iqm(means) if means else None


def criteria(results: Path, best_models: Path | None = None) -> dict:
    """Both criteria for every (row, package method) the folder holds with its twin; with
    ``best_models`` (a cache folder), also the package method's best models on the fresh episodes."""
    from containergym_marl.config.loading import list_configs

    table = json.loads((results / "table.json").read_text())
    known = set(list_configs())
    for r in table["rows"]:  # a row names files read and written: only a built-in plant's name
        if r.get("config") not in known:
            raise ValueError(f"{results / 'table.json'}: row config {r.get('config')!r} is not a built-in plant")
    rows = {(r["config"], r["method"]): r for r in table["rows"]}
    pairs, overflows = [], []
    for row in dict.fromkeys(r["config"] for r in table["rows"]):
        reference = results / "fresh" / row / f"{REFERENCE}.json"
        for native, twin in twins().items():
            ours, theirs = rows.get((row, native)), rows.get((row, twin))
            if ours is not None and theirs is not None:
                pairs.append({"row": row, "method": native, "twin": twin,
                              "seeds": ours["seeds"], "twin_seeds": theirs["seeds"],
                              "model": model_kinds(results / "fresh", row, native),
                              "twin_model": model_kinds(results / "fresh", row, twin),
                              **{f"{key}": ours[key] for key in ("iqm", "fresh_iqm")},
                              **{f"twin_{key}": theirs[key] for key in ("iqm", "fresh_iqm")},
                              "best_models_fresh_iqm": (best_model_iqm(results, row, native, best_models)
                                                        if best_models is not None else None),
                              "at_least_test": ours["iqm"] >= theirs["iqm"],
                              "at_least_fresh": (ours["fresh_iqm"] is not None and theirs["fresh_iqm"] is not None
                                                 and ours["fresh_iqm"] >= theirs["fresh_iqm"])})
            if ours is not None and reference.is_file():
                rates = seed_overflow_rates(results / "fresh", row, native)
                limit = overflow_rate(reference)
                overflows.append({"row": row, "method": native, "reference_rate": limit, "seeds": len(rates),
                                  "above": [seed for seed, rate in rates.items() if rate > limit]})
    shown = results.resolve()
    shown = shown.relative_to(REPO) if shown.is_relative_to(REPO) else shown  # a committed report names no machine
    return {"results": str(shown), "pairs": pairs, "overflows": overflows, "moonshot": moonshot(table["rows"])}


def moonshot(table_rows: list[dict]) -> list[dict]:
    """Each learned method without a teacher that the table holds: on every row where it and the rule
    both have fresh episodes, its fresh IQM [interval] against the rule's fresh mean."""
    from containergym_marl.methods import METHODS

    by = {(r["config"], r["method"]): r for r in table_rows}
    rows = list(dict.fromkeys(r["config"] for r in table_rows))
    found = []
    for name, method in METHODS.items():
        if not method.learned or method.teacher is not None:
            continue
        entries = []
        for row in rows:
            ours, rule = by.get((row, name)), by.get((row, REFERENCE))
            if ours is None or rule is None or ours.get("fresh_iqm") is None or rule.get("fresh_iqm") is None:
                continue
            entries.append({"row": row, "seeds": ours["seeds"], "fresh_iqm": ours["fresh_iqm"],
                            "fresh_iqm_low": ours.get("fresh_iqm_low"), "rule_fresh_mean": rule["fresh_iqm"],
                            "fresh_overflow_rate": ours.get("fresh_overflow_rate"),
                            "above": ours["fresh_iqm"] > rule["fresh_iqm"],
                            "interval_above": (ours.get("fresh_iqm_low") is not None
                                               and ours["fresh_iqm_low"] > rule["fresh_iqm"])})
        if entries:
            found.append({"method": name, "shield": method.shield, "rows": entries,
                          "every_row": len(entries) == len(rows) and all(e["above"] for e in entries)})
    return found


def _value(x) -> str:
    return "–" if x is None else f"{x:.2f}"


def report(found: dict) -> str:
    pairs, overflows = found["pairs"], found["overflows"]
    both = sum(p["at_least_test"] and p["at_least_fresh"] for p in pairs)
    lines = ["# The package's PPO against SB3's", "",
             f"`python studies/baseline_criteria.py --results {found['results']}`. IQM of the per-seed mean returns "
             "on the paper's test protocol (δ = 120 s, T = 600, 15 episodes) and on the fresh episodes; a pair holds "
             "where the package's IQM is at least its SB3 twin's on both. Model: which of each seed's models the "
             "files evaluated (validated: the checkpoint of highest validation return; best: of highest training "
             "return); a pair of different kinds does not compare the algorithms alone.", "",
             f"**{both} of {len(pairs)} pairs hold on both episode sets** "
             f"({sum(p['at_least_test'] for p in pairs)} on the test episodes, "
             f"{sum(p['at_least_fresh'] for p in pairs)} on the fresh ones).", "",
             "| row | method (seeds) | model | IQM, test | twin (seeds) | model | twin IQM, test | IQM, fresh "
             "| twin IQM, fresh | holds |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for p in pairs:
        holds = "yes" if p["at_least_test"] and p["at_least_fresh"] else (
            "test only" if p["at_least_test"] else "fresh only" if p["at_least_fresh"] else "no")
        lines.append(f"| {p['row']} | {p['method']} ({p['seeds']}) | {p['model']} | {_value(p['iqm'])} | {p['twin']} "
                     f"({p['twin_seeds']}) | {p['twin_model']} | {_value(p['twin_iqm'])} | {_value(p['fresh_iqm'])} | "
                     f"{_value(p['twin_fresh_iqm'])} | {holds} |")
    worst = [o for o in overflows if len(o["above"]) > 2]
    like = [p for p in pairs if p.get("best_models_fresh_iqm") is not None]
    if like:
        lines += ["", "Where the package's seeds stand by validated models, the same pairs with its seeds' best models "
                  "instead (of the highest training return, as SB3's seeds stand), on the same fresh episodes: "
                  f"**{sum(p['best_models_fresh_iqm'] >= p['twin_fresh_iqm'] for p in like)} of {len(like)} at least "
                  "the twin's**.", "",
                  "| row | method | IQM, fresh, best models | IQM, fresh, validated | twin IQM, fresh |", "|---|---|---|---|---|"]
        lines += [f"| {p['row']} | {p['method']} | {_value(p['best_models_fresh_iqm'])} | {_value(p['fresh_iqm'])} | "
                  f"{_value(p['twin_fresh_iqm'])} |" for p in like]
    lines += ["", f"Seeds that overflow in a larger share of their fresh episodes than `{REFERENCE}` on the same "
              f"episodes: **{len(worst)} of {len(overflows)} (row, method) have more than 2**.", "",
              f"| row | method | `{REFERENCE}`'s rate | seeds above it |", "|---|---|---|---|"]
    for o in overflows:
        above = ", ".join(f"s{s}" for s in o["above"]) or "none"
        lines.append(f"| {o['row']} | {o['method']} | {o['reference_rate']:.3f} | {len(o['above'])} of "
                     f"{o['seeds']}: {above} |")
    shots = found.get("moonshot", [])
    if shots:
        rows = list(dict.fromkeys(e["row"] for m in shots for e in m["rows"]))
        lines += ["", f"The moonshot: a method that learns from rewards alone (no planner in its training) above "
                  f"`{REFERENCE}` on every row, on the fresh episodes. Each cell is the method's fresh IQM over seeds "
                  "(its 95 % interval's low end) against the rule's fresh mean; `>` where the IQM is above it, `>>` "
                  "where the whole interval is. "
                  f"**{sum(m['every_row'] for m in shots)} of {len(shots)} methods are above it on every row**"
                  + (" (" + ", ".join(f"`{m['method']}`" for m in shots if m["every_row"]) + ")"
                     if any(m["every_row"] for m in shots) else "") + ".", "",
                  "| method | rows above | " + " | ".join(rows) + " |", "|---|---|" + "---|" * len(rows)]
        rule = {e["row"]: e["rule_fresh_mean"] for m in shots for e in m["rows"]}
        lines.append(f"| `{REFERENCE}` | – | " + " | ".join(f"{rule[r]:.2f}" for r in rows) + " |")
        for m in shots:
            cells = {e["row"]: (">> " if e["interval_above"] else "> " if e["above"] else "")
                     + f"{e['fresh_iqm']:.2f} ({_value(e['fresh_iqm_low'])})" for e in m["rows"]}
            name = f"`{m['method']}`" + (f" (with {m['shield']})" if m["shield"] else "")
            lines.append(f"| {name} | {sum(e['above'] for e in m['rows'])} of {len(m['rows'])} | "
                         + " | ".join(cells.get(r, "–") for r in rows) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--results", type=Path, default=REPO / "results" / "paper_rows",
                        help="a folder written by containergym-marl publish")
    parser.add_argument("--out", type=Path, default=REPO / "results" / "baseline_criteria",
                        help="where criteria.md and criteria.json go")
    parser.add_argument("--best-models", action="store_true",
                        help="also evaluate the best models of seeds that stand by validated ones (fresh episodes)")
    args = parser.parse_args(argv)
    if not (args.results / "table.json").is_file():
        parser.error(f"--results: {str(args.results)!r} holds no table.json (a folder written by publish)")
    from containergym_marl.files import atomic_write_text

    try:
        found = criteria(args.results, args.out / "best_models" if args.best_models else None)
    except ValueError as exc:
        parser.error(str(exc))
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "criteria.json", json.dumps(found, indent=1))
    text = report(found)
    atomic_write_text(out / "criteria.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
