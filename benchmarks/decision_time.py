"""A native shared policy's decision time per plant step, its forward through the actor's modules
against ``ActorCritic.decision_logits`` (the same addmm and tanh called directly), side by side.

    python benchmarks/decision_time.py                                    # a fresh network, n11_m2_dt120
    python benchmarks/decision_time.py --model results/paper_rows/runs/dagger_agents_n11_m2_dt120_s1/best_model.pt
    python benchmarks/decision_time.py --rounds 1 --steps 50              # the smoke test: seconds

Each round times ``policy.act`` on every step of ``--steps`` steps of the container agents' PettingZoo
env (validation seed 20000 on), one torch thread, first with one forward and then with the other
(alternating which goes first), and checks that both decided the same. It prints the median wall
milliseconds per decision of each, the CPU seconds of each round (``time.process_time``), and the
ratios (modules / direct), medians over rounds: a busy machine slows both alike.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np


class _ModuleForward:
    """A model whose decisions go through the actor's modules (``net.actor``), all else its own."""

    def __init__(self, model):
        self._model = model

    def __getattr__(self, name):
        return getattr(self._model, name)

    def decision_logits(self, observations):
        import torch

        with torch.no_grad():
            return self._model.net.actor(observations)


def _timed(policy, env, steps: int, seed: int) -> tuple[np.ndarray, float, list]:
    """The policy's decision times (ms), the CPU seconds of the whole loop and what it decided."""
    from containergym_marl.evaluation.decision_time import decision_times_ms

    decided = []

    class Recording:  # the same small cost on both sides
        def act(self, observations, env):
            decided.append(policy.act(observations, env))
            return decided[-1]

    cpu = time.process_time()
    ms = decision_times_ms(Recording(), env, steps, seed)
    return ms, time.process_time() - cpu, decided


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", help="a decentralised native model file (default: a fresh network)")
    p.add_argument("--config", default="n11_m2_dt120")
    p.add_argument("--steps", type=int, default=600)
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--json", help="write the measurements here")
    args = p.parse_args(argv)

    import torch

    from containergym_marl.config import load_config
    from containergym_marl.envs.container_agents_v0 import parallel_env
    from containergym_marl.policies.actor_critic import ActorCritic, policy_for

    torch.set_num_threads(1)
    plant = load_config(args.config)
    env = parallel_env(plant, action_masking=True)
    if args.model:
        model = ActorCritic.load(args.model)
    else:
        size = env.observation_space(env.possible_agents[0])["observation"].shape[0]
        model = ActorCritic("decentralised", size, 2, generator=torch.Generator().manual_seed(0))
    direct, modules = policy_for(model, "direct"), policy_for(model, "modules")
    modules.model = _ModuleForward(model)  # the same policy class: masks, own check and all
    rounds = []
    for r in range(args.rounds):
        order = (("direct", direct), ("modules", modules)) if r % 2 == 0 else (("modules", modules), ("direct", direct))
        out = {}
        for name, policy in order:
            ms, cpu, decided = _timed(policy, env, args.steps, 20_000)
            out[name] = {"ms_median": float(np.median(ms)), "cpu_s": cpu, "decided": decided}
        if out["direct"]["decided"] != out["modules"]["decided"]:
            raise SystemExit("the two forwards decided differently")
        rounds.append({name: {k: v for k, v in o.items() if k != "decided"} for name, o in out.items()})
    result = {"config": args.config, "steps": args.steps, "model": args.model or "fresh", "rounds": rounds,
              "ms_median": {name: statistics.median(r[name]["ms_median"] for r in rounds) for name in ("direct", "modules")},
              "ratio_wall": statistics.median(r["modules"]["ms_median"] / r["direct"]["ms_median"] for r in rounds),
              "ratio_cpu": statistics.median(r["modules"]["cpu_s"] / r["direct"]["cpu_s"] for r in rounds)}
    print(f"{args.config}, {args.steps} steps x {args.rounds} rounds, one torch thread, model {result['model']}: "
          f"median ms per decision: direct {result['ms_median']['direct']:.4f}, modules "
          f"{result['ms_median']['modules']:.4f}; modules / direct: wall {result['ratio_wall']:.2f}x, "
          f"CPU per round (env steps included) {result['ratio_cpu']:.2f}x; the same decisions")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=1)
    return result


if __name__ == "__main__":
    main()
