"""MAPPO, the CTDE baseline: BenchMARL's MAPPO on the batched container-agents env, evaluated with the
paper's test protocol through the same ``evaluate`` as every other method.

    python baselines/train_mappo.py --config n5_m2_dt120 --seed 1               # the paper's budget
    python baselines/train_mappo.py --config n11_m2_dt120 --seed 2 --evaluations results/mappo/evaluations
    python baselines/train_mappo.py --config n5_m2_dt120 --seed 1 --resume      # after an interruption
    containergym-marl evaluate runs/mappo_n5_m2_dt120_s1                        # its best model, again
    python -m containergym_marl.evaluation.table results/mappo/evaluations      # the table rows

**What it trains.** BenchMARL 1.5's MAPPO (``MappoConfig`` and ``ExperimentConfig`` from
BenchMARL's own YAML files, ``MlpConfig`` for both networks) on the ContainerGym task of
``--config`` (``containergym_marl.training.benchmarl_task``, the batched
``ContainerAgentsTorchRLEnv``): one **actor shared** by the n container agents
(``share_policy_params``) on each agent's own observation, sampling from a categorical masked by
the agent's ``action_mask`` (requesting while no PU is free is masked), and one **critic on the
global state** (the normalised ``[v / v_max, p / longest PU time]``, ``share_param_critic``). Its
settings are BenchMARL's: MLPs 256 × 256 with tanh, Adam lr 5e-5 (eps 1e-6), grad-norm clip 5,
γ = 0.99, GAE λ = 0.9, clip ε = 0.2, no entropy bonus, 6000 frames per iteration from 10
simulations, 45 passes over it in minibatches of 400 frames. Training episodes are those of every
other method: T = 1500 at the config's δ.

**Reward: team.** Every agent gets the plant reward (the task's default, ``reward_mode="team"``).
MAPPO's shared critic predicts one value of the global state for all agents, which is right only
when all agents have the same return; with individual rewards the agents' returns differ and one
state value cannot fit them.

**Budget.** ``--timesteps`` counts **plant steps**: one step of one simulation, in which all n agents
act. That is what BenchMARL calls a *frame* (``batch.numel()`` of a collected batch whose shape is
[simulations, steps]; ``max_n_frames``, ``total_frames``). The default is the paper's budget of the
row, as for centralised PPO: 2M plant steps for n = 5 (= 10M agent steps) and 5M for n >= 11
(n11_m2_dt120: 55M agent steps). BenchMARL trains whole iterations, so a budget that 6000 does not
divide is rounded up (2M -> 334 iterations, 2,004,000 plant steps); run.json records what was
trained. For comparison: shared PPO's budget counts agent steps (its 5M on n11 are 455k plant
steps), so at the paper's budget MAPPO sees n times the plant steps of shared PPO. The table counts
samples as one per decision of the trained policy, so a MAPPO row reads in agent steps (10M, 55M).

**Deviations from BenchMARL's defaults** (none changes the algorithm): BenchMARL's own evaluation
is off (the paper's test protocol replaces it), loggers: csv only, no rendering, checkpoints every
min(200k, budget / 10) plant steps in whole iterations (``--checkpoint-every``), the last 2 kept,
without the on-policy buffer (refilled every iteration anyway); one torch thread. ``--hp KEY=VALUE``
sets any other field of ``ExperimentConfig``, ``MappoConfig`` or ``MlpConfig`` (values in JSON, e.g.
``--hp lr=3e-4 num_cells=[64,64]``); args.json records them.

**Run directory** (``--out``, default ``runs/mappo_<config>_s<seed>``), the package's layout as far
as it applies::

    args.json         the arguments (algo "mappo", budget in plant steps, BenchMARL overrides)
    config.toml       the plant trained on
    metrics.csv       one row per iteration, the package's columns: timesteps (plant steps), training
                      episodes, mean plant return of the last 100 training episodes, best so far, ...
    best_model.pt     the actor with the best 100-episode mean training return (the paper's choice and
                      the package's for every method; taken when a batch is collected, i.e. the policy
                      that collected it); absent if no training episode ended (run.json says so)
    final_model.pt    the actor at the end of the budget
    run.json          written when training ends: plant steps, episodes, returns, and "training"
                      (library, plant steps, agent steps, samples) that evaluations carry to the table
    benchmarl/<experiment>/   BenchMARL's folder: config.pkl, csv logs, checkpoints/checkpoint_<frames>.pt
                      (a finished run keeps the last: ``Experiment.reload_from_file`` rebuilds it)
    evaluation_best.json      the paper's test protocol on the best model (15 episodes, seeds 10000-10014)

The ``.pt`` models are a plain torch file (``containergym_marl.policies.shared_actor``: the layer
list and a state dict of ``torch.nn.Sequential``), so ``containergym-marl evaluate RUN`` (best model,
or ``--model final``) and ``policy_from_run`` load them with torch alone, without BenchMARL or
TorchRL (the algorithm registry's ``mappo`` entry names the adapter). When exporting, the script
checks that the plain network gives BenchMARL's logits. ``--evaluations DIR`` also writes the
evaluation to ``DIR/<config>/mappo_s<seed>.json``, the file name the table reads as method
``mappo`` (``containergym-marl evaluate RUN --json DIR/<config>/mappo_s<seed>.json`` writes the
same file). ``compare`` does not train MAPPO (it trains SB3 algorithms on Ray); put MAPPO's
evaluation files beside compare's ``evaluations/<config>/`` to get one table.

**Resuming.** ``--resume`` continues an interrupted run from BenchMARL's newest readable checkpoint
(``Experiment``'s ``restore_file``): networks, counters and the collector are restored; metrics rows
after the checkpoint are dropped, and the 100-episode window and best model are those saved with
the checkpoint. BenchMARL's checkpoints hold the networks but not the optimisers, so the script
adds Adam's state to them; the simulations restart with seeds ``seed + plant steps`` (as the
package's SB3 runs do after a resume), and BenchMARL reseeds torch, so a resumed run is not the
uninterrupted one, but continues the same learning process. Without
``--resume`` the script refuses a directory that holds results; a finished run is not trained
again (``--resume`` on it only evaluates).

**Wall time.** On one core of this project's 2-core machine (one torch thread): about 615 plant
steps/s on n5_m2_dt120 (3,100 agent steps/s) and 370 on n11_m2_dt120 (4,100 agent steps/s), ~90 %
of it in BenchMARL's 675 gradient steps per iteration; the paper's budget takes about 0.9 h per
seed on n = 5 and 3.8 h on n = 11 (``benchmarks/mappo_throughput.py``, benchmarks/RESULTS_clients.md).

Needs the ``clients`` extra (BenchMARL, TorchRL): ``./run test-clients`` builds that environment
(.venv-clients).
"""

