"""Centralised TRPO (sb3-contrib): one controller picks which container to empty.

Paper settings: gamma = 0.99, 6144 samples per update (n_steps = 6144 / n_envs), SB3 defaults
otherwise, training episodes of T = 1500 at the config's delta, budget 2M samples (n = 5) or 5M
(n = 11). The run keeps the policy with the best training cumulative reward and the final one;
both are evaluated with the paper's test protocol.

    python baselines/trpo.py --config n5_m2_dt120 --seed 1
"""

from __future__ import annotations

from dataclasses import dataclass

from containergym_marl.training.runs import train_and_evaluate
from containergym_marl.training.script_args import parse_args


@dataclass
class Args:
    """Centralised TRPO on one plant, then evaluation of its best and final policies."""

    config: str = "n5_m2_dt120"  # plant configuration (built-in name or path)
    seed: int = 1  # training seed
    timesteps: int = 0  # budget in samples; 0 = the paper's (2M for n=5, 5M for n=11)
    n_envs: int = 8  # simulations stepped together by the native vectorised env
    out: str = ""  # run directory (default runs/trpo_<config>_s<seed>)
    resume: bool = False  # continue an interrupted run from its last checkpoint
    progress_bar: bool = True  # show training progress
    episodes: int = 15  # evaluation episodes (paper protocol: delta=120 s, T=600)


def main(args: Args) -> dict:
    return train_and_evaluate("trpo", args)


if __name__ == "__main__":
    main(parse_args(Args))
