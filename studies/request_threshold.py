"""Would the imitation's container agents score higher if they requested a PU below even odds?

    python studies/request_threshold.py results/paper_rows/runs/dagger_agents_*   # -> results/request_threshold
    python studies/request_threshold.py RUN ... --thresholds 0.5 0.3 --episodes 60 --out DIR
    python studies/request_threshold.py results/paper_rows/runs/dagger_agents_* --fresh 0.3   # the chosen τ, reported

**Question.** A student of the planner sees one container; the planner that labels it sees the plant. Where
similar-looking agent states get different labels, the network learns the share of them in which the planner
requests, and greedy acting (its most likely action) waits wherever that share is below 1/2, although a
missed request near an overflow costs far more than an early one. A request threshold τ < 1/2
(:attr:`~containergym_marl.policies.actor_critic.ActorCritic.request_threshold`) requests wherever the
probability is above τ.

**Protocol.** Each run's standing model (its validated model, else its best), unchanged but for τ, on the
same ``--episodes`` validation episodes (δ = 120 s, T = 600, seeds 20100+: none of the 30 the run's curve
picked its model on, no test or fresh episode), for every ``--thresholds`` τ (0.5: the most likely action,
the model as trained); the reference, ``planner_agents_shielded``, on the same episodes of every row. Per
method and row: the mean over runs of each τ's mean return as a share of the reference's, and the
overflowing episodes summed over runs. The models were trained acting by their most likely action: a student
trained acting with τ (``--hp request_threshold=τ`` on ``dagger_agents``) collects other states.

**Reporting** (``--fresh τ``, once τ is chosen on the validation episodes): every run's standing model with τ
and as trained on the fresh episodes (200, seeds 30000+, used for nothing else; the published results' episodes),
beside the reference's published fresh return on them (``results/paper_rows/fresh``). Per method and row: the
IQM over seeds of their mean fresh returns as a share of the reference's and the share of all episodes that
overflow, the issue's bar being at least 97 % and at most 0.5 % (``studies/reference_shares.py``). Writes
``<out>/fresh.json`` and ``fresh.md``.

``--own-check RISK:LEAD`` puts the agents' own deadline check (:func:`~containergym_marl.policies.safety.own_deadline_due`)
in every policy evaluated with a threshold (a model trained with a check keeps its own otherwise): the two
decision rules together.

Resumable (``<out>/thresholds.json`` keeps every run's numbers by its model's hash, the reference's by row and
episodes); writes ``thresholds.md``. One torch thread, batched evaluations (the planner's one by one).
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
FIRST_SEED = 20100  # after the curves' 30 validation episodes (20000-20029)
THRESHOLDS = (0.5, 0.4, 0.3, 0.2, 0.1)
REFERENCE = "planner_agents_shielded"
#: The issue's bar for a learned decentralised method (studies/reference_shares.py's): at least this share of the
#: reference's fresh mean, at most this share of the episodes overflowing.
BAR_SHARE, BAR_OVERFLOW = 0.97, 0.005


def _protocol(episodes: int):
    from containergym_marl.evaluation import EvalProtocol

    return EvalProtocol(episodes=episodes, first_seed=FIRST_SEED)


def _standing(run: Path, protocol) -> tuple:
    """The run's args, its standing model's policy (one torch thread) and the entry naming them."""
    import torch

    from containergym_marl.algorithms import get_algorithm
    from containergym_marl.evaluation.run_policies import evaluated_which, policy_from_run
    from containergym_marl.rundir import run_args

    torch.set_num_threads(1)
    saved, which = run_args(run), evaluated_which(run)
    entry = {"method": get_algorithm(saved["algo"]).method_name(saved.get("reward_mode")), "row": saved["config"],
             "seed": saved["seed"], "model": which, "episodes": protocol.episodes, "first_seed": protocol.first_seed}
    return saved, policy_from_run(run, which), entry


def _score(policy, saved: dict, protocol) -> dict:
    """The policy's batched evaluation on the run's plant: its mean return and overflowing episodes."""
    from containergym_marl.core.dynamics import DEFAULT_ARBITRATION
    from containergym_marl.evaluation.batched import evaluate_batched

    result = evaluate_batched(policy, saved["config"], protocol,
                              arbitration=saved.get("arbitration", DEFAULT_ARBITRATION))
    return {"return_mean": float(result.returns.mean()),
            "overflowing_episodes": int(sum(bool(e.overflow) for e in result.episodes))}


def evaluate_run(run: Path, thresholds: list[float], episodes: int, own_check: dict | None = None) -> dict:
    """The run's standing model with each threshold (and ``own_check``, where given) on the validation episodes."""
    protocol = _protocol(episodes)
    saved, policy, entry = _standing(run, protocol)
    if own_check is not None:
        policy.model.own_check = own_check
    scores = {}
    for tau in thresholds:
        policy.model.request_threshold = None if tau == 0.5 else tau
        scores[str(tau)] = _score(policy, saved, protocol)
    return {**entry, "own_check": own_check, "thresholds": scores}


