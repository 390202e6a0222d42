"""The native PPO's tanh (2·sigmoid(2x) − 1, containergym_marl/policies/_fast_tanh.py) against
torch's own tanh kernel: CPU seconds of the same training run with each, alternating.

    python benchmarks/fast_tanh.py fast_shared_ppo --rounds 3 --samples 300000
    python benchmarks/fast_tanh.py fast_ppo --rounds 3 --samples 150000

Prints the CPU time of every run and the median ratio (torch's tanh / the sigmoid form).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
import warnings

import torch

from containergym_marl.policies import _fast_tanh
from containergym_marl.training import TrainArgs, train


def main(argv=None) -> float:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("algo", choices=("fast_ppo", "fast_shared_ppo"))
    p.add_argument("--config", default="n11_m2_dt120")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--samples", type=int, default=300_000)
    ns = p.parse_args(argv)
    fast = _fast_tanh.Tanh
    cpu: dict[str, list[float]] = {"torch": [], "sigmoid": []}
    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory() as folder:
        try:
            for r in range(ns.rounds):
                for name, cls in (("torch", torch.nn.Tanh), ("sigmoid", fast)):
                    _fast_tanh.Tanh = cls  # what the networks built from now on use
                    t = time.process_time()
                    train(TrainArgs(algo=ns.algo, config=ns.config, timesteps=ns.samples, out=f"{folder}/{name}{r}",
                                    progress_bar=False))
                    cpu[name].append(time.process_time() - t)
        finally:
            _fast_tanh.Tanh = fast
    ratio = statistics.median(a / b for a, b in zip(cpu["torch"], cpu["sigmoid"]))
    print(f"{ns.algo} on {ns.config}, {ns.samples:,} samples a run, CPU s: torch tanh "
          f"{[round(x, 2) for x in cpu['torch']]}, sigmoid form {[round(x, 2) for x in cpu['sigmoid']]}; "
          f"median ratio {ratio:.3f}")
    return ratio


if __name__ == "__main__":
    main()
