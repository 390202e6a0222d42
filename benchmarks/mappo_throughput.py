"""MAPPO's training throughput (baselines/train_mappo.py at its defaults) and the projected wall time
of the paper's budget per seed, from a short run on each config.

Run from the repository root, in the clients environment (``./run test-clients`` builds it)::

    .venv-clients/bin/python benchmarks/mappo_throughput.py                 # 4 iterations per config
    .venv-clients/bin/python benchmarks/mappo_throughput.py --iterations 6 --json out.json
    .venv-clients/bin/python benchmarks/mappo_throughput.py --smoke --iterations 2   # seconds (the tests)

For each config it trains ``--iterations`` MAPPO iterations (6000 plant steps each from 10
simulations, BenchMARL's 45 passes in minibatches of 400, MLPs 256 × 256, one torch thread) in a
temporary run directory, then reads BenchMARL's own timers of every iteration (its wall time:
collection with the policy, the run's callback that follows training returns, the 45 × 15 gradient
steps, logging; and the collection and training parts of it). The first iteration (set-up,
warm-up) is left out of the rates. A *plant step* is one step of one simulation
(BenchMARL's frame); an *agent step* is one step of one container agent (n per plant step). The
projection is the paper's budget (2M plant steps for n = 5, 5M for n >= 11, in whole iterations)
divided by the measured plant steps/s; evaluation and checkpoints add seconds. Other processes on
the machine slow every number down: the load averages before and after are printed with them,
and the CPU share (process CPU time / wall time over the run, of one core) turns the measured rate
into plant steps per CPU-second, i.e. the rate on one free core.
"""

from __future__ import annotations

import argparse
import csv
import datetime as _dt
import importlib.util
import json
import math
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _script():
    spec = importlib.util.spec_from_file_location("train_mappo", ROOT / "baselines" / "train_mappo.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def _timers(run: Path, name: str) -> list[float]:
    (path,) = run.glob(f"benchmarl/*/*/scalars/timers_{name}.csv")
    with path.open() as f:
        return [float(row[1]) for row in csv.reader(f)]


#: ``--smoke``: tiny sizes, seconds (what the tests run: the table's structure, not speed)
SMOKE = ["--n-envs", "4", "--hp", "on_policy_n_minibatch_iters=1", "num_cells=[8,8]"]


def measure(script, config: str, iterations: int, folder: Path, frames_per_batch: int = 6000,
            extra: tuple[str, ...] = ()) -> dict:
    from containergym_marl.config import load_config
    from containergym_marl.algorithms import paper_budget

    run = folder / f"mappo_{config}"
    wall0, cpu0 = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF)
    script.train(script.parse_args(script.Args, ["--config", config, "--timesteps", str(iterations * frames_per_batch),
                                                 "--frames-per-batch", str(frames_per_batch), "--out", str(run),
                                                 *extra]))
    wall, cpu1 = time.perf_counter() - wall0, resource.getrusage(resource.RUSAGE_SELF)
    share = (cpu1.ru_utime + cpu1.ru_stime - cpu0.ru_utime - cpu0.ru_stime) / wall  # of one core
    iteration, collection, training = (_timers(run, name)[1:] for name in ("iteration_time", "collection_time",
                                                                          "training_time"))
    if not iteration:
        raise SystemExit(f"{config}: need at least 2 iterations")
    n = load_config(config).n_containers
    plant_rate = frames_per_batch / (sum(iteration) / len(iteration))
    budget = paper_budget(n)
    trained = math.ceil(budget / frames_per_batch) * frames_per_batch
    return {
        "config": config, "n": n, "iterations_timed": len(iteration),
        "plant_steps_per_s": plant_rate, "agent_steps_per_s": plant_rate * n, "cpu_share": share,
        "plant_steps_per_cpu_s": plant_rate / share,
        "s_per_iteration": frames_per_batch / plant_rate,
        "collection_s_per_iteration": sum(collection) / len(collection),
        "training_s_per_iteration": sum(training) / len(training),
        "paper_budget_plant_steps": budget, "paper_budget_agent_steps": budget * n,
        "projected_hours_per_seed": trained / plant_rate / 3600,
        "projected_hours_per_seed_one_core": trained / (plant_rate / share) / 3600,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--configs", nargs="+", default=["n5_m2_dt120", "n11_m2_dt120"])
    parser.add_argument("--iterations", type=int, default=4,
                        help="MAPPO iterations per config (the first is not timed)")
    parser.add_argument("--json", default=None, help="also write the numbers here")
    parser.add_argument("--smoke", action="store_true", help="tiny sizes (seconds): checks the script, not speed")
    ns = parser.parse_args(argv)
    import torch

    script = _script()
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="mappo_throughput_") as folder:
        results = [measure(script, c, ns.iterations, Path(folder), *((400, SMOKE) if ns.smoke else ()))
                   for c in ns.configs]
    load_after = os.getloadavg()
    print(f"\nMAPPO (BenchMARL) training throughput, {_dt.datetime.now():%Y-%m-%d %H:%M}, torch {torch.__version__}, "
          f"{torch.get_num_threads()} thread(s), {os.cpu_count()} CPUs; load average before "
          f"{load_before[0]:.1f}, after {load_after[0]:.1f}\n")
    print("| config | iterations timed | plant steps/s | agent steps/s | s/iteration (collect + train) | CPU share "
          "| plant steps per CPU-s | paper budget (plant / agent steps) | projected wall time per seed (as measured "
          "/ one free core) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in results:
        print(f"| {r['config']} | {r['iterations_timed']} | {r['plant_steps_per_s']:,.0f} | "
              f"{r['agent_steps_per_s']:,.0f} | {r['s_per_iteration']:.1f} "
              f"({r['collection_s_per_iteration']:.1f} + {r['training_s_per_iteration']:.1f}) | "
              f"{r['cpu_share']:.2f} | {r['plant_steps_per_cpu_s']:,.0f} | "
              f"{r['paper_budget_plant_steps'] / 1e6:g}M / {r['paper_budget_agent_steps'] / 1e6:g}M | "
              f"{r['projected_hours_per_seed']:.1f} h / {r['projected_hours_per_seed_one_core']:.1f} h |")
    if ns.json:
        Path(ns.json).write_text(json.dumps({"smoke": ns.smoke, "load_before": load_before,
                                             "load_after": load_after, "results": results}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
