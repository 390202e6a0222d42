"""Copy what a comparison produced into the repository: small files of every run, every evaluation,
the best and median model of each (row, method), and the table regenerated from those files.

    python baselines/publish_results.py --runs RUNS --compare OUT --to results/paper_rows

RUNS is compare's ``--runs`` folder, OUT its ``--out`` folder. For every finished run (a readable
``final_model.zip``) it copies ``args.json``, ``run.json``, ``config.toml`` and ``metrics.csv`` to
``<to>/runs/<run>/``; every evaluation file of OUT to ``<to>/evaluations/<config>/``; and, for each
(config, method) with at least ``--min-seeds`` evaluated seeds, the best model (``best_model.zip``, the policy the
evaluation used) of its best and of its median seed by mean test return (the table's rule) to
``<to>/models/<config>/<method>_{best,median}.zip`` with ``<method>.json`` naming the seeds and
their returns. Finally ``<to>/table.{md,csv,json}`` is rebuilt from the evaluation files alone
(``python -m containergym_marl.evaluation.table <to> --out <to>`` does the same). Rerunning it is
safe: files are replaced atomically, nothing else is touched.
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

from containergym_marl.compare import PAIRS
from containergym_marl.evaluation import table as tables
from containergym_marl.files import atomic_write, atomic_write_text
from containergym_marl.training.runs import run_status

SMALL_FILES = ("args.json", "run.json", "config.toml", "metrics.csv")


def _copy(src: Path, dst: Path) -> None:
    atomic_write(dst, lambda tmp: shutil.copyfile(src, tmp))


def publish(runs: Path, compare_out: Path, to: Path, min_seeds: int = 3) -> dict:
    done = {"runs": [], "evaluations": 0, "models": []}
    for run in sorted(p for p in runs.iterdir() if p.is_dir() and not p.name.startswith(".")):
        if run_status(run) != "finished":
            continue
        for name in SMALL_FILES:
            if (run / name).is_file():
                _copy(run / name, to / "runs" / run.name / name)
        done["runs"].append(run.name)
    for path in sorted((compare_out / "evaluations").glob("*/*.json")):
        _copy(path, to / "evaluations" / path.parent.name / path.name)
        done["evaluations"] += 1
    for group in tables.load_evaluations(to / "evaluations"):
        if len(group.seeds) < min_seeds:
            continue  # a rule-based controller (nothing to ship), or a row still training
        runs_of = [runs / f"{group.method}_{group.config}_s{seed}" for seed in group.seeds]
        if not all(run_status(r) == "finished" for r in runs_of):
            continue
        means = group.seed_means
        picked = {"best": group.best, "median": group.median}
        folder = to / "models" / group.config
        for which, i in picked.items():
            model = runs_of[i] / "best_model.zip"
            if not model.is_file():  # no training episode finished: the evaluation used the final model
                model = runs_of[i] / "final_model.zip"
            _copy(model, folder / f"{group.method}_{which}.zip")
        atomic_write_text(folder / f"{group.method}.json", json.dumps({
            "config": group.config, "method": group.method, "view": group.view,
            "best_seed": group.seeds[picked["best"]], "median_seed": group.seeds[picked["median"]],
            "seed_mean_returns": {str(s): float(m) for s, m in zip(group.seeds, means)},
            "files": {which: f"{group.method}_{which}.zip" for which in picked},
        }, indent=2) + "\n")
        done["models"].append(f"{group.config}/{group.method}")
    table = tables.build_table(tables.load_evaluations(to / "evaluations"), PAIRS)
    table.write(to, {"source": "baselines/publish_results.py"})
    return done


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--runs", required=True, type=Path, help="compare's --runs folder")
    parser.add_argument("--compare", required=True, type=Path, help="compare's --out folder")
    parser.add_argument("--to", default=Path("results/paper_rows"), type=Path, help="destination in the repository")
    parser.add_argument("--min-seeds", type=int, default=3, help="ship models of a (row, method) from this many seeds on")
    ns = parser.parse_args(argv)
    done = publish(ns.runs, ns.compare, ns.to, ns.min_seeds)
    size = sum(p.stat().st_size for p in (ns.to / "models").rglob("*.zip")) if (ns.to / "models").exists() else 0
    print(f"published {len(done['runs'])} finished run(s), {done['evaluations']} evaluation(s), models of "
          f"{len(done['models'])} (row, method) pair(s) ({size / 1e6:.1f} MB of models) to {ns.to}/")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
