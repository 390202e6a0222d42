"""Two torch threads per run or one: which trains more samples per wall-second on a machine's cores?

A sweep fills C cores either with C runs of one torch thread each (the default) or with C/2 runs of
two threads each. This script times both on this machine, alternately, with whole ``train``
processes of the native PPO (start-up included, as a sweep pays it)::

    python benchmarks/threads.py                        # all cores, fast_shared_ppo on n11_m2_dt120
    python benchmarks/threads.py --cores 16 --rounds 3  # on a 16-core machine
    python benchmarks/threads.py --smoke                # seconds: checks the script, not the machine

For each layout it prints the samples trained per wall-second by all its runs together and per
CPU-second (the children's user + system time), the median over rounds, and the ratio of the two
layouts measured one after the other in each round. Nothing else should run meanwhile: the question
is how the cores are best shared, so a busy machine answers a different one.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_layout(runs: int, threads: int, args, scratch: Path, tag: str) -> dict:
    """``runs`` train processes of ``threads`` torch threads each, started together; wall and CPU
    seconds until the last one ends."""
    cpu0, wall0 = _children_cpu_s(), time.perf_counter()
    processes = []
    for k in range(runs):
        env = {**os.environ, "OMP_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads)}
        command = [sys.executable, "-m", "containergym_marl.cli", "train", "--algo", args.algo,
                   "--config", args.config, "--seed", str(k + 1), "--timesteps", str(args.timesteps),
                   "--out", str(scratch / f"{tag}-{k}"), "--torch-threads", str(threads), "--no-progress",
                   "--checkpoint-every", str(args.timesteps)]
        processes.append(subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE))
    for p in processes:
        _, err = p.communicate()
        if p.returncode:
            raise SystemExit(f"a train run failed ({p.returncode}):\n{err.decode()[-2000:]}")
    wall, cpu = time.perf_counter() - wall0, _children_cpu_s() - cpu0
    samples = runs * args.timesteps
    return {"runs": runs, "threads": threads, "wall_s": wall, "cpu_s": cpu,
            "samples_per_wall_s": samples / wall, "samples_per_cpu_s": samples / cpu}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cores", type=int, default=os.cpu_count() or 1, help="cores to fill (an even number)")
    p.add_argument("--algo", default="fast_shared_ppo")
    p.add_argument("--config", default="n11_m2_dt120")
    p.add_argument("--timesteps", type=int, default=300_000, help="samples per run")
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--json", type=Path, help="also write every measurement to this file")
    p.add_argument("--smoke", action="store_true", help="2 cores, 8192 samples, 1 round")
    args = p.parse_args(argv)
    if args.smoke:
        args.cores, args.timesteps, args.rounds = 2, 8192, 1
    if args.cores < 2 or args.cores % 2:
        p.error(f"--cores: expected an even number >= 2, got {args.cores}")
    layouts = {"one thread": (args.cores, 1), "two threads": (args.cores // 2, 2)}
    measured: dict[str, list[dict]] = {name: [] for name in layouts}
    with tempfile.TemporaryDirectory(prefix="threads-") as scratch:
        for r in range(args.rounds):
            order = list(layouts) if r % 2 == 0 else list(reversed(layouts))  # neither always goes first
            for name in order:
                runs, threads = layouts[name]
                measured[name].append(run_layout(runs, threads, args, Path(scratch), f"r{r}-{threads}"))
                print(f"round {r + 1}: {name}: {measured[name][-1]['samples_per_wall_s']:,.0f} samples/s",
                      file=sys.stderr)
    print(f"# Torch threads per run: {args.algo} on {args.config}, {args.cores} cores, "
          f"{args.timesteps:,} samples per run, {args.rounds} round(s)\n")
    print("| layout | runs at once | samples / s (wall, all runs) | samples / CPU-s |")
    print("|---|---|---|---|")
    for name, (runs, threads) in layouts.items():
        rows = measured[name]
        print(f"| {name} per run | {runs} | {statistics.median(m['samples_per_wall_s'] for m in rows):,.0f} "
              f"| {statistics.median(m['samples_per_cpu_s'] for m in rows):,.0f} |")
    ratios = [a["samples_per_wall_s"] / b["samples_per_wall_s"]
              for a, b in zip(measured["two threads"], measured["one thread"])]
    verdict = "two threads per run" if statistics.median(ratios) > 1.0 else "one thread per run"
    print(f"\nTwo threads ÷ one thread, samples per wall-second, by round: "
          f"{', '.join(f'{x:.2f}' for x in ratios)}; the faster layout here: **{verdict}**.")
    if args.json:
        args.json.write_text(json.dumps({"args": {k: v for k, v in vars(args).items() if k != "json"},
                                         "measured": measured, "ratios": ratios}, indent=1, default=str))


if __name__ == "__main__":
    main()