def evaluate_reference(row: str, episodes: int) -> dict:
    import numpy as np

    from containergym_marl.evaluation import evaluate
    from containergym_marl.methods import get_method

    result = evaluate(get_method(REFERENCE).controller(), row, _protocol(episodes))
    return {"return_mean": float(np.mean(result.returns)), "episodes": episodes, "first_seed": FIRST_SEED,
            "overflowing_episodes": int(sum(bool(m.overflow) for m in result.episodes))}


def evaluate_fresh(run: Path, tau: float, own_check: dict | None = None) -> dict:
    """The run's standing model on the fresh episodes as trained and with ``tau`` (and ``own_check``, where
    given): each one's mean return and overflowing episodes."""
    from containergym_marl.evaluation.protocol import FRESH

    saved, policy, entry = _standing(run, FRESH)
    trained = (policy.model.request_threshold, policy.model.own_check)
    entry["own_check"] = own_check
    for label, (threshold, check) in (("as_trained", trained),
                                      ("threshold", (None if tau == 0.5 else tau, own_check or trained[1]))):
        policy.model.request_threshold, policy.model.own_check = threshold, check
        entry[label] = _score(policy, saved, FRESH)
    return entry


def _by_method_row(entries: dict) -> list[tuple[str, str, list[dict]]]:
    from containergym_marl.config.loading import config_sort_key

    groups: dict[tuple[str, str], list[dict]] = {}
    for entry in entries.values():
        groups.setdefault((entry["method"], entry["row"]), []).append(entry)
    return [(method, row, groups[method, row])
            for method, row in sorted(groups, key=lambda key: (key[0], config_sort_key(key[1])))]


def fresh_report(entries: dict, tau: float, results: Path, own_check: dict | None = None) -> tuple[list[dict], str]:
    """Per (method, row): the IQM share of the reference's fresh mean and the overflow rate, as trained and
    with ``tau``; and its Markdown table."""
    from containergym_marl.evaluation.stats import iqm

    summary = []
    for method, row, runs in _by_method_row(entries):
        reference = json.loads((results / "fresh" / row / f"{REFERENCE}.json").read_text())["summary"]["return_mean"]
        cells = {}
        for label in ("as_trained", "threshold"):
            share = iqm([r[label]["return_mean"] for r in runs]) / reference
            rate = sum(r[label]["overflowing_episodes"] for r in runs) / sum(r["episodes"] for r in runs)
            cells[label] = {"iqm_share": share, "overflow_rate": rate, "meets": share >= BAR_SHARE and rate <= BAR_OVERFLOW}
        summary.append({"method": method, "row": row, "seeds": len(runs), "reference_fresh_mean": reference, **cells})
    lines = [f"Fresh episodes (200 per seed, seeds 30000–30199). Per method and row: the IQM over seeds of their mean "
             f"fresh returns as a share of `{REFERENCE}`'s, and the share of all their episodes that overflow, each "
             f"seed's standing model as trained and with τ = {tau} (chosen on validation episodes). ✓: at least 97 % "
             "and at most 0.5 % overflowing.", "",
             "| method | row | seeds | reference | as trained | overflow | τ = " + str(tau) + _with(own_check)
             + " | overflow |",
             "|---|---|---|---|---|---|---|---|"]
    for s in summary:
        a, t = s["as_trained"], s["threshold"]
        lines.append(f"| {s['method']} | {s['row']} | {s['seeds']} | {s['reference_fresh_mean']:.2f} | "
                     f"{100 * a['iqm_share']:.1f} %{' ✓' if a['meets'] else ''} | {100 * a['overflow_rate']:.1f} % | "
                     f"{100 * t['iqm_share']:.1f} %{' ✓' if t['meets'] else ''} | {100 * t['overflow_rate']:.1f} % |")
    return summary, "\n".join(lines) + "\n"


