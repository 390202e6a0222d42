"""Start-up cost of a fresh process: the first step of each arbitration rule, cold and warm cache.

    python benchmarks/startup.py [--rules fullest random ...] [--compare-with PATH] [--compare-label NAME]

Numba caches the compiled step on disk (``cache=True``), so only the first process on a machine
should pay the compilation. For each rule this script runs the same child process twice on one
empty, private ``NUMBA_CACHE_DIR`` (a temporary folder; the package's ``__pycache__`` is not
touched): *cold* (nothing cached) and then *warm* (what the cold one cached). Each child imports
the package, steps one small batch with the rule (``dynamics.step``), and reports the wall and CPU
seconds of the import and of that first step, numba's cache hits and misses of the rule's kernel
(``step_batch.stats``), and how many cache files the process added. A last pair steps every rule
in one process. A warm process should compile nothing: no miss, no new file, a first step of
milliseconds. ``--compare-with`` measures another checkout (``PYTHONPATH=PATH``) the same way, in
the same run.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RULES = ("fullest", "random", "index", "best_reward")


def child(rules: list[str]) -> dict:
    """Run in the fresh process: import, one step per rule, numbers as JSON."""
    cache = Path(os.environ["NUMBA_CACHE_DIR"])
    files_before = sum(1 for p in cache.rglob("*") if p.is_file())
    wall, cpu = time.perf_counter(), time.process_time()
    import numpy as np

    from containergym_marl.config import load_config
    from containergym_marl.core import dynamics
    from containergym_marl.core.params import PlantParams

    params = PlantParams.from_config(load_config("n11_m2_dt120"))
    result = {"import_wall": time.perf_counter() - wall, "import_cpu": time.process_time() - cpu,
              "step_wall": 0.0, "step_cpu": 0.0, "hits": 0, "misses": 0}
    rng = np.random.default_rng(0)
    bsz, n = 8, params.n_containers
    state = dynamics.reset_state(params, rng.random((bsz, n)))
    for rule in rules:
        wall, cpu = time.perf_counter(), time.process_time()
        dynamics.step(state, rng.random((bsz, n)) < 0.5, params, rng.standard_normal((bsz, n)),
                      rng.random((bsz, n)), arbitration=rule)
        result["step_wall"] += time.perf_counter() - wall
        result["step_cpu"] += time.process_time() - cpu
        stats = dynamics.get_rule(rule).step_batch.stats
        result["hits"] += sum(stats.cache_hits.values())
        result["misses"] += sum(stats.cache_misses.values())
    result["new_files"] = sum(1 for p in cache.rglob("*") if p.is_file()) - files_before
    return result


def run_child(package: str, rules: list[str], cache_dir: str) -> dict:
    env = {**os.environ, "PYTHONPATH": package, "NUMBA_CACHE_DIR": cache_dir}
    started = time.perf_counter()
    out = subprocess.run([sys.executable, __file__, "--child", *rules], env=env, cwd=package, check=True,
                         capture_output=True, text=True).stdout
    result = json.loads(out.splitlines()[-1])
    result["process_wall"] = time.perf_counter() - started
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rules", nargs="+", default=list(RULES))
    parser.add_argument("--compare-with", metavar="PATH", help="another checkout of this package")
    parser.add_argument("--compare-label", default="before")
    parser.add_argument("--child", nargs="*", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child is not None:
        print(json.dumps(child(args.child)))
        return

    packages = {"ours": str(Path(__file__).resolve().parents[1])}
    if args.compare_with:
        packages[args.compare_label] = str(Path(args.compare_with).resolve())
    cases = [[rule] for rule in args.rules] + ([list(args.rules)] if len(args.rules) > 1 else [])
    print("| code | rules | cache | process wall s | import wall s | first step wall s | first step CPU s "
          "| kernel cache hits / misses | new cache files |")
    print("|---|---|---|---|---|---|---|---|---|")
    for label, package in packages.items():
        for rules in cases:
            with tempfile.TemporaryDirectory(prefix="numba-startup-") as cache_dir:
                for cache in ("cold", "warm"):
                    r = run_child(package, rules, cache_dir)
                    name = rules[0] if len(rules) == 1 else "all"
                    print(f"| {label} | {name} | {cache} | {r['process_wall']:.2f} | {r['import_wall']:.2f} "
                          f"| {r['step_wall']:.3f} | {r['step_cpu']:.3f} | {r['hits']} / {r['misses']} "
                          f"| {r['new_files']} |", flush=True)


if __name__ == "__main__":
    main()
