"""The container agents sharing one message each per step: screened on the published imitations (issue 38).

    python studies/shared_check_screen.py                      # dagger_checked_agents, the 3 contended rows, 5 seeds
    python studies/shared_check_screen.py --methods dagger_agents --rows n16_m2_dt120 --layers none withdraw
    python studies/shared_check_screen.py --smoke              # one row and seed, 2 episodes (a test)

**Question.** Where two PUs serve 11 or 16 containers, the imitation of the planner loses to it in two
ways that need the other agents' state (results/planner/decisions_*): requests that the arbitration
denies (each costs r_pen) and the rare step where a PU goes to a container that could have waited while
another one, due sooner, is left to overflow. The reference's deadline check (:mod:`~containergym_marl.
policies.safety`) sees every container; a container agent sees its own. This screen asks how much of
the gap one round of communication closes, with the trained networks unchanged.

**What is communicated**, and the rule every agent applies to the messages:
:mod:`containergym_marl.policies.shared_check` (the rule a ``dagger_messaging_agents`` model carries). The
layers: ``withdraw`` (step 1 alone: requests the arbitration would deny are withdrawn), ``both`` (steps 1
and 2: then the deadline check, ε and W by ``--epsilon`` and ``--window``, its choice among safe emptyings
by ``--prefer``), ``none`` (the policy as published).

**Protocol.** Each run's standing model (validated, else best; ``--runs``, by default the published
runs), ``--episodes`` validation episodes (seeds 20000 on, δ = 120 s, T = 600; never the test or fresh
ones), all at once (:func:`~containergym_marl.evaluation.batched.evaluate_batched`), beside the reference
``planner_agents_shielded`` on the same episodes; ``--fresh`` reports a setting chosen there on the
fresh episodes instead (seeds 30000 on, 200 by default, used for nothing else). The table (``--out``/screen.md, screen.json): per
method, row and layer, the mean over seeds of each seed's mean return as a share of the reference's, its
range, and the overflowing episodes of all seeds.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from containergym_marl.core.params import PlantParams
from containergym_marl.evaluation import EvalProtocol, evaluate
from containergym_marl.evaluation.batched import evaluate_batched
from containergym_marl.evaluation.protocol import FRESH, VALIDATION, policy_observation
from containergym_marl.evaluation.run_policies import evaluated_which, policy_from_run
from containergym_marl.evaluation.stats import iqm
from containergym_marl.files import atomic_write_text
from containergym_marl.methods import get_method
from containergym_marl.policies.planner import SHIELD
from containergym_marl.policies.shared_check import PREFERENCES, SharedCheck
from containergym_marl.rundir import run_name

ROWS = ("n11_m2_dt60", "n11_m2_dt120", "n16_m2_dt120")
REFERENCE = "planner_agents_shielded"
#: The published fresh evaluations, per row and policy (the reference's among them).
PUBLISHED_FRESH = Path(__file__).resolve().parents[1] / "results" / "paper_rows" / "fresh"
LAYERS = ("none", "withdraw", "both")
PREFERRED = {"nearest": "nearest to the requested ones", "policy": "the agents' policy finds most likely"}


class SharedCheckPolicy:
    """A container-agent policy with one round of messages between its agents (the module doc): its
    network unchanged, the requests of each simulation passed through ``layer`` (the package's compiled
    rule, :class:`~containergym_marl.policies.shared_check.SharedCheck`), counting what it changed."""

    view = "decentralised"
    deterministic = True

    def __init__(self, inner: Any, params: PlantParams, layer: str, epsilon: float, window: int,
                 prefer: str = "nearest"):
        if layer not in LAYERS:
            raise ValueError(f"layer: expected one of {LAYERS}, got {layer!r}")
        if prefer == "policy" and not hasattr(getattr(inner, "model", None), "decision_logits"):
            raise ValueError(f"prefer: 'policy' needs a native model's request probabilities; {inner.name!r} has none")
        self.inner, self.layer = inner, layer
        self.name = f"{inner.name}+{layer}"
        self.observation = policy_observation(inner)
        self.check = None if layer == "none" else SharedCheck(
            {"risk": epsilon, "window_steps": window, "prefer": prefer}, params, self.observation,
            deadline_check=layer == "both")
        self.changed = self.withdrawn = 0  # steps the check changed the emptyings, requests dropped

    @property
    def observation_space(self):
        return self.inner.observation_space

    def act_batch(self, observations: np.ndarray, masks: np.ndarray | None = None) -> np.ndarray:
        actions = np.asarray(self.inner.act_batch(observations, masks)).reshape(-1)
        if self.check is None:
            return actions
        log_odds = self._log_odds(observations) if self.check.uses_log_odds else None
        granted, changed = self.check(observations, actions, log_odds)
        self.changed += int(changed.sum())
        self.withdrawn += int((actions.astype(bool) & ~granted.reshape(-1)).sum())
        return granted.reshape(-1).astype(np.int64)

    def _log_odds(self, observations: np.ndarray) -> np.ndarray:
        """(N,) each agent's log-odds of requesting under the network (the second message of ``prefer='policy'``)."""
        import torch

        logits = self.inner.model.decision_logits(torch.as_tensor(observations, dtype=torch.float32))
        return (logits[:, 1] - logits[:, 0]).numpy().astype(np.float64)