def _with(own_check: dict | None) -> str:
    return "" if own_check is None else f", own check {own_check['risk']:g}:{own_check['lead_steps']}"


def parse_own_check(text: str) -> dict:
    """``RISK:LEAD`` (e.g. ``1e-4:1``) as an own check (a ValueError naming ``--own-check`` otherwise)."""
    from containergym_marl.policies.safety import check_own_check

    try:
        risk, lead = text.split(":")
        value = {"risk": float(risk), "lead_steps": int(lead)}
    except ValueError:
        raise ValueError(f"--own-check: expected RISK:LEAD (e.g. 1e-4:1), got {text!r}") from None
    return check_own_check(value, "--own-check")


def model_hash(run: Path) -> str:
    from containergym_marl.algorithms import get_algorithm
    from containergym_marl.evaluation.run_policies import evaluated_which
    from containergym_marl.rundir import run_args

    spec = get_algorithm(run_args(run)["algo"])
    return hashlib.sha256((run / spec.model_file(evaluated_which(run))).read_bytes()).hexdigest()


def summarise(entries: dict, references: dict) -> list[dict]:
    """Per (method, row): each threshold's mean return over runs, its share of the reference's, and the
    overflowing episodes summed over runs."""
    out = []
    for method, row, runs in _by_method_row(entries):
        reference = references[row]["return_mean"]
        cells = {}
        for tau in sorted({t for r in runs for t in r["thresholds"]}, key=float, reverse=True):
            values = [r["thresholds"][tau] for r in runs if tau in r["thresholds"]]
            mean = sum(v["return_mean"] for v in values) / len(values)
            cells[tau] = {"runs": len(values), "return_mean": mean, "share": mean / reference,
                          "overflowing_episodes": sum(v["overflowing_episodes"] for v in values)}
        out.append({"method": method, "row": row, "runs": len(runs), "episodes": runs[0]["episodes"],
                    "reference": references[row], "thresholds": cells})
    return out


