"""Decentralised, parameter-shared PPO: one policy network acts for every container agent.

Each container is an agent of the PettingZoo view (container_agents_v0) that may request to be
emptied; the environment arbitrates the free PUs. All agents' experience trains one SB3 PPO policy
(parameter sharing). The observation carries container identity features (fill rate, target,
product size, one-hot index), so no agent-indicator wrapper is needed.

Vectorisation: by default our native ContainerAgentsVecEnv (slot b*n + i = agent i of simulation
b); --vec supersuit runs the same through SuperSuit's pettingzoo_env_to_vec_env_v1 +
concat_vec_envs_v1 with the package's adapter (seeding, TimeLimit.truncated, clean exit).

Budget in samples = agent steps: 2M samples on n = 5 are 400k plant steps.

    python baselines/shared_ppo.py --config n5_m2_dt120 --seed 1
"""

from __future__ import annotations

from dataclasses import dataclass

from containergym_marl.training.runs import train_and_evaluate
from containergym_marl.training.script_args import parse_args


@dataclass
class Args:
    """Shared PPO over the container agents of one plant, then evaluation (paper protocol)."""

    config: str = "n5_m2_dt120"  # plant configuration (built-in name or path)
    seed: int = 1  # training seed
    timesteps: int = 0  # budget in samples (agent steps); 0 = the paper's (2M for n=5, 5M for n=11)
    n_envs: int = 8  # simulations (each contributes n agent slots)
    vec: str = "native"  # "native" or "supersuit"
    num_cpus: int = 0  # SuperSuit worker processes (vec=supersuit)
    reward_mode: str = "individual"  # "individual" (own emptying reward) or "team" (plant reward)
    arbitration: str = "fullest"  # rule granting contested PUs
    out: str = ""  # run directory (default runs/shared_ppo_<config>_s<seed>)
    resume: bool = False  # continue an interrupted run from its last checkpoint
    progress_bar: bool = True  # show training progress
    episodes: int = 15  # evaluation episodes (paper protocol: delta=120 s, T=600)


def main(args: Args) -> dict:
    return train_and_evaluate("shared_ppo", args)


if __name__ == "__main__":
    main(parse_args(Args))
