"""MAPPO, the CTDE baseline: BenchMARL's MAPPO on the batched container-agents env, then the paper's
test protocol through the same ``evaluate`` as every other method.

    python baselines/train_mappo.py --config n11_m2_dt120 --seed 1                 # the paper's budget
    python baselines/train_mappo.py --config n5_m2_dt120 --seed 1 --frames 60000   # a short run
    python baselines/train_mappo.py ... --evaluations results/paper_rows/evaluations

What it trains: one actor shared by all n container agents (BenchMARL's ``share_policy_params``)
on the agents' own observations with their action masks, and a centralised critic on the
normalised global state ``[v / v_max, p / longest PU time]`` (BenchMARL's MAPPO; its yaml
defaults otherwise, MLP 256×256 actor and critic). The reward is the **team** reward (every agent
gets the plant reward, the ContainerGym task's default), so a shared critic learns one value.

Budget: ``--frames`` counts BenchMARL frames, and a frame of this env is one **plant step** (all n
agents act at once), so the default is the paper's budget in plant steps, as for centralised PPO
(2M for n = 5, 5M for n >= 11), i.e. n × that in **agent steps** (10M for n5, 55M for n11).
BenchMARL collects 6,000 frames per iteration from 10 batched simulations.

Output, in ``--out`` (default ``runs/mappo_<config>_s<seed>``): BenchMARL's own experiment folder
(its csv logs and checkpoints; ``checkpoint_interval`` = every 10 % of the budget), ``args.json``,
``config.toml``, ``policy.pt`` (the final actor's state dict; ``Experiment.reload_from_file`` on
the last checkpoint rebuilds the whole experiment), and ``evaluation.json``: the paper's protocol
(δ = 120 s, T = 600, 15 episodes, seeds 10000–10014), the file every other method's evaluation is,
so that ``--evaluations DIR`` puts it where ``python -m containergym_marl.evaluation.table`` reads
it (``DIR/<config>/mappo_s<seed>.json``). The policy evaluated is the **final** one (BenchMARL keeps
no best-so-far model). Rerunning with the same ``--out`` resumes from the newest checkpoint.

Needs the ``clients`` extra (BenchMARL, TorchRL): ``./run test-clients`` builds that environment.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from containergym_marl.config import load_config
from containergym_marl.evaluation import EvalProtocol, evaluate
from containergym_marl.files import atomic_write_text
from containergym_marl.training.algorithms import paper_budget

try:
    import torch
    from benchmarl.algorithms import MappoConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models.mlp import MlpConfig

    from containergym_marl.policies.torchrl_policy import TorchRLAgentsPolicy
    from containergym_marl.training.benchmarl_task import DEFAULT_TASK_CONFIG, ContainerGymTask
except ImportError as error:
    from containergym_marl.extras import missing_extra

    raise missing_extra("baselines/train_mappo.py", "clients", error) from error


def experiment_config(out: Path, frames: int, frames_per_batch: int, n_envs: int) -> ExperimentConfig:
    config = ExperimentConfig.get_from_yaml()
    config.max_n_frames, config.max_n_iters = frames, None
    config.on_policy_collected_frames_per_batch = frames_per_batch
    config.on_policy_n_envs_per_worker = n_envs
    config.on_policy_minibatch_size = min(config.on_policy_minibatch_size, frames_per_batch)
    config.loggers, config.render, config.create_json = ["csv"], False, True
    config.evaluation = False  # the paper's protocol below replaces BenchMARL's evaluation
    config.save_folder = str(out)
    # whole iterations, about every tenth of the budget: an interruption loses at most that
    config.checkpoint_interval = max(frames // 10 // frames_per_batch, 1) * frames_per_batch
    config.checkpoint_at_end, config.keep_checkpoints_num = True, 2
    return config


def _newest_checkpoint(out: Path) -> Path | None:
    found = sorted(out.glob("*/checkpoints/checkpoint_*.pt"), key=lambda p: int(p.stem.split("_")[-1]))
    return found[-1] if found else None


def train_mappo(config: str, seed: int, out: Path, frames: int, frames_per_batch: int = 6000,
                n_envs: int = 10, episodes: int = 15) -> dict:
    """Train (or resume) and evaluate; returns the evaluation as written to ``out/evaluation.json``."""
    torch.set_num_threads(1)  # small networks on few cores: one thread is fastest
    out.mkdir(parents=True, exist_ok=True)
    plant = load_config(config)
    args = {"algo": "mappo", "config": config, "seed": seed, "timesteps": frames, "frames_per_batch": frames_per_batch,
            "n_envs": n_envs, "reward_mode": DEFAULT_TASK_CONFIG["reward_mode"], "library": "benchmarl"}
    saved = out / "args.json"
    if saved.is_file() and json.loads(saved.read_text()) != args:
        raise SystemExit(f"{out} holds a MAPPO run with other arguments ({saved}); choose another --out")
    atomic_write_text(saved, json.dumps(args, indent=2))
    atomic_write_text(out / "config.toml", plant.to_toml())

    exp_config = experiment_config(out, frames, frames_per_batch, n_envs)
    if (checkpoint := _newest_checkpoint(out)) is not None:
        print(f"resuming from {checkpoint}", file=sys.stderr)
        exp_config.restore_file = str(checkpoint)
    model = MlpConfig.get_from_yaml()
    experiment = Experiment(task=ContainerGymTask[config.upper()].get_task(), algorithm_config=MappoConfig.get_from_yaml(),
                            model_config=model, critic_model_config=model, seed=seed, config=exp_config)
    if experiment.total_frames < frames:
        experiment.run()
    torch.save(experiment.policy.state_dict(), out / "policy.pt")

    result = evaluate(TorchRLAgentsPolicy(experiment.policy, name="mappo"), config, EvalProtocol(episodes=episodes),
                      keep_records=False)
    evaluation = json.loads(result.to_json())
    evaluation["training"] = {"frames": int(experiment.total_frames), "plant_steps": int(experiment.total_frames),
                              "agent_steps": int(experiment.total_frames) * plant.n_containers, "library": "benchmarl"}
    atomic_write_text(out / "evaluation.json", json.dumps(evaluation, indent=2) + "\n")
    return evaluation


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--config", default="n5_m2_dt120", help="a built-in config (a BenchMARL task of the package)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--frames", type=int, default=None,
                        help="plant steps of training (default: the paper's budget, 2M for n = 5, 5M for n >= 11)")
    parser.add_argument("--frames-per-batch", type=int, default=6000, help="plant steps per MAPPO iteration")
    parser.add_argument("--n-envs", type=int, default=10, help="batched simulations collecting them")
    parser.add_argument("--episodes", type=int, default=15, help="test episodes (the paper's protocol)")
    parser.add_argument("--out", type=Path, default=None, help="run folder (default runs/mappo_<config>_s<seed>)")
    parser.add_argument("--evaluations", type=Path, default=None,
                        help="also copy the evaluation to DIR/<config>/mappo_s<seed>.json (a table's input)")
    ns = parser.parse_args(argv)
    frames = ns.frames if ns.frames is not None else paper_budget(load_config(ns.config).n_containers)
    for name in ("frames", "frames_per_batch", "n_envs", "episodes"):
        if getattr(ns, name) is not None and getattr(ns, name) < 1:
            parser.error(f"--{name.replace('_', '-')}: expected a positive integer, got {getattr(ns, name)}")
    out = ns.out or Path("runs") / f"mappo_{ns.config}_s{ns.seed}"
    evaluation = train_mappo(ns.config, ns.seed, out, frames, ns.frames_per_batch, ns.n_envs, ns.episodes)
    if ns.evaluations is not None:
        atomic_write_text(ns.evaluations / ns.config / f"mappo_s{ns.seed}.json", json.dumps(evaluation, indent=2) + "\n")
    summary = evaluation["summary"]
    print(f"mappo on {ns.config}, seed {ns.seed}, {frames:,} plant steps: test return "
          f"{summary['return_mean']:.2f} ± {summary['return_std']:.2f}, overflow rate {summary['overflow_rate']:.2f} "
          f"({out / 'evaluation.json'})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
