"""The rollout planner on every row, with the paper's test protocol, against both rule-based controllers.

    python studies/planner_rows.py            # every row: default setting, strong setting on m = 2 rows
    python studies/planner_rows.py --smoke    # one row, two short episodes (to runs/planner_smoke)

For each row it evaluates ``rule_based``, ``rule_based_agents``, the planner through both views at the
default setting (``planner``: centralised, ``planner_agents``: container agents) and, on the
``--strong-rows``, at a stronger setting (more futures K, longer horizon H). Protocol: δ = 120 s,
T = 600, 15 episodes, seeds 10000–10014 (the planner's own generator is seeded from each episode's
seed, so every number is reproducible; the decision times are not, they depend on the machine's load,
which is recorded). Decision time per step is measured around ``policy.act`` (wall clock and CPU time
of this process), after a warm-up episode that loads the compiled kernels.

Writes ``--out``/rows.json (every evaluation: settings, summary, per-episode returns, timings) after
each evaluation, and ``--out``/rows.md (the table). Evaluations already in rows.json with the same
settings and protocol are reused, so an interrupted run continues where it stopped (``--fresh``
redoes everything).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from containergym_marl.config import load_config
from containergym_marl.orchestration.compare_args import PAPER_ROWS as TABLE_ROWS
from containergym_marl.core.params import PlantParams
from containergym_marl.evaluation import PAPER, EvalProtocol, evaluate
from containergym_marl.policies import PlannerAgents, RolloutPlanner, RuleBasedAgents, RuleBasedController

ROWS = TABLE_ROWS
#: the rows of the paper's Table 1 (n16_m2_dt120 is the package's own)
PAPER_ROWS = tuple(r for r in ROWS if not r.startswith("n16_"))
#: the planner every other method's return is divided by in the table's "share" column
REFERENCE = ("planner_agents", "default")


@dataclass
class Args:
    rows: list[str] = field(default_factory=lambda: list(ROWS))
    episodes: int = PAPER.episodes
    episode_length_steps: int = PAPER.episode_length_steps
    futures: int = 16  # K of the default setting (the planner's own default)
    horizon: int = 8  # H of the default setting
    strong_futures: int = 64
    strong_horizon: int = 24
    strong_rows: list[str] = field(default_factory=lambda: [r for r in ROWS if "_m2_" in r])
    out: str = "results/planner"
    fresh: bool = False
    smoke: bool = False


class Timed:
    """A policy whose ``act`` calls are timed (wall clock and process CPU time)."""

    def __init__(self, policy):
        self.policy, self.name, self.view = policy, policy.name, policy.view
        self.wall: list[float] = []
        self.cpu: list[float] = []

    def reset(self, seed=None):
        if hasattr(self.policy, "reset"):
            self.policy.reset(seed=seed)

    def act(self, observation, env):
        w, c = time.perf_counter(), time.process_time()
        action = self.policy.act(observation, env)
        self.cpu.append(time.process_time() - c)
        self.wall.append(time.perf_counter() - w)
        return action


def _policies(row: str, args: Args):
    """(method, setting, policy factory) of one row."""
    params = PlantParams.from_config(load_config(row))
    yield "rule_based", "-", lambda: RuleBasedController(params)
    yield "rule_based_agents", "-", lambda: RuleBasedAgents(params)
    settings = [("default", args.futures, args.horizon)]
    if row in args.strong_rows:
        settings.append(("strong", args.strong_futures, args.strong_horizon))
    for setting, k, h in settings:
        for cls in (RolloutPlanner, PlannerAgents):
            yield cls.name, setting, lambda cls=cls, k=k, h=h: cls(params, futures=k, horizon=h)


def _settings(policy) -> dict:
    keys = ("futures", "horizon", "base", "margin", "min_reward", "overflow_penalty", "seed")
    return {k: getattr(policy, k) for k in keys if hasattr(policy, k)}


def measure(row: str, method: str, setting: str, make, protocol: EvalProtocol) -> dict:
    policy = make()
    if isinstance(policy, RolloutPlanner):  # warm-up: load the compiled kernels before timing
        evaluate(make(), row, EvalProtocol(episodes=1, episode_length_steps=20, first_seed=1), keep_records=False)
    timed = Timed(policy)
    start = time.perf_counter()
    result = evaluate(timed, row, protocol, keep_records=False)
    s = result.summary()
    wall, cpu = np.array(timed.wall) * 1e3, np.array(timed.cpu) * 1e3
    return {
        "row": row, "method": method, "view": policy.view, "setting": setting, "policy": _settings(policy),
        "protocol": asdict(protocol),
        "return_mean": s["return_mean"], "return_std": s["return_std"],
        "overflowing_episodes": int(sum(e.overflow for e in result.episodes)),
        "overflow_rate": s["overflow_rate"], "good_emptying_share": s["good_emptying_share"],
        "denied_requests_mean": s["denied_requests_mean"], "emptyings_mean": s["emptyings_mean"],
        "decision_ms_mean": float(wall.mean()), "decision_ms_p99": float(np.quantile(wall, 0.99)),
        "decision_ms_max": float(wall.max()), "decision_cpu_ms_mean": float(cpu.mean()),
        "planned_share": (policy.planned / policy.decisions) if isinstance(policy, RolloutPlanner) else None,
        "returns": [e.cumulative_reward for e in result.episodes],
        "evaluation_s": time.perf_counter() - start,
        "load_average": os.getloadavg(),
    }


def _key(entry: dict) -> tuple:
    return (entry["row"], entry["method"], entry["setting"], json.dumps(entry["policy"], sort_keys=True),
            json.dumps(entry["protocol"], sort_keys=True))


def markdown(entries: list[dict], args: Args) -> str:
    by = {(e["row"], e["method"], e["setting"]): e for e in entries}
    lines = [
        "# The rollout planner on every row",
        "",
        f"Paper test protocol: δ = 120 s, T = {args.episode_length_steps}, {args.episodes} episodes, seeds "
        f"{PAPER.first_seed}–{PAPER.first_seed + args.episodes - 1}. Default setting: K = {args.futures} futures, "
        f"H = {args.horizon} steps; strong: K = {args.strong_futures}, H = {args.strong_horizon} (on "
        f"{', '.join(args.strong_rows)}). Base policy: rule-based agents with `fullest` arbitration "
        "(requests only what free PUs can grant). `planner` acts through the centralised view (one emptying "
        "per step), `planner_agents` through the container agents' view.",
        "",
        "Return: mean ± std over the test episodes. Share: the return as a share of `planner_agents` "
        "(default) on the same row. Overflows: overflowing test episodes. r ≥ 0.75: share of emptying actions "
        "earning at least 0.75. ms/step: wall-clock decision time per step, mean / 99th percentile (CPU time "
        "mean in brackets), measured on a 2-core machine shared with other jobs (load average in rows.json).",
        "",
        "Under the test protocol every `_dt60` row is the same plant as its `_dt120` row (the configs differ only "
        "in the training δ, which the protocol replaces by 120 s; their PlantParams are equal), so their "
        "returns coincide; both are measured, and only the decision times differ.",
        "",
        "| row | method | setting | return | share | overflows | r ≥ 0.75 | denied | ms/step |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in args.rows:
        ref = by.get((row, *REFERENCE))
        for e in [e for e in entries if e["row"] == row]:
            share = f"{e['return_mean'] / ref['return_mean']:.3f}" if ref and ref["return_mean"] else "–"
            timing = (f"{e['decision_ms_mean']:.1f} / {e['decision_ms_p99']:.1f} ({e['decision_cpu_ms_mean']:.1f})"
                      if e["method"].startswith("planner") else f"{e['decision_ms_mean']:.2f}")
            setting = e["setting"] if e["setting"] == "-" else (
                f"{e['setting']} (K={e['policy']['futures']}, H={e['policy']['horizon']})")
            lines.append(f"| {row} | {e['method']} | {setting} | {e['return_mean']:.2f} ± {e['return_std']:.2f} | "
                         f"{share} | {e['overflowing_episodes']}/{len(e['returns'])} | {e['good_emptying_share']:.3f} | "
                         f"{e['denied_requests_mean']:.1f} | {timing} |")
    lines += ["", "## Targets", ""] + _targets(entries, args) + [""]
    return "\n".join(lines)


def _targets(entries: list[dict], args: Args) -> list[str]:
    out = []
    for row in args.rows:
        rule = max((e["return_mean"] for e in entries if e["row"] == row and e["method"].startswith("rule")),
                   default=None)
        for e in entries:
            if e["row"] != row or not e["method"].startswith("planner") or e["setting"] != "default":
                continue
            beats = rule is not None and e["return_mean"] >= rule
            safe = e["overflowing_episodes"] == 0
            paper = " (paper row)" if row in PAPER_ROWS else ""
            paired = []  # the same test episodes (seeds) for every method: per-episode differences
            for r in (x for x in entries if x["row"] == row and x["method"].startswith("rule")):
                d = np.array(e["returns"]) - np.array(r["returns"])
                se = d.std(ddof=1) / np.sqrt(d.size) if d.size > 1 else float("nan")
                paired.append(f"{r['method']} {d.mean():+.2f} ± {se:.2f}, {int((d > 0).sum())}/{d.size} episodes")
            out.append(f"- {row}{paper}, {e['method']}: {'≥' if beats else '<'} both rule-based controllers "
                       f"({e['return_mean']:.2f} vs best rule {rule:.2f}; paired difference ± s.e. and episodes "
                       f"won against {'; '.join(paired)}); "
                       f"{'no' if safe else e['overflowing_episodes']} overflowing episodes"
                       + (f"; {e['decision_ms_mean']:.1f} ms per step (≤ 50 ms: {'yes' if e['decision_ms_mean'] <= 50 else 'no'})"
                          if row.startswith("n11_") else ""))
    return out


def main(args: Args) -> None:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "rows.json"
    old = [] if args.fresh or not path.exists() else json.loads(path.read_text())["evaluations"]
    done = {_key(e): e for e in old}
    protocol = EvalProtocol(episodes=args.episodes, episode_length_steps=args.episode_length_steps)
    entries = []
    for row in args.rows:
        for method, setting, make in _policies(row, args):
            probe = {"row": row, "method": method, "setting": setting, "policy": _settings(make()),
                     "protocol": asdict(protocol)}
            entry = done.get(_key(probe))
            if entry is None:
                entry = measure(row, method, setting, make, protocol)
            entries.append(entry)
            print(f"{row:14s} {method:18s} {setting:8s} return {entry['return_mean']:7.2f} ± {entry['return_std']:5.2f}"
                  f"  overflows {entry['overflowing_episodes']:2d}  r>=0.75 {entry['good_emptying_share']:.3f}"
                  f"  denied {entry['denied_requests_mean']:5.1f}  {entry['decision_ms_mean']:6.2f} ms/step", flush=True)
            kept = entries + [e for k, e in done.items() if k not in {_key(x) for x in entries}]
            meta = {"machine": platform.platform(), "cpus": os.cpu_count(), "args": asdict(args)}
            path.write_text(json.dumps({"meta": meta, "evaluations": kept}, indent=1) + "\n")
    (out / "rows.md").write_text(markdown(entries, args))
    print(f"wrote {path} and {out / 'rows.md'}")


def parse(argv=None) -> Args:
    d = Args()
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rows", nargs="+", default=d.rows, choices=ROWS)
    p.add_argument("--episodes", type=int, default=d.episodes)
    p.add_argument("--futures", type=int, default=d.futures)
    p.add_argument("--horizon", type=int, default=d.horizon)
    p.add_argument("--strong-futures", type=int, default=d.strong_futures)
    p.add_argument("--strong-horizon", type=int, default=d.strong_horizon)
    p.add_argument("--strong-rows", nargs="*", default=d.strong_rows, choices=ROWS)
    p.add_argument("--out", default=d.out)
    p.add_argument("--fresh", action="store_true", help="redo every evaluation")
    p.add_argument("--smoke", action="store_true", help="n5_m2_dt120, 2 episodes of 30 steps, tiny settings")
    ns = p.parse_args(argv)
    args = Args(**{k: v for k, v in vars(ns).items()})
    if args.smoke:  # written apart from the results unless --out says otherwise
        args = Args(rows=["n5_m2_dt120"], episodes=2, episode_length_steps=30, futures=4, horizon=6,
                    strong_futures=8, strong_horizon=8, strong_rows=["n5_m2_dt120"], fresh=True, smoke=True,
                    out="runs/planner_smoke" if args.out == d.out else args.out)
    return args


if __name__ == "__main__":
    main(parse())
