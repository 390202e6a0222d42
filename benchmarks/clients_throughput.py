"""Agent steps per second through the MARL libraries' environment APIs, side by side in one run.

Run from the repository root (the package installed with its ``clients`` extra)::

    python benchmarks/clients_throughput.py                 # about 1 minute on 2 cores
    python benchmarks/clients_throughput.py --json out.json # also write every number as JSON
    python benchmarks/clients_throughput.py --smoke         # tiny sizes, seconds (what the tests run)

It prints one Markdown table, for n = 5 (``n5_m2_dt120``) and n = 11 (``n11_m2_dt120``):

* **TorchRL ``PettingZooWrapper``** over one ``container_agents_v0.parallel_env`` (indexed agent
  names: one group ``"container"``, normalised state, Dict observations with masks), the way a
  TorchRL/BenchMARL user runs a PettingZoo environment (BenchMARL puts B of them in a
  ``SerialEnv``, which steps them one after the other, so B does not raise this rate);
* the plain **PettingZoo ``parallel_env``** without TorchRL, for scale;
* the batched **``ContainerAgentsTorchRLEnv``** (``containergym_marl.envs.torchrl_env``) at
  B ∈ {1, 64, 1024} simulations per TensorDict step.

An *agent step* is one step of one container agent (a plant step of n agents is n agent steps).
TorchRL paths are stepped with ``env.step_and_maybe_reset`` (autoreset, as TorchRL's collectors
do) with actions drawn in advance (each agent requests with probability 1/2), so policy time is
not counted. Ratios are against ``PettingZooWrapper`` measured in the same run. Each rate is the
median of several timed bursts after a warm-up; other processes on the machine make single
numbers noisy, ratios within one run much less so. ``torch.set_num_threads(1)``.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import platform
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

CONFIGS = {5: "n5_m2_dt120", 11: "n11_m2_dt120"}
COLUMNS = ("path", "B", "n=5 agent steps/s", "n=5 × wrapper", "n=11 agent steps/s", "n=11 × wrapper")


@dataclass
class Sizes:
    batch_sizes: tuple[int, ...]
    burst_s: float  # target duration of one timed burst
    bursts: int


FULL = Sizes(batch_sizes=(1, 64, 1024), burst_s=0.5, bursts=5)
SMOKE = Sizes(batch_sizes=(1, 4), burst_s=0.01, bursts=2)


def _rate(run: Callable[[int], None], agent_steps_per_call: int, sizes: Sizes) -> float:
    """Median agent steps per second over ``sizes.bursts`` bursts of about ``sizes.burst_s`` each."""
    run(2)  # warm-up
    calls = 1
    while True:  # calibrate the burst length
        t = time.perf_counter()
        run(calls)
        dt = time.perf_counter() - t
        if dt >= sizes.burst_s / 4 or calls >= 1 << 20:
            break
        calls *= 2
    calls = max(1, int(calls * sizes.burst_s / max(dt, 1e-9)))
    rates = []
    for _ in range(sizes.bursts):
        t = time.perf_counter()
        run(calls)
        rates.append(calls * agent_steps_per_call / (time.perf_counter() - t))
    return statistics.median(rates)


def _actions(shape: tuple[int, ...], count: int = 64) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    return [rng.integers(0, 2, shape) for _ in range(count)]


def _torchrl_loop(env, group: str, actions: list) -> Callable[[int], None]:
    """k steps of a TorchRL env with autoreset, the actions cycled from ``actions``."""
    state = {"td": env.reset(), "t": 0}

    def run(k):
        td, t = state["td"], state["t"]
        for i in range(k):
            td.set((group, "action"), actions[(t + i) % len(actions)])
            _, td = env.step_and_maybe_reset(td)
        state["td"], state["t"] = td, t + k
    return run


def _runner(path: str, n: int, batch: int) -> tuple[Callable[[int], None], int]:
    """A function running k steps of ``path`` and the agent steps one step makes."""
    import torch

    from containergym_marl import container_agents_v0

    name = CONFIGS[n]
    if path == "wrapper":
        from torchrl.envs.libs.pettingzoo import PettingZooWrapper

        env = PettingZooWrapper(container_agents_v0.parallel_env(name, agent_names="indexed", observation_mode="dict",
                                                                 state_mode="normalised"),
                                return_state=True, categorical_actions=True, seed=0)
        group = next(iter(env.group_map))
        return _torchrl_loop(env, group, [torch.from_numpy(a) for a in _actions((n,))]), n
    if path == "pettingzoo":
        env = container_agents_v0.parallel_env(name)
        env.reset(seed=0)
        acts = [dict(zip(env.possible_agents, a.tolist())) for a in _actions((n,))]
        state = {"t": 0}

        def run(k):
            t = state["t"]
            for i in range(k):
                env.step(acts[(t + i) % len(acts)])
                if not env.agents:
                    env.reset()
            state["t"] = t + k
        return run, n
    if path == "batched":
        from containergym_marl.envs.torchrl_env import GROUP, ContainerAgentsTorchRLEnv

        env = ContainerAgentsTorchRLEnv(name, num_envs=batch, seed=0)
        return _torchrl_loop(env, GROUP, [torch.from_numpy(a) for a in _actions((batch, n))]), batch * n
    raise ValueError(path)


PATHS = (
    # (key, label, batched)
    ("wrapper", "TorchRL PettingZooWrapper(parallel_env)", False),
    ("pettingzoo", "PettingZoo parallel_env, no TorchRL (for scale)", False),
    ("batched", "ContainerAgentsTorchRLEnv (batched)", True),
)


def measure(sizes: Sizes, progress: Callable[[str], None]) -> list[dict]:
    rows = []
    for key, label, batched in PATHS:
        for batch in (sizes.batch_sizes if batched else (1,)):
            row = {"path": key, "label": label, "B": batch}
            for n in CONFIGS:
                progress(f"{label}, B={batch}, n={n}")
                run, per_call = _runner(key, n, batch)
                row[f"n{n}"] = _rate(run, per_call, sizes)
            rows.append(row)
    for row in rows:
        base = next(r for r in rows if r["path"] == "wrapper")
        for n in CONFIGS:
            row[f"n{n}_ratio"] = row[f"n{n}"] / base[f"n{n}"]
    return rows


def markdown(rows: list[dict], smoke: bool) -> str:
    out = ["# Agent steps per second through the MARL libraries' APIs" + (" (smoke run)" if smoke else ""), "",
           f"{platform.processor() or platform.machine()}, Python {platform.python_version()}, "
           f"{_versions()}, {_dt.date.today().isoformat()}", "",
           "| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for r in rows:
        cells = [r["label"], str(r["B"])]
        for n in CONFIGS:
            cells += [f"{r[f'n{n}']:,.0f}", f"{r[f'n{n}_ratio']:.1f}"]
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out)


def _versions() -> str:
    import tensordict
    import torch
    import torchrl

    return f"torch {torch.__version__}, torchrl {torchrl.__version__}, tensordict {tensordict.__version__}"


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--smoke", action="store_true", help="tiny sizes (seconds); checks the table, not speed")
    parser.add_argument("--json", type=Path, help="also write the results to this JSON file")
    parser.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    args = parser.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    sizes = SMOKE if args.smoke else FULL
    progress = (lambda s: None) if args.quiet else (lambda s: print(f"... {s}", file=sys.stderr, flush=True))
    rows = measure(sizes, progress)
    print(markdown(rows, args.smoke))
    if args.json:
        args.json.write_text(json.dumps({"smoke": args.smoke, "versions": _versions(), "rows": rows}, indent=2))
    return rows


if __name__ == "__main__":
    main()