def screen_run(run: Path, row: str, layers: list[str], protocol: EvalProtocol, epsilon: float,
               window: int, prefer: str = "nearest") -> dict[str, Any]:
    which = evaluated_which(run)
    inner = policy_from_run(run, which)
    if inner.view != "decentralised":
        raise ValueError(f"{run}: not a container-agent policy")
    params = PlantParams.from_config(protocol.plant(row))
    out: dict[str, Any] = {"model": which}
    for layer in layers:
        policy = SharedCheckPolicy(inner, params, layer, epsilon, window, prefer)
        result = evaluate_batched(policy, row, protocol)
        out[layer] = {"returns": [float(m.cumulative_reward) for m in result.episodes],
                      "overflowing_episodes": int(sum(bool(m.values["overflow"]) for m in result.episodes)),
                      "changed": policy.changed, "withdrawn": policy.withdrawn}
    return out


def reference_returns(row: str, protocol: EvalProtocol, cache: Path) -> list[float]:
    """``planner_agents_shielded``'s return on each of the protocol's episodes: from its published evaluation
    where that holds these episodes (the fresh ones, ``results/paper_rows/fresh``), else evaluated here (and
    cached in ``cache``)."""
    data = json.loads(cache.read_text()) if cache.is_file() else {}
    key = f"{row}|{protocol.first_seed}|{protocol.episodes}"
    if key not in data:
        published = PUBLISHED_FRESH / row / f"{REFERENCE}.json"
        episodes = json.loads(published.read_text())["episodes"] if published.is_file() else []
        if [e["seed"] for e in episodes[:protocol.episodes]] == list(protocol.seeds):
            data[key] = [float(e["cumulative_reward"]) for e in episodes[:protocol.episodes]]
        else:
            result = evaluate(get_method(REFERENCE).controller(), row, protocol)
            data[key] = [float(m.cumulative_reward) for m in result.episodes]
        cache.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(cache, json.dumps(data, indent=1) + "\n")
    return data[key]