def report(summary: list[dict], own_check: dict | None = None) -> str:
    taus = sorted({t for s in summary for t in s["thresholds"]}, key=float, reverse=True)
    checked = "" if own_check is None else \
        f"; with the agents' own check {own_check['risk']:g}:{own_check['lead_steps']} in every policy"
    lines = ["# A request threshold for the imitation's greedy agents", "",
             f"`python studies/request_threshold.py RUN ...`: each run's standing model on the same validation "
             f"episodes (seeds {FIRST_SEED}+), requesting wherever its probability of a request is above τ (0.5: its "
             f"most likely action, as trained){checked}. Per method and row: the mean over runs of each τ's mean return as a "
             f"share of `{REFERENCE}`'s on the same episodes, and the overflowing episodes summed over runs.", "",
             "| method | row | runs × episodes | reference | " + " | ".join(f"τ = {t}" for t in taus) + " |",
             "|---|---|---|---|" + "---|" * len(taus)]
    for s in summary:
        cells = []
        for tau in taus:
            c = s["thresholds"].get(tau)
            cells.append("–" if c is None else f"{100 * c['share']:.1f} % ({c['overflowing_episodes']})")
        lines.append(f"| {s['method']} | {s['row']} | {s['runs']} × {s['episodes']} | "
                     f"{s['reference']['return_mean']:.2f} ({s['reference']['overflowing_episodes']}) | "
                     + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="finished run directories of shared native-PPO models")
    parser.add_argument("--thresholds", nargs="+", type=float, default=list(THRESHOLDS))
    parser.add_argument("--episodes", type=int, default=60)
    parser.add_argument("--out", type=Path, default=REPO / "results" / "request_threshold")
    parser.add_argument("--fresh", type=float, metavar="TAU",
                        help="report TAU (chosen on the validation episodes) on the fresh episodes instead")
    parser.add_argument("--own-check", metavar="RISK:LEAD",
                        help="evaluate every threshold with this own deadline check (e.g. 1e-4:1) in the policy")
    parser.add_argument("--results", type=Path, default=REPO / "results" / "paper_rows",
                        help="the published results whose fresh/ holds the reference's fresh evaluations")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes: expected at least 1, got {args.episodes}")
    from containergym_marl.policies.actor_critic import check_request_threshold

    try:
        args.own_check = None if args.own_check is None else parse_own_check(args.own_check)
    except ValueError as exc:
        parser.error(str(exc))
    for tau, name in [(t, "--thresholds") for t in args.thresholds] + [(args.fresh, "--fresh")]:
        try:
            check_request_threshold(tau, name)
        except ValueError as exc:
            parser.error(str(exc))
    from containergym_marl.algorithms import get_algorithm
    from containergym_marl.rundir import check_distinct_names, run_args

    try:  # every refusal before anything is evaluated or written
        check_distinct_names(args.runs)
    except ValueError as exc:
        parser.error(str(exc))
    for run in args.runs:
        try:
            spec = get_algorithm(run_args(run)["algo"])
        except Exception as exc:  # noqa: BLE001 - any unreadable run is named
            parser.error(f"{str(run)!r} is not a run directory ({exc})")
        if spec.view != "decentralised" or spec.model_suffix != ".pt":
            parser.error(f"{str(run)!r}: a {spec.name} run; the threshold is a rule of the package's shared "
                         f"container-agent models (the native PPO's and the imitations')")
    from containergym_marl.files import atomic_write_text

    if args.fresh is not None:
        rows = {run_args(run)["config"] for run in args.runs}
        missing = [row for row in sorted(rows) if not (args.results / "fresh" / row / f"{REFERENCE}.json").is_file()]
        if missing:
            parser.error(f"--results: no fresh evaluation of {REFERENCE} on {missing} under {args.results}")
    args.out.mkdir(parents=True, exist_ok=True)
    if args.fresh is not None:
        return report_fresh(args, atomic_write_text)
    store = args.out / "thresholds.json"
    known = json.loads(store.read_text()) if store.is_file() else {}
    entries, references = known.get("runs", {}), known.get("references", {})
    wanted = [str(t) for t in args.thresholds]
    for run in sorted(args.runs):
        sha, old = model_hash(run), entries.get(run.name)
        if old is not None and old.get("model_sha256") == sha and old["episodes"] == args.episodes \
                and set(wanted) <= set(old["thresholds"]) and old.get("own_check") == args.own_check:
            continue
        entries[run.name] = {**evaluate_run(run, args.thresholds, args.episodes, args.own_check), "model_sha256": sha}
        atomic_write_text(store, json.dumps({"runs": entries, "references": references}, indent=1, sort_keys=True)
                          + "\n")
        print(run.name, entries[run.name]["thresholds"], flush=True)
    for row in sorted({e["row"] for e in entries.values()}):
        if references.get(row, {}).get("episodes") != args.episodes:
            references[row] = evaluate_reference(row, args.episodes)
            atomic_write_text(store, json.dumps({"runs": entries, "references": references}, indent=1,
                                                sort_keys=True) + "\n")
            print(REFERENCE, row, references[row], flush=True)
    summary = summarise({k: e for k, e in entries.items() if e["episodes"] == args.episodes}, references)
    atomic_write_text(args.out / "summary.json", json.dumps(summary, indent=1, sort_keys=True) + "\n")
    text = report(summary, args.own_check)
    atomic_write_text(args.out / "thresholds.md", text)
    print(text)
    return 0


def report_fresh(args, atomic_write_text) -> int:
    store = args.out / "fresh.json"
    known = json.loads(store.read_text()) if store.is_file() else {}
    same = (known.get("tau"), known.get("own_check")) == (args.fresh, args.own_check)
    entries = known.get("runs", {}) if same else {}
    for run in sorted(args.runs):
        sha, old = model_hash(run), entries.get(run.name)
        if old is not None and old.get("model_sha256") == sha:
            continue
        entries[run.name] = {**evaluate_fresh(run, args.fresh, args.own_check), "model_sha256": sha}
        atomic_write_text(store, json.dumps({"tau": args.fresh, "own_check": args.own_check, "runs": entries},
                                            indent=1, sort_keys=True) + "\n")
        print(run.name, entries[run.name]["as_trained"], entries[run.name]["threshold"], flush=True)
    summary, text = fresh_report(entries, args.fresh, args.results, args.own_check)
    atomic_write_text(args.out / "fresh_summary.json",
                      json.dumps({"tau": args.fresh, "own_check": args.own_check, "rows": summary}, indent=1) + "\n")
    atomic_write_text(args.out / "fresh.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
