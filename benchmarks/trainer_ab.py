"""The native trainer of this checkout against another checkout's, side by side: whole training runs in
fresh processes, alternated, the same algorithm, plant, settings and seed in both.

    python benchmarks/trainer_ab.py --other /path/to/other/checkout            # fast_shared_ppo, n11_m2_dt120
    python benchmarks/trainer_ab.py --other ../old --algo fast_ppo --samples 300000 --rounds 4
    python benchmarks/trainer_ab.py --other ../old --algo dagger_agents --samples 200000 --rounds 2
    python benchmarks/trainer_ab.py --other . --samples 20000 --rounds 1        # the smoke test: seconds

Each run is one ``containergym_marl.training.train`` call (one torch thread) in a new Python process
whose ``PYTHONPATH`` is the checkout; it reports the CPU seconds of the call alone
(``time.process_time``: start-up and imports left out), its wall time (what waiting for the disk
adds: the run's files are written where a real run writes them, ``--dir``, by default a temporary
folder on the system's disk), the calls of ``os.fsync`` and the wall time spent in them, and a hash
of the final model, so the two sides are also shown to train the same numbers (or not). The runs alternate (this, other, this, …)
so a busy machine slows both alike; the ratio is the median over rounds of other / this.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from containergym_marl.algorithms import ALGORITHMS, get_algorithm

REPO = Path(__file__).resolve().parents[1]
CHILD = r"""
import hashlib, json, sys, time, warnings
warnings.simplefilter("ignore")
import torch
from containergym_marl.training import TrainArgs, train
algo, config, samples, out, hp = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4], json.loads(sys.argv[5])
import os
flushes = [0, 0.0]  # calls of os.fsync, wall seconds in them (waiting for the disk)
real_fsync = os.fsync
def timed_fsync(fd):
    t = time.perf_counter()
    real_fsync(fd)
    flushes[0] += 1
    flushes[1] += time.perf_counter() - t
os.fsync = timed_fsync
start, wall = time.process_time(), time.perf_counter()
run = train(TrainArgs(algo=algo, config=config, seed=1, timesteps=samples, out=out, progress_bar=False,
                      torch_threads=1, hyperparams=hp))
cpu, wall = time.process_time() - start, time.perf_counter() - wall
model = torch.load(run / "final_model.pt", weights_only=True)
digest = hashlib.sha256()
def walk(x):
    if isinstance(x, torch.Tensor):
        digest.update(x.numpy().tobytes())
    elif isinstance(x, dict):
        for k in sorted(x):
            walk(x[k])
walk(model)
trained = json.loads((run / "run.json").read_text())["timesteps"]
print(json.dumps({"cpu_s": cpu, "wall_s": wall, "fsyncs": flushes[0], "fsync_wall_s": flushes[1], "samples": trained, "model_sha256": digest.hexdigest()}))
"""


def one_run(checkout: Path, algo: str, config: str, samples: int, hp: dict, out: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    proc = subprocess.run([sys.executable, "-c", CHILD, algo, config, str(samples), str(out), json.dumps(hp)],
                          env=env, capture_output=True, text=True, check=True, cwd=checkout)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--other", required=True, type=Path, help="the other checkout (a git worktree of another commit)")
    p.add_argument("--algo", default="fast_shared_ppo",
                   choices=[a for a in ALGORITHMS if get_algorithm(a).native])  # the package's own trainers
    p.add_argument("--config", default="n11_m2_dt120")
    p.add_argument("--samples", type=int, default=200_000)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--hp", default="{}", help="settings as JSON, the same for both sides (default: this checkout's "
                                               "settings file, passed to both)")
    p.add_argument("--json", default=None, help="also write the measurements here")
    p.add_argument("--dir", default=None, help="where the runs write (default: a temporary folder)")
    ns = p.parse_args(argv)
    hp = json.loads(ns.hp)
    if not hp:
        from containergym_marl.config import load_config
        from containergym_marl.config.hyperparams import method_settings

        hp = method_settings(ns.algo, load_config(ns.config).n_containers)
    sides = {"this": REPO, "other": ns.other.resolve()}
    results: dict[str, list[dict]] = {name: [] for name in sides}
    with tempfile.TemporaryDirectory(dir=ns.dir) as tmp:
        for r in range(ns.rounds):
            for name, checkout in sides.items():
                results[name].append(one_run(checkout, ns.algo, ns.config, ns.samples, hp, Path(tmp) / f"{name}_{r}"))
    ratios = [o["cpu_s"] / t["cpu_s"] for t, o in zip(results["this"], results["other"])]
    wall_ratios = [o["wall_s"] / t["wall_s"] for t, o in zip(results["this"], results["other"])]
    same = {r["model_sha256"] for side in results.values() for r in side}
    lines = [f"# {ns.algo} on {ns.config}, {ns.samples:,} samples per run, {ns.rounds} round(s), settings {hp}", "",
             "| checkout | CPU s per run (each round) | samples / CPU-s (median) | wall s per run (each round) | "
             "flushes to disk per run: calls, wall s (median) |", "|---|---|---|---|---|"]
    for name, runs in results.items():
        rate = statistics.median(r["samples"] / r["cpu_s"] for r in runs)
        each = ", ".join(format(r["cpu_s"], ".1f") for r in runs)
        walls = ", ".join(format(r["wall_s"], ".1f") for r in runs)
        calls = statistics.median(r["fsyncs"] for r in runs)
        waited = statistics.median(r["fsync_wall_s"] for r in runs)
        lines.append(f"| {name} ({sides[name]}) | {each} | {rate:,.0f} | {walls} | {calls:.0f}, {waited:.2f} |")
    each = ", ".join(format(x, ".2f") for x in ratios)
    each_wall = ", ".join(format(x, ".2f") for x in wall_ratios)
    lines += ["", f"other / this CPU time: {statistics.median(ratios):.2f}x (median of {each}); wall time: "
              f"{statistics.median(wall_ratios):.2f}x (median of {each_wall}); final models "
              + ("identical" if len(same) == 1 else "differ") + " on both sides"]
    print("\n".join(lines))
    report = {"algo": ns.algo, "config": ns.config, "samples": ns.samples, "hyperparams": hp,
              "runs": {k: v for k, v in results.items()}, "ratio_median": statistics.median(ratios),
              "wall_ratio_median": statistics.median(wall_ratios),
              "identical_models": len(same) == 1}
    if ns.json:
        Path(ns.json).write_text(json.dumps(report, indent=1) + "\n")
    return report


if __name__ == "__main__":
    main()
