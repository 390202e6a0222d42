"""The rollout planner's settings on validation episodes, and the planner on fresh episodes (issue 27).

    python studies/planner_validation.py                  # everything below (about 40 CPU-minutes)
    python studies/planner_validation.py --parts fresh --workers 2
    python studies/planner_validation.py --smoke          # two episodes of a few settings on one plant
    python studies/planner_validation.py --report         # only validation.md, from validation.json

Both views of the planner (``planner``: centralised, ``planner_agents``: container agents), with the
paper's test protocol (δ = 120 s, T = 600), on the five test plants (the ``_dt60`` and ``_dt120``
rows of a plant are evaluated on the same plant: the training δ does not concern a planner):

* ``settings``: each of ``overflow_penalty``, ``margin`` and ``min_reward`` varied alone around the
  defaults, on *validation* episodes (seeds 20000–20029): how the defaults were chosen.
* ``horizons``: the look-ahead H (K = 16 futures) on the contended plants n11_m2 and n16_m2,
  validation episodes: the docstring's claim that long horizons lower the return there.
* ``fresh``: the defaults on 200 *fresh* episodes (seeds 30000–30199: the one fresh range, used for
  nothing but reporting, on which the published tables evaluate every policy too; disjoint from the
  test seeds 10000–10014 and the validation seeds 20000+): the planner held to its claim of never
  overflowing, on episodes that chose nothing.
* ``wide``: the look-ahead widened on uncertain decisions (``max_futures``: more futures where a
  candidate is within two standard errors of the best) on the contended plants, 200 validation
  episodes (seeds 20000–20199) per setting: whether the sampling error the replays point at can be
  removed where it decides, and at what cost per step (issue 38).
* ``replay``: every fresh episode that overflowed, again with the planner's own seed changed
  (``seed`` = 1, 2) and with K = 64 futures: whether the overflow is the look-ahead's sampling error
  (a diagnosis, not a choice: the defaults stay those chosen on validation episodes). Runs after
  ``fresh``.
* ``safety``: the deadline check (``safety_risk``, :mod:`containergym_marl.policies.safety`) next to
  the defaults on the contended plants, ``--safety-episodes`` (default 1,000) episodes per setting and
  view from ``--safety-first-seed`` (default the fresh seeds 30000+, where the claim of no overflow is
  held; 20000 for validation episodes, on which its setting was chosen): whether it removes the
  overflows, at what return and time per step (issue 38).
* ``risk``: the deadline check at ε = 1e-4, 1e-5 and 1e-6 and the defaults on the contended plants,
  ``--risk-episodes`` (default 100) validation episodes each (seeds 20000+): the overflow rate each
  leaves, estimated by the episodes' mean overflow risk (the summed exact probability of an overflow
  at each step, :data:`~containergym_marl.evaluation.metrics.METRICS`), which sees rates of one in
  10,000 episodes that counting overflows cannot: how ε is chosen (issue 38).

Episodes run in blocks of 10 on ``--workers`` processes (the planner seeds its own generator from
each episode's seed, so a block gives what a whole evaluation would). Writes ``--out``/validation.json
after every block (resumable: blocks already there are reused) and validation.md.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from containergym_marl.evaluation.protocol import FRESH
from containergym_marl.files import atomic_write_text
from containergym_marl.orchestration.stopping import exit_on_sigterm, worker_pool
from containergym_marl.policies.planner import SHIELD
from containergym_marl.policies.safety import CHECK_VERSION, DECISIONS_CHANGED

#: one row per test plant (the δ of a row's training settings does not concern the planner)
PLANTS = ("n5_m2_dt120", "n5_m5_dt120", "n11_m2_dt120", "n11_m11_dt120", "n16_m2_dt120")
CONTENDED = ("n11_m2_dt120", "n16_m2_dt120")
VIEWS = ("planner", "planner_agents")
DEFAULTS = {"futures": 16, "horizon": 8, "overflow_penalty": 10.0, "margin": 1.0, "min_reward": 0.0}
#: each setting varied alone; the default is evaluated once
VARIED = {"overflow_penalty": (0.0, 3.0, 30.0, 100.0), "margin": (0.0, 2.0, 4.0), "min_reward": (-1.0, 0.25, 0.5)}
HORIZONS = (4, 8, 16, 24, 32, 48)
#: futures of an uncertain decision (the planner's ``max_futures``), the defaults' K first
WIDE = (16, 64, 128)
VALIDATION_SEED, FRESH_SEED = 20_000, FRESH.first_seed
BLOCK = 10
PARTS = ("settings", "horizons", "wide", "fresh", "replay", "safety", "risk")
#: the deadline check's setting (chosen on validation episodes 20000+; the shielded planners'), run next to the defaults
SAFETY = SHIELD
#: the deadline check's ε compared by the overflow risk they leave (W = the shield's)
RISKS = (1e-4, 1e-5, 1e-6)
#: how the overflowing fresh episodes are replayed
REPLAYS = ({"seed": 1}, {"seed": 2}, {"futures": 64})


def settings_for(part: str) -> list[tuple[str, dict]]:
    """(plant, settings) pairs of a part."""
    if part == "settings":
        variants = [dict(DEFAULTS)] + [{**DEFAULTS, key: v} for key, values in VARIED.items() for v in values]
        return [(plant, s) for plant in PLANTS for s in variants]
    if part == "horizons":
        return [(plant, {**DEFAULTS, "horizon": h}) for plant in CONTENDED for h in HORIZONS]
    if part == "wide":
        return [(plant, dict(DEFAULTS) if k == DEFAULTS["futures"] else {**DEFAULTS, "max_futures": k})
                for plant in CONTENDED for k in WIDE]
    if part == "safety":  # the shield's episodes first (the claim), then the defaults' beside them
        return [(plant, s) for s in ({**DEFAULTS, **SAFETY}, dict(DEFAULTS)) for plant in CONTENDED]
    if part == "risk":
        checks = [{**DEFAULTS, **SAFETY, "safety_risk": risk} for risk in RISKS]
        return [(plant, s) for s in (*checks, dict(DEFAULTS)) for plant in CONTENDED]
    return [(plant, dict(DEFAULTS)) for plant in PLANTS]


def key(part: str, plant: str, view: str, settings: dict, first_seed: int, episodes: int) -> str:
    return json.dumps([part, plant, view, settings, first_seed, episodes], sort_keys=True)


def run_block(job: tuple) -> dict:
    from containergym_marl.evaluation import EvalProtocol, evaluate
    from containergym_marl.policies import PlannerAgents, RolloutPlanner

    part, plant, view, settings, first_seed, episodes = job
    cls = PlannerAgents if view == "planner_agents" else RolloutPlanner
    cpu = time.process_time()
    result = evaluate(cls(**settings), plant, EvalProtocol(episodes=episodes, first_seed=first_seed), keep_records=False)
    return {"key": key(*job), "part": part, "plant": plant, "view": view, "settings": settings,
            "first_seed": first_seed, "episodes": episodes, "returns": result.returns.tolist(),
            "overflows": [int(e.overflow) for e in result.episodes], "cpu_s": time.process_time() - cpu,
            "risks": [e.overflow_risk for e in result.episodes],
            "steps": int(sum(e.steps for e in result.episodes)),
            **({"check": CHECK_VERSION} if settings.get("safety_risk") is not None else {})}


def jobs_for(parts: list[str], episodes: dict[str, int], safety_first_seed: int = FRESH_SEED) -> list[tuple]:
    jobs = []
    for part in parts:
        first = {"fresh": FRESH_SEED, "safety": safety_first_seed}.get(part, VALIDATION_SEED)
        for plant, settings in settings_for(part):
            for view in VIEWS:
                for start in range(0, episodes[part], BLOCK):
                    jobs.append((part, plant, view, settings, first + start, min(BLOCK, episodes[part] - start)))
    return jobs


def replay_jobs(rows: list[dict]) -> list[tuple]:
    """One-episode blocks: each overflowing fresh episode of the defaults under each of :data:`REPLAYS`."""
    return [("replay", r["plant"], r["view"], {**DEFAULTS, **change}, seed, 1)
            for r in rows if r["part"] == "fresh" for seed in r["overflowing_seeds"] for change in REPLAYS]


def summarise(blocks: list[dict]) -> list[dict]:
    """One row per (part, plant, view, settings): the blocks' episodes together."""
    rows: dict[str, dict] = {}
    for b in sorted(blocks, key=lambda b: b["first_seed"]):
        # fresh and validation episodes of a part (the safety part runs either) are rows apart
        k = json.dumps([b["part"], b["plant"], b["view"], b["settings"], b["first_seed"] >= FRESH_SEED], sort_keys=True)
        row = rows.setdefault(k, {"part": b["part"], "plant": b["plant"], "view": b["view"], "settings": b["settings"],
                                  "first_seed": b["first_seed"], "returns": [], "overflows": [], "cpu_s": 0.0,
                                  "steps": 0, "risks": []})
        row["returns"] += b["returns"]
        # blocks run before the overflow risk was measured have none: the row's risk is then unknown
        row["risks"] += b.get("risks", [float("nan")] * b["episodes"])
        row["overflows"] += b["overflows"]
        row["cpu_s"] += b["cpu_s"]
        row["steps"] += b["steps"]
    for row in rows.values():
        r = np.array(row["returns"])
        row.update(episodes=len(r), return_mean=float(r.mean()), return_sem=float(r.std(ddof=1) / np.sqrt(len(r)))
                   if len(r) > 1 else 0.0, overflowing_episodes=int(sum(row["overflows"])),
                   overflowing_seeds=[row["first_seed"] + i for i, o in enumerate(row["overflows"]) if o],
                   ms_cpu_per_step=1e3 * row["cpu_s"] / max(row["steps"], 1),
                   risk_mean=float(np.mean(row["risks"])),
                   risk_sem=float(np.std(row["risks"], ddof=1) / np.sqrt(len(r))) if len(r) > 1 else 0.0)
    return list(rows.values())