from __future__ import annotations

import copy
import json
import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from containergym_marl.config import load_config
from containergym_marl.evaluation import EvalProtocol
from containergym_marl.evaluation.run_policies import evaluate_run
from containergym_marl.files import atomic_write_text
from containergym_marl.policies.shared_actor import SharedActor
from containergym_marl.algorithms import paper_budget
from containergym_marl.rundir import (
    append_metrics,
    read_metrics,
    read_run_summary,
    run_name,
    RunError,
    RunLock,
    truncate_metrics,
)
from containergym_marl.training.checkpoints import TrainingProgress
from containergym_marl.evaluation.table import evaluation_key
from containergym_marl.options import key_values, option, positive_int
from containergym_marl.options import parse as parse_args

try:
    import torch
    from benchmarl import __version__ as BENCHMARL_VERSION
    from benchmarl.algorithms import MappoConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.experiment.callback import Callback
    from benchmarl.models.mlp import MlpConfig
    from torchrl.modules import MultiAgentMLP

    from containergym_marl.envs.torchrl_env import GROUP
    from containergym_marl.training.benchmarl_task import DEFAULT_TASK_CONFIG, ContainerGymTask
except ImportError as error:
    from containergym_marl.extras import missing_extra

    raise missing_extra("baselines/train_mappo.py", "clients", error) from error


