"""Train one learning baseline on one plant, then evaluate its best and final policies.

    python baselines/train_baseline.py --algo ppo --config n5_m2_dt120 --seed 1
    python baselines/train_baseline.py --algo shared_ppo --config n11_m2_dt120 --seed 2 --vec supersuit

The algorithms (``--algo``; containergym_marl.algorithms.REGISTRY):

* ``ppo``, ``trpo``, ``maskable_ppo``: one centralised controller picks which container to empty
  (MaskablePPO never picks an emptying while no PU is free). 6144 samples per update spread over
  the simulations (n_steps = 768 with 8), minibatch 64 (TRPO: sb3-contrib's 128).
* ``dqn``: centralised DQN with SB3's defaults (one environment, replay buffer of 1M, train_freq
  4); checkpoints include the replay buffer, so --resume continues the same learning process.
* ``shared_ppo``: decentralised, parameter-shared PPO. Each container is an agent of the
  PettingZoo view (container_agents_v0) that may request to be emptied; the environment
  arbitrates the free PUs; all agents' experience trains one policy. The observation carries
  container identity features, so no agent-indicator wrapper is needed. Vectorisation: our native
  ContainerAgentsVecEnv, or SuperSuit's pettingzoo_env_to_vec_env_v1 + concat_vec_envs_v1 with
  --vec supersuit. Its budget counts agent steps: 2M samples on n = 5 are 400k plant steps.

Paper settings for all: gamma = 0.99, training episodes of T = 1500 at the config's delta, budget
2M samples (n = 5) or 5M (n = 11). The run keeps the policy with the best training cumulative
reward and the final one; both are evaluated with the paper's test protocol (delta = 120 s,
T = 600, seeds 10000, 10001, ...). The run directory is the same as `containergym-marl train`'s.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from containergym_marl.evaluation import EvalProtocol
from containergym_marl.evaluation.runs import evaluate_run
from containergym_marl.training import ALGORITHMS, TrainArgs, train
from containergym_marl.training.script_args import parse_args


@dataclass
class Args:
    """Train one learning baseline on one plant, then evaluate its best and final policies."""

    algo: str = field(default="ppo", metadata={"choices": ALGORITHMS})  # the algorithm
    config: str = "n5_m2_dt120"  # plant configuration (built-in name or path)
    seed: int = 1  # training seed
    timesteps: int | None = None  # budget in samples (agent steps for shared_ppo); default: the paper's
    n_envs: int | None = None  # simulations stepped together; default: the algorithm's (8; DQN 1)
    vec: str = "native"  # shared_ppo: "native" or "supersuit"
    num_cpus: int = 0  # SuperSuit worker processes (vec=supersuit)
    reward_mode: str = "individual"  # shared_ppo: "individual" (own emptying reward) or "team" (plant reward)
    arbitration: str = "fullest"  # shared_ppo: rule granting contested PUs
    out: str | None = None  # run directory (default runs/<algo>_<config>_s<seed>)
    resume: bool = False  # continue an interrupted run from its last checkpoint
    progress_bar: bool = True  # show training progress
    episodes: int = 15  # evaluation episodes (paper protocol: delta=120 s, T=600)


def main(args: Args) -> dict:
    run = train(TrainArgs(algo=args.algo, config=args.config, seed=args.seed, timesteps=args.timesteps,
                          n_envs=args.n_envs, vec=args.vec, num_cpus=args.num_cpus, reward_mode=args.reward_mode,
                          arbitration=args.arbitration, out=args.out, resume=args.resume,
                          progress_bar=args.progress_bar))
    protocol = EvalProtocol(episodes=args.episodes)
    results = {which: evaluate_run(run, which=which, protocol=protocol) for which in ("best", "final")}
    for which, result in results.items():
        s = result.summary()
        print(f"{which} policy ({result.policy}): {s['return_mean']:.2f} ± {s['return_std']:.2f} over "
              f"{s['episodes']} episodes (overflow rate {s['overflow_rate']:.2f}, denied requests/episode "
              f"{s['denied_requests_mean']:.1f})")
    return results


if __name__ == "__main__":
    main(parse_args(Args))