def table(data: dict[str, Any]) -> str:
    kind = "fresh" if data["first_seed"] == FRESH.first_seed else "validation"
    lines = [f"# One message per agent and step: the published networks with a shared check ({kind} episodes)", "",
             f"Generated by `python studies/shared_check_screen.py` from `{data['runs']}`: each run's standing model "
             f"(its network unchanged), {data['episodes']} {kind} episodes (seeds {data['first_seed']}+, δ = 120 s, "
             f"T = 600), with each layer (the study's docstring; check: ε = {data['epsilon']:g}, W = {data['window']}, "
             f"choosing the safe emptyings {PREFERRED[data.get('prefer', 'nearest')]}). "
             "Share: the mean over seeds of each seed's mean return as a share of `planner_agents_shielded`'s on the "
             "same episodes; IQM share: the interquartile mean over seeds of those means as a share of it (the bar's "
             "statistic); overflowing: episodes of all seeds; changed: steps where the check changed the "
             "emptyings; withdrawn: requests the layer dropped, denied ones and those the check replaced (all seeds).", "",
             "| method | row | reference | layer | seeds | return | share | IQM share | min – max share "
             "| overflowing episodes | changed | withdrawn |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for method, rows in data["results"].items():
        for row, seeds in rows.items():
            reference = float(np.mean(data["reference"][row]))
            for layer in data["layers"]:
                means = [float(np.mean(s[layer]["returns"])) for s in seeds.values()]
                shares = [m / reference for m in means]
                over = sum(s[layer]["overflowing_episodes"] for s in seeds.values())
                lines.append(f"| `{method}` | {row} | {reference:.2f} | {layer} | {len(means)} | {np.mean(means):.2f} | "
                             f"{100 * np.mean(shares):.1f} % | {100 * iqm(means) / reference:.1f} % | "
                             f"{100 * min(shares):.1f} – {100 * max(shares):.1f} % | "
                             f"{over} of {len(means) * data['episodes']} | "
                             f"{sum(s[layer]['changed'] for s in seeds.values())} | "
                             f"{sum(s[layer]['withdrawn'] for s in seeds.values())} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--methods", nargs="+", default=["dagger_checked_agents"])
    p.add_argument("--rows", nargs="+", default=list(ROWS))
    p.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3, 4, 5])
    p.add_argument("--layers", nargs="+", choices=LAYERS, default=list(LAYERS))
    p.add_argument("--epsilon", type=float, default=SHIELD["safety_risk"], help="the check's ε (the reference's)")
    p.add_argument("--window", type=int, default=SHIELD["safety_horizon_steps"], help="the check's W (steps)")
    p.add_argument("--prefer", choices=PREFERENCES, default="nearest",
                   help="the check's choice among safe emptyings: nearest to the requests, or the policy's most "
                        "likely (each agent's message then carries its log-odds of requesting)")
    p.add_argument("--episodes", type=int, default=None,
                   help="validation episodes (seeds 20000 on; default 100); with --fresh, fresh ones (default 200)")
    p.add_argument("--fresh", action="store_true",
                   help="report a setting chosen on validation episodes on the fresh ones (seeds 30000 on, used for "
                        "nothing else) instead")
    p.add_argument("--runs", default="results/paper_rows/runs", help="the run directories <method>_<row>_s<seed>")
    p.add_argument("--out", default="results/shared_check")
    p.add_argument("--smoke", action="store_true", help="one row and seed, 2 episodes")
    ns = p.parse_args(argv)
    if ns.smoke:
        ns.rows, ns.seeds, ns.episodes = ["n11_m2_dt120"], [1], 2
    first = FRESH if ns.fresh else VALIDATION
    ns.episodes = first.episodes if ns.episodes is None and ns.fresh else 100 if ns.episodes is None else ns.episodes
    if ns.episodes < 1:
        p.error(f"--episodes: expected a positive number of episodes, got {ns.episodes}")
    if not 0 < ns.epsilon < 1:
        p.error(f"--epsilon: expected a probability in (0, 1), got {ns.epsilon}")
    if ns.window < 1:
        p.error(f"--window: expected a number of steps >= 1, got {ns.window}")
    runs, out = Path(ns.runs), Path(ns.out)
    missing = [run_name(m, r, s) for m in ns.methods for r in ns.rows for s in ns.seeds
               if not (runs / run_name(m, r, s) / "args.json").is_file()]
    if missing:
        p.error(f"--runs {runs}: no run {missing[0]}" + (f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""))
    protocol = EvalProtocol(episodes=ns.episodes, first_seed=first.first_seed)
    settings = {"runs": str(runs), "episodes": ns.episodes, "first_seed": protocol.first_seed, "layers": ns.layers,
                "epsilon": ns.epsilon, "window": ns.window, "prefer": ns.prefer}
    earlier = json.loads((out / "screen.json").read_text()) if (out / "screen.json").is_file() else {}
    out.mkdir(parents=True, exist_ok=True)
    # a screen stopped part way resumes, and one on other rows or methods adds to it: the runs screened
    # with the same settings are kept
    data = {**settings, "reference": {}, "results": earlier.get("results", {}) if all(
        earlier.get(k) == v for k, v in settings.items()) else {}}
    for method in ns.methods:
        for row in ns.rows:
            data["reference"][row] = reference_returns(row, protocol, out / "reference.json")
            for seed in ns.seeds:
                done = data["results"].setdefault(method, {}).setdefault(row, {})
                if f"s{seed}" not in done:
                    done[f"s{seed}"] = screen_run(runs / run_name(method, row, seed), row, ns.layers, protocol,
                                                  ns.epsilon, ns.window, ns.prefer)
                    atomic_write_text(out / "screen.json", json.dumps(data, indent=1) + "\n")
                got = done[f"s{seed}"]
                print(method, row, f"s{seed}", got["model"], " ".join(
                    f"{k} {np.mean(v['returns']):.2f}/{v['overflowing_episodes']}" for k, v in got.items()
                    if k != "model"), flush=True)
    for rows in data["results"].values():  # the rows an earlier invocation screened too
        for row in rows:
            data["reference"][row] = reference_returns(row, protocol, out / "reference.json")
    atomic_write_text(out / "screen.json", json.dumps(data, indent=1) + "\n")
    atomic_write_text(out / "screen.md", table(data))
    print(table(data))


if __name__ == "__main__":
    main()