@dataclass
class Args:
    """Train BenchMARL's MAPPO (shared actor, critic on the global state, team reward) on one plant,
    then evaluate its best model with the paper's test protocol."""

    config: str = option("n5_m2_dt120", help="built-in plant config (one BenchMARL task each)")
    seed: int = option(1, type=int, help="training seed (BenchMARL's seed_everything and the simulations' seeds)")
    timesteps: int | None = option(None, type=positive_int,
                                   help="budget in plant steps (BenchMARL frames); default: 2M (n=5), 5M (n>=11)")
    out: str | None = option(None, help="run directory (default: runs/mappo_<config>_s<seed>)")
    resume: bool = option(False, action="store_true",
                          help="continue the interrupted run in --out from its newest checkpoint")
    frames_per_batch: int = option(6000, type=positive_int,
                                   help="plant steps collected per MAPPO iteration (BenchMARL's default)")
    n_envs: int = option(10, type=positive_int, help="batched simulations collecting them (BenchMARL's default)")
    checkpoint_every: int | None = option(None, type=positive_int,
                                          help="plant steps between checkpoints; default: min(200k, budget/10)")
    hp: dict = option(default_factory=dict, nargs="*", metavar="KEY=VALUE", convert=key_values,
                      help="BenchMARL Experiment/Mappo/Mlp config fields")
    override: dict = option(default_factory=dict, nargs="*", metavar="KEY=VALUE", convert=key_values,
                            help="plant overrides for training")
    episodes: int = option(15, type=positive_int,
                           help="test episodes of the evaluation (paper protocol: delta=120 s, T=600)")
    evaluations: str | None = option(None, help="also write the evaluation to DIR/<config>/mappo_s<seed>.json")
    torch_threads: int = option(1, type=positive_int,
                                help="torch.set_num_threads: one is fastest for these small networks")


# ---- BenchMARL's configs, with the deviations the docstring lists ---------------------------------
def benchmarl_configs(args: Args, run: Path, budget: int, interval: int):
    experiment = ExperimentConfig.get_from_yaml()
    algorithm = MappoConfig.get_from_yaml()
    model = MlpConfig.get_from_yaml()
    experiment.max_n_frames, experiment.max_n_iters = budget, None
    experiment.on_policy_collected_frames_per_batch = args.frames_per_batch
    experiment.on_policy_n_envs_per_worker = args.n_envs
    experiment.on_policy_minibatch_size = min(experiment.on_policy_minibatch_size, args.frames_per_batch)
    experiment.evaluation, experiment.render, experiment.create_json = False, False, False
    experiment.loggers = ["csv"]
    experiment.save_folder = str(run / "benchmarl")
    experiment.checkpoint_interval, experiment.checkpoint_at_end = interval, True
    experiment.keep_checkpoints_num, experiment.exclude_buffer_from_checkpoint = 2, True
    for key, value in args.hp.items():
        target = next((c for c in (experiment, algorithm, model) if hasattr(c, key)), None)
        if target is None:
            raise SystemExit(f"--hp: {key!r} is not a field of BenchMARL's ExperimentConfig, MappoConfig or MlpConfig")
        setattr(target, key, value)
    return experiment, algorithm, model


# ---- the actor as a plain torch network ------------------------------------------------------------
def export_actor(experiment: Experiment, config: str) -> SharedActor:
    """The shared actor of a BenchMARL MAPPO experiment as a :class:`SharedActor` (plain torch)."""
    (mlp,) = [m for m in experiment.group_policies[GROUP].modules() if isinstance(m, MultiAgentMLP)]
    if not mlp.share_params or getattr(mlp, "centralized", getattr(mlp, "centralised", False)):
        raise ValueError("export_actor: expected a shared, decentralised actor (share_policy_params=True)")
    layers = []
    for layer in mlp._empty_net:
        if isinstance(layer, torch.nn.Linear):
            layers.append({"type": "Linear", "in": layer.in_features, "out": layer.out_features})
        else:
            layers.append({"type": type(layer).__name__})
    weights = {k: v.detach().clone() for k, v in mlp.params.flatten_keys(".").items()}
    meta = {"algorithm": "mappo", "library": f"benchmarl {BENCHMARL_VERSION}", "config": config,
            "group": GROUP, "n_agents": len(experiment.group_map[GROUP]), "plant_steps": int(experiment.total_frames)}
    return SharedActor(layers, weights, meta)


