"""Training throughput of SB3's PPO at the paper's settings against the native PPO at its settings files,
measured side by side in one run: samples per CPU-second and per wall-second.

    python benchmarks/trainer_throughput.py                      # n11_m2_dt120, 3 rounds, ~3 minutes
    python benchmarks/trainer_throughput.py --rounds 1 --smoke   # tiny bursts, seconds (the smoke test)

Each burst is one ``containergym_marl.training.train`` call (the package's training path: vector env,
rollouts, updates, metrics rows, best model and checkpoints) with one torch thread, in this
process, for a fixed number of rollouts: ``ppo`` against ``fast_ppo`` (centralised) and
``shared_ppo`` against ``fast_shared_ppo`` (one policy shared by the container agents). The four
bursts alternate within each round, and each ratio is the median over rounds of the ratio of two
bursts taken one after the other, so a busy machine slows both sides alike. CPU time is this
process's (``time.process_time``, all its threads), which leaves out time spent waiting for a core.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
import warnings
from pathlib import Path

from containergym_marl.config import load_config
from containergym_marl.config.hyperparams import method_settings
from containergym_marl.training import TrainArgs, train
from containergym_marl.algorithms import get_algorithm, rollout_steps
from containergym_marl.training.fast_ppo import PPOArgs

PAIRS = (("ppo", "fast_ppo"), ("shared_ppo", "fast_shared_ppo"))


def rollout_samples(algo: str, n_containers: int) -> int:
    """Samples per rollout of ``algo`` as ``train`` runs it: SB3's paper settings, or the native PPO's
    shape from its method's settings file."""
    spec = get_algorithm(algo)
    if not spec.native:
        slots = spec.num_slots(n_containers, spec.default_sims(n_containers))
        return slots * rollout_steps(slots)
    settings = PPOArgs.from_hyperparams(method_settings(spec.method_name(None)))
    return spec.num_slots(n_containers, spec.default_sims(n_containers, settings=settings)) * settings.n_steps


def burst(algo: str, config: str, rollouts: int, folder: Path, k: int) -> dict:
    samples = rollouts * rollout_samples(algo, load_config(config).n_containers)
    cpu, wall = time.process_time(), time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run = train(TrainArgs(algo=algo, config=config, timesteps=samples, out=str(folder / f"{algo}_{k}"),
                              progress_bar=False, torch_threads=1))
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    trained = json.loads((run / "run.json").read_text())["timesteps"]
    return {"algo": algo, "samples": trained, "cpu_s": cpu, "wall_s": wall,
            "samples_per_cpu_s": trained / cpu, "samples_per_s": trained / wall}


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", default="n11_m2_dt120")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--sb3-rollouts", type=int, default=3, help="rollouts per SB3 burst (about 6k samples each)")
    p.add_argument("--fast-samples", type=int, default=400_000, help="samples per native burst (whole rollouts)")
    p.add_argument("--smoke", action="store_true", help="one rollout per burst: seconds, numbers meaningless")
    p.add_argument("--json", default=None)
    ns = p.parse_args(argv)
    n = load_config(ns.config).n_containers
    plan = {}
    for sb3, fast in PAIRS:
        plan[sb3] = 1 if ns.smoke else ns.sb3_rollouts
        plan[fast] = 1 if ns.smoke else max(1, ns.fast_samples // rollout_samples(fast, n))
    results: dict[str, list[dict]] = {a: [] for a in plan}
    with tempfile.TemporaryDirectory() as tmp:
        for algo in plan:  # warm-up: compiled kernels, torch
            burst(algo, ns.config, 1, Path(tmp) / "warm", 0)
        for k in range(ns.rounds):
            for algo, rollouts in plan.items():
                results[algo].append(burst(algo, ns.config, rollouts, Path(tmp), k))
    lines = [f"# Training throughput on {ns.config}, one torch thread, {ns.rounds} round(s)", "",
             "| algorithm | settings | samples per burst | samples / CPU-s | samples / s (wall) |",
             "|---|---|---|---|---|"]
    summary = {"config": ns.config, "rounds": ns.rounds, "algorithms": {}, "ratios": {}}
    for algo, bursts in results.items():
        cpu_rate = statistics.median(b["samples_per_cpu_s"] for b in bursts)
        wall_rate = statistics.median(b["samples_per_s"] for b in bursts)
        summary["algorithms"][algo] = {"samples_per_cpu_s": cpu_rate, "samples_per_s": wall_rate, "bursts": bursts}
        settings = "native settings file" if get_algorithm(algo).native else "paper (SB3)"
        lines.append(f"| {algo} | {settings} | {bursts[0]['samples']:,} | {cpu_rate:,.0f} | {wall_rate:,.0f} |")
    lines += ["", "| native / SB3 | samples per CPU-second | samples per second (wall) |", "|---|---|---|"]
    for sb3, fast in PAIRS:
        cpu = statistics.median(f["samples_per_cpu_s"] / s["samples_per_cpu_s"]
                                for s, f in zip(results[sb3], results[fast]))
        wall = statistics.median(f["samples_per_s"] / s["samples_per_s"] for s, f in zip(results[sb3], results[fast]))
        summary["ratios"][f"{fast}/{sb3}"] = {"cpu": cpu, "wall": wall}
        lines.append(f"| {fast} / {sb3} | {cpu:.1f}x | {wall:.1f}x |")
    budget = 5_000_000
    for _, fast in PAIRS:
        minutes = budget / summary["algorithms"][fast]["samples_per_cpu_s"] / 60
        lines.append(f"\n{fast}: a 5M-sample run on {ns.config} takes about {minutes:.1f} CPU-minutes at this rate.")
    print("\n".join(lines))
    if ns.json:
        Path(ns.json).write_text(json.dumps(summary, indent=1) + "\n")
    return summary


if __name__ == "__main__":
    main()
