"""Training runs: algorithms, environments, run directories, checkpoints, best-model selection.

A run directory holds everything needed to inspect, resume and evaluate a run::

    RUN/
      args.json           the TrainArgs of the run (resolved)
      config.toml         the plant the run trains on (after overrides)
      metrics.csv         one row per rollout/log interval: timesteps, plant return of training episodes…
      best_model.zip      the policy with the best training cumulative reward (paper, section 6.1)
      final_model.zip     the policy at the end of the budget
      checkpoints/        periodic checkpoints (plus the replay buffer for DQN), used by --resume
      tb/                 TensorBoard logs
      evaluation_best.json / evaluation_final.json   written by `containergym-marl evaluate RUN`

Budgets are SB3 timesteps, i.e. samples: one per environment step for the centralised algorithms
and one per *agent* step for shared PPO (a simulation step of an n-container plant gives n samples).
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import math
import re
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from containergym_marl.config import PlantConfig, load_config

ALGORITHMS = ("ppo", "trpo", "dqn", "maskable_ppo", "shared_ppo")
#: Samples per policy update for PPO / TRPO / MaskablePPO (the paper's n_steps with one env).
ROLLOUT_SAMPLES = 6144


@dataclass
class TrainArgs:
    """Arguments of one training run (also the CLI's ``train`` options).

    Attributes:
        algo: ppo | trpo | dqn | maskable_ppo (centralised) or shared_ppo (one policy shared by all
            container agents, trained on the decentralised view).
        config: built-in config name or path; training uses its δ and T (1500 for the paper's).
        seed: training seed (simulation b of the vectorised env is seeded seed + b).
        timesteps: budget in SB3 timesteps (samples); None = the paper's budget for the plant's size
            (2M for n <= 5 containers, 5M for more).
        out: run directory (default ``runs/<algo>_<config>_s<seed>``).
        resume: continue an interrupted run from its last checkpoint.
        n_envs: parallel simulations (default 8; DQN 1, as the paper's SB3 defaults).
        vec: "native" (our batched vec envs) or "supersuit" (shared_ppo through SuperSuit).
        num_cpus: SuperSuit worker processes (vec="supersuit" only).
        reward_mode: shared_ppo's agent rewards, "individual" or "team".
        arbitration: shared_ppo's arbitration rule.
        checkpoint_every: samples between checkpoints.
        gamma: discount factor (paper: 0.99).
        hyperparams: further keyword arguments for the SB3 algorithm (e.g. learning_rate).
        progress_bar: show SB3's progress bar.
        torch_threads: torch.set_num_threads; 1 is fastest for these small MLPs on 2 cores.
        overrides: plant-level config overrides for training (e.g. episode_length_steps).
    """

    algo: str
    config: str = "n5_m2_dt120"
    seed: int = 1
    timesteps: int | None = None
    out: str | None = None
    resume: bool = False
    n_envs: int | None = None
    vec: str = "native"
    num_cpus: int = 0
    reward_mode: str = "individual"
    arbitration: str = "fullest"
    checkpoint_every: int = 200_000
    gamma: float = 0.99
    hyperparams: dict[str, Any] = field(default_factory=dict)
    progress_bar: bool = True
    torch_threads: int = 1
    overrides: dict[str, Any] = field(default_factory=dict)

    def run_dir(self) -> Path:
        if self.out:
            return Path(self.out)
        name = Path(str(self.config)).stem
        return Path("runs") / f"{self.algo}_{name}_s{self.seed}"


class RunError(RuntimeError):
    """A run directory cannot be used as asked (would overwrite results, nothing to resume…)."""


def paper_budget(n_containers: int) -> int:
    """The paper's training budget: 2M samples for n = 5, 5M for n = 11 (section 6.1)."""
    return 2_000_000 if n_containers <= 5 else 5_000_000


# ---- algorithms and environments ----------------------------------------------------------------
def algorithm_class(algo: str):
    if algo not in ALGORITHMS:
        raise ValueError(f"algo: unknown algorithm {algo!r}; choose one of {ALGORITHMS}")
    if algo in ("ppo", "shared_ppo"):
        from stable_baselines3 import PPO

        return PPO
    if algo == "dqn":
        from stable_baselines3 import DQN

        return DQN
    if algo == "trpo":
        from sb3_contrib import TRPO

        return TRPO
    from sb3_contrib import MaskablePPO

    return MaskablePPO


def default_n_envs(algo: str) -> int:
    return 1 if algo == "dqn" else 8


def make_training_env(args: TrainArgs, plant: PlantConfig, n_envs: int):
    """The vectorised training env of ``args.algo`` (native by default)."""
    if args.algo == "shared_ppo":
        if args.vec == "supersuit":
            from containergym_marl.training.supersuit_adapter import SuperSuitVecEnv

            return SuperSuitVecEnv(num_copies=n_envs, num_cpus=args.num_cpus, seed=args.seed, config=plant,
                                   arbitration=args.arbitration, reward_mode=args.reward_mode)
        if args.vec != "native":
            raise ValueError(f"vec: unknown vectorisation {args.vec!r}; choose 'native' or 'supersuit'")
        from containergym_marl.envs.vector import ContainerAgentsVecEnv

        return ContainerAgentsVecEnv(plant, n_envs, arbitration=args.arbitration, reward_mode=args.reward_mode)
    if args.vec != "native":
        raise ValueError(f"vec: {args.vec!r} applies to shared_ppo only; centralised algorithms use 'native'")
    from containergym_marl.envs.vector import ContainerGymVecEnv

    return ContainerGymVecEnv(plant, n_envs)


def algorithm_kwargs(args: TrainArgs, num_slots: int) -> dict[str, Any]:
    kwargs: dict[str, Any] = {"gamma": args.gamma}
    if args.algo in ("ppo", "trpo", "maskable_ppo", "shared_ppo"):
        # The paper's 6144 samples per update, spread over the vectorised slots.
        kwargs["n_steps"] = max(ROLLOUT_SAMPLES // num_slots, 2)
        if args.algo != "trpo":
            kwargs["batch_size"] = 64  # SB3's default, kept explicit
    # Adam's fused CPU kernel: the same update rule as SB3's default Adam, one kernel per step
    # instead of a dozen small ops per parameter tensor; with these small MLPs that makes a
    # PPO run ~25 % faster. (Rounding differs in the last bits, as between any two Adam kernels.)
    # Passing optimizer_kwargs replaces SB3's own: its actor-critic policies (PPO, TRPO,
    # MaskablePPO) use eps = 1e-5 only when given none, so that value is restated here; DQN's
    # policy keeps torch's default eps.
    optimizer_kwargs: dict[str, Any] = {"fused": True}
    if args.algo != "dqn":
        optimizer_kwargs["eps"] = 1e-5
    kwargs["policy_kwargs"] = {"optimizer_kwargs": optimizer_kwargs}
    for key, value in args.hyperparams.items():
        if key == "policy_kwargs":  # the caller's policy settings win, key by key
            kwargs["policy_kwargs"] = {**kwargs["policy_kwargs"], **value}
        else:
            kwargs[key] = value
    return kwargs


@contextlib.contextmanager
def _no_distribution_validation():
    """Skip torch.distributions' argument checks while training (SB3 builds a distribution for
    every rollout step and minibatch; the policy's own outputs need no validation). The previous
    setting is restored afterwards."""
    from torch.distributions import Distribution

    previous = Distribution._validate_args
    Distribution.set_default_validate_args(False)
    try:
        yield
    finally:
        Distribution.set_default_validate_args(previous)


# ---- callbacks ------------------------------------------------------------------------------------
def _make_callbacks(run: Path, args: TrainArgs, n_envs: int, num_slots: int, best_so_far: float):
    from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback

    class PlantReturnCallback(BaseCallback):
        """Tracks the plant's return of every training episode; saves the best model (by the mean
        of the last 100 training episodes, as SB3's episode buffer) and writes metrics.csv."""

        def __init__(self):
            super().__init__()
            self.best = best_so_far
            self.returns: list[float] = []
            self.lengths: list[int] = []
            self._acc = np.zeros(n_envs)
            self._len = np.zeros(n_envs, dtype=np.int64)
            self._t0 = time.perf_counter()

        def _plant_step(self):
            env = self.training_env
            if hasattr(env, "last_plant_step"):
                return env.last_plant_step()
            out = env.simulator.last_outcome
            return out.plant_reward, out.terminated | out.truncated

        def _on_step(self) -> bool:
            rewards, dones = self._plant_step()
            self._acc += rewards
            self._len += 1
            for b in np.flatnonzero(dones):
                self.returns.append(float(self._acc[b]))
                self.lengths.append(int(self._len[b]))
                self._acc[b], self._len[b] = 0.0, 0
            return True

        def _on_rollout_end(self) -> None:
            if not self.returns:
                return
            recent = float(np.mean(self.returns[-100:]))
            self.logger.record("plant/train_return_mean100", recent)
            self.logger.record("plant/train_episode_length_mean100", float(np.mean(self.lengths[-100:])))
            improved = recent > self.best
            if improved:
                self.best = recent
                self.model.save(run / "best_model.zip")
            _append_metrics(run, {
                "timesteps": self.num_timesteps,
                "episodes": len(self.returns),
                "train_return_mean100": recent,
                "train_episode_length_mean100": float(np.mean(self.lengths[-100:])),
                "best_train_return": self.best,
                "saved_best": int(improved),
                "wall_time_s": round(time.perf_counter() - self._t0, 2),
            })

    save_freq = max(args.checkpoint_every // max(num_slots, 1), 1)  # callback calls = vec steps
    checkpoint = CheckpointCallback(save_freq=save_freq, save_path=str(run / "checkpoints"), name_prefix="ckpt",
                                    save_replay_buffer=args.algo == "dqn")
    return PlantReturnCallback(), checkpoint


METRIC_FIELDS = ("timesteps", "episodes", "train_return_mean100", "train_episode_length_mean100",
                 "best_train_return", "saved_best", "wall_time_s")


def _append_metrics(run: Path, row: dict) -> None:
    path = run / "metrics.csv"
    new = not path.exists()
    with path.open("a", newline="") as f:
        w = csv.DictWriter(f, fieldnames=METRIC_FIELDS)
        if new:
            w.writeheader()
        w.writerow(row)


def read_metrics(run: str | Path) -> list[dict[str, float]]:
    path = Path(run) / "metrics.csv"
    if not path.exists():
        return []
    with path.open() as f:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]


# ---- run directories ------------------------------------------------------------------------------
_CKPT = re.compile(r"ckpt_(\d+)_steps\.zip$")


def latest_checkpoint(run: Path) -> tuple[Path, int] | None:
    found = []
    for p in (run / "checkpoints").glob("ckpt_*_steps.zip"):
        m = _CKPT.search(p.name)
        if m:
            found.append((int(m.group(1)), p))
    if not found:
        return None
    steps, path = max(found)
    return path, steps


def _prepare_run_dir(args: TrainArgs, plant: PlantConfig) -> Path:
    run = args.run_dir()
    existing = sorted(p.name for p in run.iterdir()) if run.exists() else []
    if args.resume:
        if not existing:
            raise RunError(f"--resume: run directory {str(run)!r} does not exist or is empty; nothing to resume")
        saved = json.loads((run / "args.json").read_text())
        for key in ("algo", "config", "seed", "n_envs", "vec", "reward_mode", "arbitration", "overrides"):
            if key != "n_envs" and saved.get(key) != _jsonable(getattr(args, key)):
                raise RunError(f"--resume: {key}={getattr(args, key)!r} differs from the run's {saved.get(key)!r}")
        return run
    if existing:
        raise RunError(
            f"run directory {str(run)!r} already holds results ({', '.join(existing[:5])}); refusing to "
            f"overwrite them: pass --resume to continue that run or choose another --out"
        )
    run.mkdir(parents=True, exist_ok=True)
    (run / "config.toml").write_text(plant.to_toml())
    (run / "args.json").write_text(json.dumps(_jsonable(dataclasses.asdict(args)), indent=2))
    return run


def _jsonable(x):
    return json.loads(json.dumps(x, default=str))


def train(args: TrainArgs) -> Path:
    """Train one run; returns its directory. Resumable, never overwrites results."""
    import torch

    algo_cls = algorithm_class(args.algo)
    plant = load_config(args.config, **args.overrides)  # raises ConfigError for unknown configs
    if args.timesteps is None:
        args = dataclasses.replace(args, timesteps=paper_budget(plant.n_containers))
    if args.resume and (args.run_dir() / "args.json").is_file():
        saved_n_envs = json.loads((args.run_dir() / "args.json").read_text()).get("n_envs")
        args = dataclasses.replace(args, n_envs=saved_n_envs)  # the model's rollout shape
    n_envs = int(args.n_envs or default_n_envs(args.algo))
    args = dataclasses.replace(args, n_envs=n_envs)
    run = _prepare_run_dir(args, plant)
    torch.set_num_threads(max(int(args.torch_threads), 1))

    env = make_training_env(args, plant, n_envs)
    best_so_far = -math.inf
    if args.resume:
        ckpt = latest_checkpoint(run)
        if ckpt is None:
            env.close()
            raise RunError(f"--resume: run directory {str(run)!r} has no checkpoint to resume from")
        path, steps = ckpt
        # Fresh simulation seeds after a resume (an uninterrupted run's streams are not replayed).
        env.seed(args.seed + steps)
        model = load_model(path, algo=args.algo, env=env)
        if args.algo == "dqn":
            buffer = path.with_name(path.name.replace("ckpt_", "ckpt_replay_buffer_").replace(".zip", ".pkl"))
            if buffer.exists():
                model.load_replay_buffer(buffer)
        rows = read_metrics(run)
        best_so_far = max((r["best_train_return"] for r in rows), default=-math.inf)
        reset = False
    else:
        env.seed(args.seed)
        model = algo_cls("MlpPolicy", env, seed=args.seed, verbose=0, tensorboard_log=str(run / "tb"),
                         device="cpu", **algorithm_kwargs(args, env.num_envs))
        reset = True
    remaining = args.timesteps - model.num_timesteps
    if remaining <= 0:
        if not (run / "final_model.zip").exists():
            model.save(run / "final_model.zip")
        env.close()
        return run
    callbacks = _make_callbacks(run, args, n_envs, env.num_envs, best_so_far)
    with _no_distribution_validation():
        model.learn(total_timesteps=remaining, callback=list(callbacks), reset_num_timesteps=reset,
                    progress_bar=args.progress_bar, tb_log_name="run")
    model.save(run / "final_model.zip")
    if not (run / "best_model.zip").exists():  # budget too small to finish a training episode
        model.save(run / "best_model.zip")
    env.close()
    return run


# ---- loading and evaluating runs ------------------------------------------------------------------
def load_model(path: str | Path, algo: str, env=None):
    """Load an SB3 model file with a clear error when it is missing or unreadable."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"model file {str(path)!r} does not exist")
    try:
        with zipfile.ZipFile(path) as z:
            z.testzip()
        return algorithm_class(algo).load(path, env=env, device="cpu")
    except (zipfile.BadZipFile, KeyError, ValueError, RuntimeError, EOFError, OSError) as exc:
        raise ValueError(f"cannot read model file {str(path)!r} as a {algo} model: {exc}") from exc


def run_args(run: str | Path) -> dict[str, Any]:
    path = Path(run) / "args.json"
    if not path.is_file():
        raise FileNotFoundError(f"{str(run)!r} is not a run directory (no args.json)")
    return json.loads(path.read_text())


def policy_from_run(run: str | Path, which: str = "best", deterministic: bool = True):
    """The evaluation policy of a run directory (``which`` = "best" or "final")."""
    from containergym_marl.policies import CentralisedModelPolicy, SharedModelPolicy

    if which not in ("best", "final"):
        raise ValueError(f"which: expected 'best' or 'final', got {which!r}")
    saved = run_args(run)
    model = load_model(Path(run) / f"{which}_model.zip", algo=saved["algo"])
    name = f"{saved['algo']}[s{saved['seed']},{which}]"
    if saved["algo"] == "shared_ppo":
        return SharedModelPolicy(model, name=name, deterministic=deterministic)
    return CentralisedModelPolicy(model, name=name, deterministic=deterministic)


def evaluate_run(run: str | Path, config: str | None = None, which: str = "best", protocol=None,
                 arbitration: str | None = None, write: bool = True):
    """Evaluate a run's model with the paper's test protocol (on its own config by default)."""
    from containergym_marl.evaluation import PAPER, evaluate

    saved = run_args(run)
    policy = policy_from_run(run, which)
    result = evaluate(policy, config or saved["config"], protocol or PAPER,
                      arbitration=arbitration or saved.get("arbitration", "fullest"))
    if write:
        (Path(run) / f"evaluation_{which}.json").write_text(result.to_json())
    return result


def train_and_evaluate(algo: str, script_args: Any) -> dict[str, Any]:
    """What every learning baseline script does: train (or resume) a run from the script's ``Args``
    dataclass, then evaluate its best and final policies with the paper's protocol."""
    from containergym_marl.evaluation import EvalProtocol

    fields = dataclasses.asdict(script_args)
    episodes = fields.pop("episodes", 15)
    fields["out"] = fields.get("out") or None
    fields["timesteps"] = fields.get("timesteps") or None  # 0: the paper's budget
    run = train(TrainArgs(algo=algo, **fields))
    protocol = EvalProtocol(episodes=episodes)
    results = {which: evaluate_run(run, which=which, protocol=protocol) for which in ("best", "final")}
    for which, result in results.items():
        s = result.summary()
        print(f"{which} policy: {s['return_mean']:.2f} ± {s['return_std']:.2f} over {s['episodes']} episodes "
              f"(overflow rate {s['overflow_rate']:.2f}, denied requests/episode {s['denied_requests_mean']:.1f})")
    return results