def changed(settings: dict) -> str:
    diff = [f"{k} = {v:g}" for k, v in settings.items() if DEFAULTS.get(k) != v]
    return ", ".join(diff) or "defaults"


def report(rows: list[dict], note: str = "") -> str:
    lines = ["# The rollout planner on validation and fresh episodes", "",
             "`python studies/planner_validation.py`. Paper's test protocol (δ = 120 s, T = 600); "
             "return: mean ± standard error over the episodes; overflows: overflowing episodes (their seeds "
             f"in validation.json). Defaults: {', '.join(f'{k} = {v:g}' for k, v in DEFAULTS.items())}.", ""]
    if note:
        lines += ["Where it ran: " + note, ""]
    titles = {"settings": f"## Settings varied one at a time (validation seeds {VALIDATION_SEED}+)",
              "horizons": f"## Look-ahead H with K = 16 on the contended plants (validation seeds {VALIDATION_SEED}+)",
              "wide": "## More futures on uncertain decisions, on the contended plants (validation seeds "
                      f"{VALIDATION_SEED}+)",
              "fresh": f"## The defaults on fresh episodes (seeds {FRESH_SEED}+)",
              "safety": "## The deadline check next to the defaults, on the contended plants",
              "risk": "## The deadline check's ε by the overflow rate it leaves, on the contended plants"}
    for part, title in titles.items():
        mine = [r for r in rows if r["part"] == part and part != "replay"]
        if not mine:
            continue
        if part in ("safety", "risk"):
            lines += safety_table(mine, title)
            continue
        lines += [title, "", "| plant | setting | episodes | planner | overflows | planner_agents | overflows | "
                  "ms CPU/step (agents) |", "|---|---|---|---|---|---|---|---|"]
        by = {}
        for r in mine:
            by.setdefault((r["plant"], changed(r["settings"])), {})[r["view"]] = r
        for (plant, setting), views in by.items():
            cells = []
            for view in VIEWS:
                r = views.get(view)
                cells += [f"{r['return_mean']:.2f} ± {r['return_sem']:.2f}", str(r["overflowing_episodes"])] if r else ["–", "–"]
            agents = views.get("planner_agents")
            episodes = max(r["episodes"] for r in views.values())
            lines.append(f"| {plant.rsplit('_', 1)[0]} | {setting} | {episodes} | " + " | ".join(cells)
                         + (f" | {agents['ms_cpu_per_step']:.2f} |" if agents else " | – |"))
        lines.append("")
    replays = [r for r in rows if r["part"] == "replay"]
    if replays:
        lines += ["## The overflowing fresh episodes replayed", "",
                  "Each fresh episode in which the defaults overflowed, run again with the planner's own seed "
                  "changed or with more futures: overflowing episodes of those replayed.", "",
                  "| plant | view | replayed | " + " | ".join(changed({**DEFAULTS, **c}) for c in REPLAYS) + " |",
                  "|---|---|---|" + "---|" * len(REPLAYS)]
        for plant in dict.fromkeys(r["plant"] for r in replays):
            for view in VIEWS:
                cells = []
                for change in REPLAYS:
                    mine = [r for r in replays if (r["plant"], r["view"]) == (plant, view)
                            and r["settings"] == {**DEFAULTS, **change}]
                    cells.append(str(sum(r["overflowing_episodes"] for r in mine)))
                replayed = sum(r["episodes"] for r in replays if (r["plant"], r["view"]) == (plant, view)
                               and r["settings"] == {**DEFAULTS, **REPLAYS[0]})
                if replayed:
                    lines.append(f"| {plant.rsplit('_', 1)[0]} | {view} | {replayed} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def safety_table(rows: list[dict], title: str) -> list[str]:
    """The safety and risk parts' rows: per plant, seed range and view, each setting's return,
    overflowing episodes, overflow risk and CPU time per decision."""
    lines = [title, "",
             "Overflow risk: the episodes' mean summed probability of an overflow at each step (± its standard "
             "error), per 1,000 episodes: an estimate of the overflowing episodes to expect in 1,000 (– where "
             "episodes ran without it). CPU per step: the mean over every step of the episodes (steps without a "
             "choice included).", "",
             "| plant | seeds | view | setting | episodes | return | overflows | overflow risk per 1,000 | "
             "ms CPU/step |", "|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: (r["plant"], r["first_seed"] >= FRESH_SEED, r["view"],
                                         changed(r["settings"]) != "defaults")):
        seeds = f"{FRESH_SEED}+ (fresh)" if r["first_seed"] >= FRESH_SEED else f"{VALIDATION_SEED}+ (validation)"
        lines.append(f"| {r['plant'].rsplit('_', 1)[0]} | {seeds} | {r['view']} | {changed(r['settings'])} | "
                     f"{r['episodes']} | {r['return_mean']:.2f} ± {r['return_sem']:.2f} | {r['overflowing_episodes']} | "
                     f"{risk_text(r)} | {r['ms_cpu_per_step']:.2f} |")
    return lines + [""]


