"""Centralised DQN (Stable-Baselines3): one controller picks which container to empty.

Paper settings: gamma = 0.99 and SB3's defaults otherwise (one environment, replay buffer of 1M,
train_freq 4, ...), training episodes of T = 1500, budget 2M samples (n = 5) or 5M (n = 11).
Checkpoints include the replay buffer so that --resume continues the same learning process.

    python baselines/dqn.py --config n5_m2_dt120 --seed 1
"""

from __future__ import annotations

from dataclasses import dataclass

from containergym_marl.training.runs import train_and_evaluate
from containergym_marl.training.script_args import parse_args


@dataclass
class Args:
    """Centralised DQN on one plant, then evaluation of its best and final policies."""

    config: str = "n5_m2_dt120"  # plant configuration (built-in name or path)
    seed: int = 1  # training seed
    timesteps: int = 0  # budget in samples; 0 = the paper's (2M for n=5, 5M for n=11)
    n_envs: int = 1  # simulations stepped together (SB3's DQN default is one environment)
    out: str = ""  # run directory (default runs/dqn_<config>_s<seed>)
    resume: bool = False  # continue an interrupted run from its last checkpoint
    progress_bar: bool = True  # show training progress
    episodes: int = 15  # evaluation episodes (paper protocol: delta=120 s, T=600)


def main(args: Args) -> dict:
    return train_and_evaluate("dqn", args)


if __name__ == "__main__":
    main(parse_args(Args))
