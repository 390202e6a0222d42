"""Which of a run's models should stand for its seed: the best (of the highest 100-episode training
return), the final, or the validated one (its sample-efficiency curve's pick, on 30 validation episodes)?

    python studies/model_choice.py results/paper_rows/runs/fast_shared_ppo_n*   # -> results/model_choice
    python studies/model_choice.py RUN ... --episodes 100 --out DIR

Each run's three models are evaluated on the same validation episodes, seeds 20100+ (``--episodes``,
100 by default): none of the 30 (20000-20029) its curve picked the validated model on, none a test
or fresh episode. Per method and row: the mean over runs of each model's mean return, and the overflowing
episodes summed over runs. Resumable (``<out>/model_choice.json`` keeps every run's numbers, keyed
by the three models' hashes); writes ``model_choice.md``. One torch thread, batched evaluations.
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
FIRST_SEED = 20100  # after the curve's 30 validation episodes (20000-20029) and the table's 100 (20000-20099)
MODELS = ("validated", "best", "final")


def evaluate_run(run: Path, episodes: int) -> dict:
    import torch

    from containergym_marl.core.dynamics import DEFAULT_ARBITRATION
    from containergym_marl.evaluation import EvalProtocol
    from containergym_marl.evaluation.batched import evaluate_batched
    from containergym_marl.evaluation.run_policies import policy_from_run
    from containergym_marl.rundir import run_args

    torch.set_num_threads(1)
    saved = run_args(run)
    protocol = EvalProtocol(episodes=episodes, first_seed=FIRST_SEED)
    from containergym_marl.algorithms import get_algorithm

    method = get_algorithm(saved["algo"]).method_name(saved.get("reward_mode"))
    entry = {"method": method, "row": saved["config"], "seed": saved["seed"], "episodes": episodes,
             "first_seed": FIRST_SEED}
    for which in MODELS:
        result = evaluate_batched(policy_from_run(run, which), saved["config"], protocol,
                                  arbitration=saved.get("arbitration", DEFAULT_ARBITRATION))
        entry[which] = {"return_mean": float(result.returns.mean()),
                        "overflowing_episodes": int(sum(bool(e.overflow) for e in result.episodes))}
    return entry


def model_hashes(run: Path) -> dict[str, str]:
    from containergym_marl.algorithms import get_algorithm
    from containergym_marl.rundir import run_args

    spec = get_algorithm(run_args(run)["algo"])
    return {which: hashlib.sha256((run / spec.model_file(which)).read_bytes()).hexdigest() for which in MODELS}


def report(entries: dict) -> str:
    from containergym_marl.config.loading import config_sort_key

    rows: dict[tuple[str, str], list[dict]] = {}
    for entry in entries.values():
        rows.setdefault((entry["method"], entry["row"]), []).append(entry)
    episodes = {e["episodes"] for e in entries.values()}
    lines = ["# Which model stands for a run's seed", "",
             f"`python studies/model_choice.py`: each run's validated, best and final model on the same "
             f"{'/'.join(map(str, sorted(episodes)))} validation episodes (seeds {FIRST_SEED}+: not the 30 its curve "
             "picked the validated model on). Mean over runs of each model's mean return; overflowing episodes "
             "summed over runs.", "",
             "| method | row | runs | validated | best (training return) | final |", "|---|---|---|---|---|---|"]
    for method, row in sorted(rows, key=lambda key: (key[0], config_sort_key(key[1]))):
        runs = rows[method, row]
        cells = [f"{sum(r[w]['return_mean'] for r in runs) / len(runs):.2f} "
                 f"({sum(r[w]['overflowing_episodes'] for r in runs)} overflowing)" for w in MODELS]
        lines.append(f"| {method} | {row} | {len(runs)} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="finished run directories with a validated model")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--out", type=Path, default=REPO / "results" / "model_choice")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes: expected at least 1, got {args.episodes}")
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
        missing = [spec.model_file(w) for w in MODELS if not (run / spec.model_file(w)).is_file()]
        if missing:
            parser.error(f"{str(run)!r} has no {', '.join(missing)} (a finished run whose curve picked a model)")
    from containergym_marl.files import atomic_write_text

    args.out.mkdir(parents=True, exist_ok=True)
    store = args.out / "model_choice.json"
    entries = json.loads(store.read_text()) if store.is_file() else {}
    for run in sorted(args.runs):
        hashes = model_hashes(run)
        old = entries.get(run.name)
        if old is not None and old.get("models") == hashes and old.get("episodes") == args.episodes:
            continue
        entries[run.name] = {**evaluate_run(run, args.episodes), "models": hashes}
        atomic_write_text(store, json.dumps(entries, indent=1, sort_keys=True) + "\n")
        print(run.name, {w: entries[run.name][w] for w in MODELS}, flush=True)
    text = report(entries)
    atomic_write_text(args.out / "model_choice.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