def check_export(actor: SharedActor, experiment: Experiment) -> None:
    """The plain network must give the logits BenchMARL's actor gives, on states a rollout visits."""
    env = experiment.task.get_env_fun(num_envs=4, continuous_actions=False, seed=12345, device="cpu")()
    with torch.no_grad():
        rollout = env.rollout(25, policy=experiment.policy, break_when_any_done=False)
    ours = actor.logits(rollout[GROUP, "observation"])
    if not torch.allclose(ours, rollout[GROUP, "logits"], atol=1e-5):
        raise RuntimeError("the exported actor's logits differ from BenchMARL's: the export does not fit "
                           "this BenchMARL/TorchRL version's MultiAgentMLP")


# ---- training returns, best model, metrics.csv, and their part of BenchMARL's checkpoints ----------
class RunTracker(Callback):
    """Follows the plant return of every training episode in the collected batches, appends a
    metrics.csv row per iteration, keeps best_model.pt, and stores its state in BenchMARL's
    checkpoints (``on_state_dict``) so that a resumed run continues it."""

    def __init__(self, run: Path, config: str, n_envs: int):
        super().__init__()
        self.run, self.config = run, config
        self.progress, self.best = TrainingProgress(), None  # best: the best actor's dict, or None
        self.returns, self.lengths = np.zeros(n_envs), np.zeros(n_envs, dtype=np.int64)
        self.t0 = time.perf_counter()

    def wall(self) -> float:
        return round(self.progress.wall_time_s + time.perf_counter() - self.t0, 2)

    def on_batch_collected(self, batch) -> None:
        rewards = batch.get(("next", GROUP, "info", "plant_reward"))[..., 0].numpy()  # [sims, steps]
        done = batch.get(("next", "done"))[..., 0].numpy()
        for t in range(rewards.shape[1]):
            self.returns += rewards[:, t]
            self.lengths += 1
            for b in np.flatnonzero(done[:, t]):
                self.progress.add_episode(float(self.returns[b]), int(self.lengths[b]))
                self.returns[b], self.lengths[b] = 0.0, 0
        p, steps = self.progress, int(self.experiment.total_frames)
        if not p.returns:
            return
        recent = float(np.mean(p.returns))
        improved = recent > p.best_train_return
        if improved:  # the policy that collected this batch (before it trains on it), as SB3's loop keeps
            p.best_train_return, p.best_timesteps = recent, steps
            actor = export_actor(self.experiment, self.config)
            actor.save(self.run / "best_model.pt")
            self.best = actor.to_dict()
        append_metrics(self.run, {"timesteps": steps, "episodes": p.episodes, "train_return_mean100": recent,
                                  "train_episode_length_mean100": float(np.mean(p.lengths)),
                                  "best_train_return": p.best_train_return, "saved_best": int(improved),
                                  "wall_time_s": self.wall()})

    def on_state_dict(self, state_dict) -> None:
        self.progress.wall_time_s = self.wall()
        self.t0 = time.perf_counter()
        # BenchMARL's checkpoint holds the networks, not the optimisers: Adam's moments are saved here
        optimizers = {f"{g}/{k}": opt.state_dict() for g, by_loss in self.experiment.optimizers.items()
                      for k, opt in by_loss.items()}
        state_dict["containergym_marl"] = {"progress": self.progress.to_json(), "best_model": self.best,
                                           "optimizers": optimizers}

    def on_load_state_dict(self, state_dict) -> None:
        saved = state_dict.get("containergym_marl") or {}
        frames = int(state_dict["state"]["total_frames"])
        for key, optimizer_state in saved.get("optimizers", {}).items():
            group, loss = key.split("/", 1)
            self.experiment.optimizers[group][loss].load_state_dict(optimizer_state)
        # fresh simulation seeds after a resume (seed + plant steps, as the package's SB3 runs do),
        # instead of replaying the streams the run started with
        self.experiment.collector.set_seed(self.experiment.seed + frames)
        self.experiment.collector.reset()
        self.progress = TrainingProgress.from_json(saved["progress"]) if "progress" in saved else TrainingProgress()
        self.best, self.t0 = saved.get("best_model"), time.perf_counter()
        if self.best is not None:
            best = SharedActor(self.best["layers"], self.best["state_dict"], self.best["meta"])
            best.save(self.run / "best_model.pt")
        else:
            (self.run / "best_model.pt").unlink(missing_ok=True)
        dropped = truncate_metrics(self.run, frames)
        print(f"resuming from the checkpoint at {frames:,} plant steps ({self.progress.episodes} training episodes"
              + (f"; {dropped} metrics row(s) after it dropped" if dropped else "") + ")", file=sys.stderr)


