"""The paper's rule-based controller, centralised and decentralised, under the test protocol.

Centralised: empty the lowest-index container within 1 volume unit of its global optimum.
Decentralised: every container agent requests when it is within the margin; the environment's
arbitration grants the free PUs. No training; evaluated on the fixed evaluation seeds.

    python baselines/rule_based.py --config n5_m2_dt120
"""

from __future__ import annotations

from dataclasses import dataclass

from containergym_marl import load_config
from containergym_marl.core.params import PlantParams
from containergym_marl.evaluation import EvalProtocol, evaluate
from containergym_marl.policies import RuleBasedAgents, RuleBasedController
from containergym_marl.training.script_args import parse_args


@dataclass
class Args:
    """Rule-based controllers on one plant (paper test protocol: delta=120 s, T=600)."""

    config: str = "n5_m2_dt120"  # plant configuration (built-in name or path)
    episodes: int = 15  # evaluation episodes (seeds 10000, 10001, ...)
    margin: float = 1.0  # volume units below the optimum at which a container is emptied
    arbitration: str = "fullest"  # decentralised view: rule granting contested PUs


def main(args: Args) -> dict:
    params = PlantParams.from_config(load_config(args.config))
    protocol = EvalProtocol(episodes=args.episodes)
    results = {}
    for policy in (RuleBasedController(params, args.margin), RuleBasedAgents(params, args.margin)):
        result = evaluate(policy, args.config, protocol, arbitration=args.arbitration)
        s = result.summary()
        print(f"{policy.name:<18} ({policy.view}): {s['return_mean']:.2f} ± {s['return_std']:.2f} "
              f"over {s['episodes']} episodes, overflow rate {s['overflow_rate']:.2f}")
        results[policy.name] = result
    return results


if __name__ == "__main__":
    main(parse_args(Args))