def risk_text(row: dict) -> str:
    """A row's overflow risk per 1,000 episodes, mean ± standard error, in 3 significant digits."""
    if np.isnan(row["risk_mean"]):
        return "–"
    return f"{1e3 * row['risk_mean']:.3g} ± {1e3 * row['risk_sem']:.2g}"


def current_blocks(blocks: list[dict]) -> list[dict]:
    """The blocks that stand: a shielded block run before its view's shielded decisions last changed
    (:data:`~containergym_marl.policies.safety.DECISIONS_CHANGED`) is left out, to be run again."""
    return [b for b in blocks if b["settings"].get("safety_risk") is None
            or b.get("check", 1) >= DECISIONS_CHANGED[b["view"]]]


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--parts", nargs="+", default=list(PARTS), choices=PARTS)
    p.add_argument("--validation-episodes", type=int, default=30)
    p.add_argument("--fresh-episodes", type=int, default=200)
    p.add_argument("--wide-episodes", type=int, default=200)
    p.add_argument("--safety-episodes", type=int, default=1000)
    p.add_argument("--safety-first-seed", type=int, default=FRESH_SEED,
                   help=f"first episode seed of the safety part ({FRESH_SEED}: fresh; {VALIDATION_SEED}: validation)")
    p.add_argument("--risk-episodes", type=int, default=100)
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    p.add_argument("--out", default="results/planner_validation")
    p.add_argument("--note", default=None, help="where it ran (kept in validation.json, shown in validation.md)")
    p.add_argument("--smoke", action="store_true", help="two episodes per setting, one plant")
    p.add_argument("--report", action="store_true", help="only validation.md, from the blocks in validation.json")
    ns = p.parse_args(argv)
    episodes = {"settings": ns.validation_episodes, "horizons": ns.validation_episodes, "wide": ns.wide_episodes,
                "fresh": ns.fresh_episodes, "safety": ns.safety_episodes, "risk": ns.risk_episodes}
    for label, value in (("--safety-episodes", ns.safety_episodes), ("--safety-first-seed", ns.safety_first_seed),
                         ("--risk-episodes", ns.risk_episodes)):
        if value < 1:
            p.error(f"{label}: expected an integer >= 1, got {value}")
    global PLANTS, CONTENDED, VARIED, HORIZONS, WIDE, RISKS
    if ns.smoke:
        episodes = dict.fromkeys(episodes, 2)
        PLANTS, CONTENDED, VARIED, HORIZONS, WIDE = ("n5_m2_dt120",), ("n5_m2_dt120",), {"margin": (2.0,)}, (4,), (32,)
        RISKS = (1e-5,)
        ns.out = ns.out if ns.out != p.get_default("out") else "runs/planner_validation_smoke"
    out = Path(ns.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "validation.json"
    saved = json.loads(path.read_text()) if path.is_file() else {}
    blocks, note = saved.get("blocks", []), ns.note if ns.note is not None else saved.get("note", "")
    # fresh episodes come from the one fresh range: blocks of another (an earlier range) are dropped
    kept = [b for b in blocks if b["part"] not in ("fresh", "replay")
            or FRESH_SEED <= b["first_seed"] < FRESH_SEED + episodes["fresh"]]
    if len(kept) < len(blocks):
        print(f"{len(blocks) - len(kept)} fresh block(s) outside seeds {FRESH_SEED}+ dropped", flush=True)
    blocks = kept
    kept = current_blocks(blocks)
    if len(kept) < len(blocks):
        print(f"{len(blocks) - len(kept)} block(s) of an earlier deadline check dropped", flush=True)
    blocks = kept
    done = {b["key"] for b in blocks}
    parts = [part for part in ns.parts if part != "replay"]
    todo = [] if ns.report else [j for j in jobs_for(parts, episodes, ns.safety_first_seed) if key(*j) not in done]
    print(f"{len(todo)} block(s) to run, {len(done)} reused", flush=True)
    with worker_pool(ns.workers) as pool:
        for block in pool.map(run_block, todo):
            blocks.append(block)
            atomic_write_text(path, json.dumps({"defaults": DEFAULTS, "note": note, "blocks": blocks}) + "\n")
        if "replay" in ns.parts and not ns.report:
            replays = [j for j in replay_jobs(summarise(blocks)) if key(*j) not in done]
            print(f"{len(replays)} overflowing fresh episode replay(s) to run", flush=True)
            for block in pool.map(run_block, replays):
                blocks.append(block)
                atomic_write_text(path, json.dumps({"defaults": DEFAULTS, "note": note, "blocks": blocks}) + "\n")
    atomic_write_text(path, json.dumps({"defaults": DEFAULTS, "note": note, "blocks": blocks}) + "\n")
    rows = summarise(blocks)
    atomic_write_text(out / "validation.md", report(rows, note))
    print(report(rows, note))


if __name__ == "__main__":
    exit_on_sigterm()  # stopped by SIGTERM, the study's workers stop with it
    main()