# ---- the run directory ---------------------------------------------------------------------------
def checkpoints(run: Path) -> list[tuple[int, Path]]:
    """BenchMARL's checkpoints of the run, newest first."""
    found = [(int(p.stem.rsplit("_", 1)[1]), p) for p in run.glob("benchmarl/*/checkpoints/checkpoint_*.pt")]
    return sorted(found, reverse=True)


def readable_checkpoint(run: Path) -> Path | None:
    """The newest checkpoint that loads; broken ones are set aside as ``*.broken``."""
    for _, path in checkpoints(run):
        try:
            torch.load(path, map_location="cpu", weights_only=True)
            return path
        except Exception as exc:  # noqa: BLE001 - a file cut short by a crash
            print(f"checkpoint {path} is unreadable ({type(exc).__name__}); set aside, trying the previous one",
                  file=sys.stderr)
            os.replace(path, path.with_name(path.name + ".broken"))
    return None


def prepare(args: Args, saved_args: dict, run: Path, plant) -> str:
    """Check the run directory for this command; returns "new", "resume" or "finished"."""
    contents = [p.name for p in run.iterdir() if p.name != ".lock"] if run.is_dir() else []
    if not args.resume:
        if contents:
            raise RunError(f"run directory {str(run)!r} already holds results; pass --resume to continue "
                           f"or evaluate it, or choose another --out")
        atomic_write_text(run / "args.json", json.dumps(saved_args, indent=2))
        atomic_write_text(run / "config.toml", plant.to_toml())
        return "new"
    if not (run / "args.json").is_file():
        raise RunError(f"--resume: {str(run)!r} holds no MAPPO run (no args.json); nothing to resume")
    before = json.loads((run / "args.json").read_text())
    differ = sorted(k for k in set(before) | set(saved_args) if before.get(k) != saved_args.get(k))
    if differ:
        raise RunError(f"--resume: {', '.join(f'{k}={saved_args.get(k)!r}' for k in differ)} differ from the "
                       f"run's ({', '.join(f'{k}={before.get(k)!r}' for k in differ)})")
    done = read_run_summary(run)
    if (run / "final_model.pt").is_file() and done is not None and done.get("timesteps", 0) >= saved_args["timesteps"]:
        return "finished"
    return "resume"


