"""The paper-style results table (Table 1) regenerated from small evaluation files.

    python -m containergym_marl.evaluation.table results/n5_m2_dt120/evaluations/n5_m2_dt120

reads the evaluation files that ``containergym-marl compare`` writes (``<method>_s<seed>.json`` for
each training seed of a learned method, ``<method>.json`` for the rule-based controllers) and prints,
per method, the best and the median policy over seeds (ranked by mean test return), each as
mean ± std over the test episodes, next to the paper's Table 1 row for the same configuration.
"""

from __future__ import annotations

import json
import re
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: The paper's Table 1 (PPO, TRPO, DQN; best and median of 15 seeds; mean ± std over 15 episodes).
PAPER_TABLE_1 = {
    "n5_m2_dt60": {"ppo": ((38.55, 1.87), (29.94, 8.42)), "trpo": ((37.35, 7.13), (4.93, 4.90)), "dqn": ((29.50, 3.43), (1.57, 0.93))},
    "n5_m2_dt120": {"ppo": ((51.43, 3.00), (49.81, 1.56)), "trpo": ((38.33, 8.36), (16.86, 2.78)), "dqn": ((42.96, 2.80), (7.90, 4.72))},
    "n5_m5_dt60": {"ppo": ((37.54, 1.50), (30.64, 2.44)), "trpo": ((33.62, 7.76), (7.36, 4.40)), "dqn": ((23.98, 13.17), (1.96, 1.28))},
    "n5_m5_dt120": {"ppo": ((50.42, 2.57), (47.23, 1.89)), "trpo": ((47.36, 2.07), (5.39, 4.38)), "dqn": ((43.26, 3.73), (8.56, 4.12))},
    "n11_m2_dt60": {"ppo": ((31.01, 8.62), (23.25, 16.79)), "trpo": ((26.62, 18.94), (4.26, 3.81)), "dqn": ((42.63, 21.73), (11.84, 10.33))},
    "n11_m2_dt120": {"ppo": ((54.30, 8.48), (49.58, 13.54)), "trpo": ((45.78, 18.42), (32.08, 18.04)), "dqn": ((72.19, 16.20), (24.07, 13.68))},
    "n11_m11_dt60": {"ppo": ((27.87, 8.89), (17.57, 13.99)), "trpo": ((15.66, 10.65), (4.90, 2.68)), "dqn": ((28.32, 22.42), (8.49, 4.92))},
    "n11_m11_dt120": {"ppo": ((47.75, 10.78), (42.37, 13.25)), "trpo": ((50.55, 11.08), (34.29, 16.00)), "dqn": ((29.06, 13.10), (13.16, 8.32))},
}


@dataclass
class MethodRow:
    method: str
    seeds: list[int]
    best: tuple[float, float, int]  # mean, std, seed
    median: tuple[float, float, int]
    overflow_rate_best: float
    view: str  # "centralised" or "decentralised", as the evaluation files record it


_NAME = re.compile(r"^(?P<method>.+?)(?:_s(?P<seed>\d+))?$")


def _load_evaluations(directory: Path) -> dict[str, list[tuple[int, dict]]]:
    by_method: dict[str, list[tuple[int, dict]]] = {}
    for path in sorted(directory.glob("*.json")):
        m = _NAME.match(path.stem)
        seed = int(m["seed"]) if m["seed"] is not None else -1
        by_method.setdefault(m["method"], []).append((seed, json.loads(path.read_text())))
    return by_method


def method_rows(results: str | Path) -> list[MethodRow]:
    rows = []
    for method, runs in _load_evaluations(Path(results)).items():
        stats = []
        for seed, data in runs:
            r = np.array([e["cumulative_reward"] for e in data["episodes"]])
            stats.append((float(r.mean()), float(r.std()), seed, data["summary"]["overflow_rate"]))
        stats.sort(key=lambda s: s[0], reverse=True)
        best = stats[0]
        median = stats[(len(stats) - 1) // 2]  # the lower median for an even count
        rows.append(MethodRow(method, sorted(s[2] for s in stats), best[:3], median[:3], best[3], _view(method, runs[0][1])))
    return rows


def _view(method: str, evaluation: dict) -> str:
    """The view an evaluation file records; for files without one, the registry's."""
    if "view" in evaluation:
        return evaluation["view"]
    from containergym_marl.training.algorithms import view_of

    return view_of(method)


def markdown_table(results: str | Path, config: str | None = None) -> str:
    results = Path(results)
    config = config or results.name  # compare writes evaluations/<config>/
    lines = [
        f"Test cumulative reward on `{config}` (paper protocol: δ = 120 s, T = 600, 15 episodes; "
        "mean ± std over episodes of the best and the median policy over training seeds)",
        "",
        "| method | view | seeds | best | median | overflow rate (best) |",
        "|---|---|---|---|---|---|",
    ]
    for row in method_rows(results):
        seeds = "–" if row.seeds == [-1] else str(len(row.seeds))
        lines.append(
            f"| {row.method} | {row.view} | {seeds} | "
            f"{row.best[0]:.2f} ± {row.best[1]:.2f} | {row.median[0]:.2f} ± {row.median[1]:.2f} | "
            f"{row.overflow_rate_best:.2f} |"
        )
    for algo, (best, median) in PAPER_TABLE_1.get(config, {}).items():
        lines.append(f"| paper {algo.upper()} (15 seeds) | centralised | 15 | {best[0]:.2f} ± {best[1]:.2f} | "
                     f"{median[0]:.2f} ± {median[1]:.2f} | – |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        raise SystemExit("usage: python -m containergym_marl.evaluation.table EVALUATIONS_DIR")
    print(markdown_table(argv[0]))


if __name__ == "__main__":
    main()
