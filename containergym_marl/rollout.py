"""Main job (for now): roll out the rule-based controller through both views, per-episode statistics.

    python -m containergym_marl.rollout --config n5_m2_dt120 --episodes 5 --seed 1000

Both views run the paper's test protocol (δ = 120 s, T = 600) on the same seeds, so the centralised
controller and the decentralised container agents face identical inflows.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import numpy as np

from containergym_marl.config import list_configs
from containergym_marl.envs.centralised import ContainerGymEnv
from containergym_marl.envs.container_agents_v0 import parallel_env
from containergym_marl.policies.rule_based import RuleBasedAgents, RuleBasedController


@dataclass
class EpisodeStats:
    view: str
    seed: int
    cumulative_reward: float
    steps: int
    end: str  # "overflow" or "time limit"
    emptyings: int
    positive_emptying_share: float
    denied_requests: int


def run_centralised(config: str, seed: int) -> EpisodeStats:
    env = ContainerGymEnv(config, protocol="paper_test")
    policy = RuleBasedController(env.simulator.params)
    obs, _ = env.reset(seed=seed)
    total, emptying_rewards, denied, done = 0.0, [], 0, False
    while not done:
        obs, reward, terminated, truncated, info = env.step(policy.act(obs))
        total += reward
        if info["emptied_index"] >= 0:  # a container was emptied (-1: none)
            emptying_rewards.append(info["emptying_reward"])
        denied += int(info["no_free_pu"])
        done = terminated or truncated
    return _stats("centralised", seed, total, info["step"], terminated, emptying_rewards, denied)


def run_decentralised(config: str, seed: int) -> EpisodeStats:
    env = parallel_env(config=config, protocol="paper_test", reward_mode="team")
    policy = RuleBasedAgents(env.simulator.params)
    obs, _ = env.reset(seed=seed)
    total, emptying_rewards, denied = 0.0, [], 0
    while env.agents:
        obs, rewards, terminations, _, infos = env.step(policy.act(obs))
        total += next(iter(rewards.values()))  # team reward: the plant's reward
        emptying_rewards += [i["emptying_reward"] for i in infos.values() if i["granted"]]
        denied += sum(i["denied"] for i in infos.values())
    terminated = any(terminations.values())
    step = next(iter(infos.values()))["step"]
    return _stats("decentralised", seed, total, step, terminated, emptying_rewards, denied)


def _stats(view, seed, total, steps, terminated, emptying_rewards, denied) -> EpisodeStats:
    r = np.asarray(emptying_rewards)
    return EpisodeStats(
        view=view,
        seed=seed,
        cumulative_reward=total,
        steps=steps,
        end="overflow" if terminated else "time limit",
        emptyings=len(r),
        positive_emptying_share=float((r > 0).mean()) if r.size else float("nan"),
        denied_requests=denied,
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default="n5_m2_dt120", help=f"one of {list_configs()} or a path")
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--seed", type=int, default=1000, help="first evaluation seed")
    args = parser.parse_args(argv)

    start = time.perf_counter()
    header = f"{'view':<14}{'seed':>6}{'return':>9}{'steps':>7}  {'end':<11}{'emptyings':>10}{'r>0':>6}{'denied':>8}"
    print(f"rule-based controller on {args.config}, paper test protocol (delta=120 s, T=600)")
    print(header)
    results = []
    for seed in range(args.seed, args.seed + args.episodes):
        for run in (run_centralised, run_decentralised):
            s = run(args.config, seed)
            results.append(s)
            print(f"{s.view:<14}{s.seed:>6}{s.cumulative_reward:>9.2f}{s.steps:>7}  {s.end:<11}"
                  f"{s.emptyings:>10}{s.positive_emptying_share:>6.2f}{s.denied_requests:>8}")
    for view in ("centralised", "decentralised"):
        r = np.array([s.cumulative_reward for s in results if s.view == view])
        print(f"{view}: cumulative reward {r.mean():.2f} ± {r.std():.2f} over {r.size} episodes")
    print(f"({time.perf_counter() - start:.1f} s)")


if __name__ == "__main__":
    main()