def train(args: Args) -> Path:
    """Train (or resume) one MAPPO run; returns its directory."""
    torch.set_num_threads(max(args.torch_threads, 1))
    overrides = args.override
    plant = load_config(args.config, **overrides)
    budget = args.timesteps if args.timesteps is not None else paper_budget(plant.n_containers)
    if min(budget, args.frames_per_batch, args.n_envs, args.episodes) < 1:
        raise SystemExit("--timesteps, --frames-per-batch, --n-envs and --episodes must be positive integers")
    if args.frames_per_batch % args.n_envs:
        raise SystemExit(f"--frames-per-batch ({args.frames_per_batch}) must be a multiple of --n-envs ({args.n_envs})")
    if Path(args.config).stem.upper() not in ContainerGymTask.__members__:
        raise SystemExit(f"--config: {args.config!r} is not a built-in config (a BenchMARL task of the package)")
    every = args.checkpoint_every if args.checkpoint_every is not None else min(200_000, budget // 10)
    interval = max(every // args.frames_per_batch, 1) * args.frames_per_batch  # whole iterations
    run = Path(args.out or Path("runs") / run_name("mappo", args.config, args.seed))
    saved_args = {"algo": "mappo", "config": args.config, "seed": args.seed, "timesteps": budget,
                  "budget_unit": "plant steps", "frames_per_batch": args.frames_per_batch, "n_envs": args.n_envs,
                  "checkpoint_every": interval, "reward_mode": DEFAULT_TASK_CONFIG["reward_mode"],
                  "arbitration": DEFAULT_TASK_CONFIG["arbitration"], "hyperparams": args.hp,
                  "overrides": overrides, "torch_threads": args.torch_threads,
                  "library": f"benchmarl {BENCHMARL_VERSION}"}
    with RunLock(run):
        state = prepare(args, saved_args, run, plant)
        if state == "finished":
            print(f"{run} finished already ({budget:,} plant steps); not trained again", file=sys.stderr)
            return run
        restore = readable_checkpoint(run) if state == "resume" else None
        if state == "resume" and restore is None:  # interrupted before its first checkpoint: start again
            print(f"{run}: no readable checkpoint; training starts again from the beginning", file=sys.stderr)
            for name in ("metrics.csv", "best_model.pt", "run.json"):
                (run / name).unlink(missing_ok=True)
        (run / "benchmarl").mkdir(exist_ok=True)
        experiment_config, algorithm, model = benchmarl_configs(args, run, budget, interval)
        experiment_config.restore_file = None if restore is None else str(restore)
        tracker = RunTracker(run, args.config, args.n_envs)
        task = ContainerGymTask[Path(args.config).stem.upper()].get_task(config={**DEFAULT_TASK_CONFIG, **overrides})
        experiment = Experiment(task=task, algorithm_config=algorithm, model_config=model,
                                critic_model_config=copy.deepcopy(model), seed=args.seed,
                                config=experiment_config, callbacks=[tracker])
        resumed_from = int(experiment.total_frames) if restore is not None else None
        experiment.run()

        final = export_actor(experiment, args.config)
        check_export(final, experiment)
        progress, frames, n = tracker.progress, int(experiment.total_frames), plant.n_containers
        best = (run / "best_model.pt").is_file()
        summary = {
            "status": "finished", "algo": "mappo", "timesteps": frames, "budget": budget, "unit": "plant steps",
            "episodes": progress.episodes,
            "train_return_mean100": float(np.mean(progress.returns)) if progress.returns else None,
            "best_train_return": None if math.isinf(progress.best_train_return) else progress.best_train_return,
            "best_timesteps": progress.best_timesteps, "best_model": "best_model.pt" if best else None,
            "resumed_from": resumed_from, "wall_time_s": tracker.wall(),
            "note": None if best else ("no training episode finished within the budget, so there is no best "
                                       "model; evaluation uses final_model.pt"),
            # what evaluations carry to the table: the budget and what was trained (whole iterations);
            # "samples", the table's column, is the budget in agent steps (one per decision of the actor),
            # as compare records the budget of the SB3 runs
            "training": {"library": f"benchmarl {BENCHMARL_VERSION}", "algorithm": "mappo",
                         "budget_plant_steps": budget, "budget_agent_steps": budget * n,
                         "plant_steps": frames, "agent_steps": frames * n, "samples": budget * n,
                         "samples_unit": "agent steps", "reward_mode": DEFAULT_TASK_CONFIG["reward_mode"]},
        }
        atomic_write_text(run / "run.json", json.dumps(summary, indent=2))
        final.save(run / "final_model.pt")  # last: a final model marks a finished run, as in the package
        for _, older in checkpoints(run)[1:]:  # a resumed run leaves its earlier checkpoints behind
            older.unlink()
    return run


def main(args: Args) -> dict:
    try:
        run = train(args)
    except RunError as exc:
        raise SystemExit(f"train_mappo.py: error: {exc}") from None
    result = evaluate_run(run, which="best", protocol=EvalProtocol(episodes=args.episodes))
    if args.evaluations:
        atomic_write_text(Path(args.evaluations) / Path(args.config).stem / f"{evaluation_key('mappo', args.seed)}.json",
                          result.to_json() + "\n")
    rows, s = read_metrics(run), result.summary()
    training = f"training return {rows[-1]['train_return_mean100']:.2f} (last 100 episodes); " if rows else ""
    print(f"{run}: {training}test return of {result.policy} {s['return_mean']:.2f} ± {s['return_std']:.2f} "
          f"over {s['episodes']} episodes, overflow rate {s['overflow_rate']:.2f} ({run / 'evaluation_best.json'})")
    return json.loads(result.to_json())


if __name__ == "__main__":
    main(parse_args(Args))
