"""Training runs: their arguments (:class:`TrainArgs`), the run directory a training creates or
resumes, the best-model tracker a checkpoint carries, checkpoints and models saved and loaded.

The layout of a run directory, its lock, metrics and checkpoint names are
:mod:`containergym_marl.rundir`'s.

Budgets are SB3 timesteps, i.e. samples: one per environment step for the centralised algorithms
and one per *agent* step for shared PPO (a simulation step of an n-container plant gives n samples).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from containergym_marl.algorithms import ALGORITHMS, REGISTRY, get_algorithm
from containergym_marl.config import MAX_SIMS
from containergym_marl.config.bounds import MAX_EPOCHS, MAX_MINIBATCH, MAX_N_STEPS, MAX_REPLAY_BUFFER, check_count
from containergym_marl.core.dynamics import ARBITRATION_RULES, DEFAULT_ARBITRATION
from containergym_marl.files import atomic_write_text
from containergym_marl.options import key_values, option, positive_int
from containergym_marl.rundir import (
    RunError,
    RunLock,
    remove_stale_temporaries,
    run_args,
    run_contents,
    run_name,
)


#: The agent reward modes of the algorithms ``train`` trains, the default first.
REWARD_MODES = tuple(dict.fromkeys(m for name in ALGORITHMS for m in REGISTRY[name].reward_modes))


@dataclass
class TrainArgs:
    """Arguments of one training run, and the options of ``containergym-marl train`` (each field's
    help is its option's; the parser is generated from them, :mod:`containergym_marl.options`).

    Budgets are samples: one per environment step for the centralised algorithms and one per
    *agent* step for the decentralised ones. Training uses the config's δ and T (1500 for the
    paper's); simulation b of the vectorised env is seeded ``seed + b``.
    """

    algo: str = option(choices=ALGORITHMS, help="; ".join(f"{name}: {REGISTRY[name].description}" for name in ALGORITHMS)
                       + " (MAPPO: baselines/train_mappo.py, then evaluate its run directory here)")
    config: str = option("n5_m2_dt120", help="plant: a built-in config name or a path")
    seed: int = option(1, type=int, help=f"training seed, in [0, {2**32 - 1}] (numpy's seed range)")
    timesteps: int | None = option(None, type=positive_int,
                                   help="budget in samples (agent steps for the decentralised algorithms); "
                                        "default: the paper's, 2M for n=5 and 5M for n>=11")
    out: str | None = option(None, help="run directory (default: runs/<algo>_<config>_s<seed>)")
    resume: bool = option(False, action="store_true",
                          help="continue the run in --out from its newest intact checkpoint")
    n_envs: int | None = option(None, type=positive_int, help="parallel simulations, >= 1 (default: " + ", ".join(
                                 f"{name} {REGISTRY[name].default_sims_text}" for name in ALGORITHMS) + ")")
    vec: str = option("native", choices=("native", "supersuit"),
                      help="shared_ppo's vectorisation: the package's batched env or the SuperSuit stack")
    num_cpus: int = option(0, type=int, help="SuperSuit worker processes (--vec supersuit only)")
    reward_mode: str | None = option(None, choices=REWARD_MODES,
                                     help="agent rewards of the decentralised algorithms: each container's own, "
                                          "or the plant's for every agent (default: " + ", ".join(
                                              f"{name} {REGISTRY[name].default_reward_mode}" for name in ALGORITHMS
                                              if REGISTRY[name].reward_modes) + ")")
    arbitration: str = option(DEFAULT_ARBITRATION, choices=tuple(ARBITRATION_RULES),
                              help="how free PUs are shared among the container agents' requests")
    checkpoint_every: int | None = option(None, type=positive_int,
                                          help="samples between checkpoints, taken at the end of a rollout "
                                               "(default: min(200000, budget/10) in whole vector steps)")
    gamma: float = option(0.99, type=float, help="discount factor, in (0, 1]")
    hyperparams: dict[str, Any] = option(default_factory=dict, flag="--hp", nargs="*", metavar="KEY=VALUE",
                                         convert=key_values,
                                         help="further settings of the algorithm (SB3's keyword arguments, or "
                                              "the fields of the native trainers' PPOArgs and DAggerArgs), "
                                              "e.g. learning_rate=1e-4")
    progress_bar: bool = option(True, flag="--no-progress", action="store_false",
                                help="no progress bar (samples, samples/s, ETA, latest training return; on a "
                                     "terminal only)")
    torch_threads: int = option(1, type=positive_int,
                                help="torch threads; 1 is fastest for these small networks")
    overrides: dict[str, Any] = option(default_factory=dict, flag="--override", nargs="*", metavar="KEY=VALUE",
                                       convert=key_values,
                                       help="plant config overrides for training, e.g. episode_length_steps=600")

    def __post_init__(self) -> None:
        if self.reward_mode is None and self.algo in REGISTRY:  # an unknown algo is refused by validate
            self.reward_mode = REGISTRY[self.algo].default_reward_mode

    def run_dir(self) -> Path:
        if self.out:
            return Path(self.out)
        return Path("runs") / run_name(self.algo, self.config, self.seed)

    def validate(self):
        """Refuse bad values up front (a ValueError naming the argument). Returns a native trainer's
        parsed settings (None for the others), so that the run does not parse them again."""
        spec = get_algorithm(self.algo)
        if not spec.trained_here:
            raise ValueError(f"algo: {self.algo} is not trained by containergym-marl train but by {spec.trainer_name}")
        for name in ("timesteps", "n_envs", "checkpoint_every"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
                raise ValueError(f"{name}: expected a positive integer, got {value!r}")
        if self.n_envs is not None and self.n_envs > MAX_SIMS:
            raise ValueError(f"n_envs: at most {MAX_SIMS} simulations, got {self.n_envs}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed <= MAX_SEED:
            raise ValueError(f"seed: expected an integer in [0, {MAX_SEED}] (numpy's seed range), got {self.seed!r}")
        if isinstance(self.num_cpus, bool) or not isinstance(self.num_cpus, int) or self.num_cpus < 0:
            raise ValueError(f"num_cpus: expected an integer >= 0 (0: no worker processes), got {self.num_cpus!r}")
        if isinstance(self.torch_threads, bool) or not isinstance(self.torch_threads, int) or self.torch_threads < 1:
            raise ValueError(f"torch_threads: expected a positive integer, got {self.torch_threads!r}")
        if not isinstance(self.hyperparams, dict) or not all(isinstance(k, str) for k in self.hyperparams):
            raise ValueError(f"hyperparams: expected a mapping of setting names to values, got {self.hyperparams!r}")
        if self.vec not in ("native", "supersuit"):
            raise ValueError(f"vec: unknown vectorisation {self.vec!r}; choose 'native' or 'supersuit'")
        if self.vec == "supersuit" and spec.view != "decentralised":
            raise ValueError(f"vec: {self.vec!r} applies to decentralised algorithms only; {self.algo} uses 'native'")
        if spec.reward_modes and self.reward_mode not in spec.reward_modes:
            raise ValueError(f"reward_mode: unknown mode {self.reward_mode!r}; choose one of {spec.reward_modes}")
        if not (isinstance(self.gamma, (int, float)) and not isinstance(self.gamma, bool)
                and 0 < self.gamma <= 1):
            raise ValueError(f"gamma: expected a discount factor in (0, 1], got {self.gamma!r}")
        if spec.sb3:
            _check_sb3_settings(spec, self.hyperparams)
        if spec.native:
            if self.vec != "native":
                raise ValueError(f"vec: {self.algo} trains on the native vector env only, not {self.vec!r}")
            settings = spec.trainer().settings(self.hyperparams)  # torch missing: a message naming the extra
            if spec.view == "centralised" and getattr(settings, "own_check_risk", 0) > 0:
                raise ValueError(f"hp: own_check_risk is the container agents' own check; {self.algo} is a "
                                 f"centralised controller")
            return settings
        return None


#: The largest training seed: SB3 seeds numpy's global generator, which takes seeds below 2**32.
MAX_SEED = 2**32 - 1


def _check_sb3_settings(spec, hyperparams: dict[str, Any]) -> None:
    """Every ``--hp`` key is a keyword argument of the algorithm's SB3 class (a ValueError naming the
    unknown ones and the choices), and the settings that size memory lie within their bounds
    (:mod:`containergym_marl.config.bounds`); SB3 checks the other values when the model is built,
    before the run directory is written."""
    import inspect

    from containergym_marl.models import sb3_networks

    cls = spec.load_class()
    accepted = set(inspect.signature(cls.__init__).parameters) - {"self", "policy", "env", "kwargs", "args"}
    unknown = sorted(set(hyperparams) - accepted)
    if unknown:
        raise ValueError(f"hp: unknown {cls.__name__} setting(s) {unknown}; choose from {sorted(accepted)}")
    for key, hi in (("n_steps", MAX_N_STEPS), ("batch_size", MAX_MINIBATCH), ("n_epochs", MAX_EPOCHS),
                    ("buffer_size", MAX_REPLAY_BUFFER)):
        if key in hyperparams:
            check_count(hyperparams[key], 1, hi, f"hp: {key}")
    sb3_networks(hyperparams.get("policy_kwargs", {}), "hp: policy_kwargs")


def memory_estimate(args: TrainArgs, plant, n_envs: int, settings=None) -> dict[str, int]:
    """Bytes a run of ``args`` on ``plant`` with ``n_envs`` simulations needs at least, one entry per
    setting that sizes them (what :func:`~containergym_marl.config.bounds.check_memory` names),
    with F the observation size, A the actions, S = the slots (simulations, or agents of all of
    them) and float32 throughout (:class:`~containergym_marl.training.native.MemoryShapes`):

    * the simulations: B × (n + m) × 16 floats of state and S × F × 4 observations' copies;
    * a rollout (``n_steps``): n_steps × S × (F + 8) (observations and ~8 per-sample buffers; SB3's
      twice, for its flattened copy);
    * a minibatch: its samples × (F + 4 × the hidden units + A), twice (forward and backward);
    * the networks (``policy_kwargs``): parameters × 6 (weights, gradients, Adam's two moments, the
      saved copies);
    * a replay buffer (``buffer_size``): samples × (2F + 5);
    * a native trainer's own terms (``NativeTrainer.memory``), from ``settings`` (parsed from
      ``args.hyperparams`` when None).
    """
    import inspect

    from containergym_marl.core.observations import DEFAULT_OBSERVATION, agent_observation_size
    from containergym_marl.training.native import MemoryShapes, env_options

    spec = get_algorithm(args.algo)
    n, m = plant.n_containers, plant.num_processing_units
    agents = spec.view == "decentralised"
    observation = DEFAULT_OBSERVATION  # the container agents' observation variant (F), DAgger's setting
    if spec.native:
        trainer = spec.trainer()
        settings = trainer.settings(args.hyperparams) if settings is None else settings
        observation = env_options(trainer, settings).get("observation", DEFAULT_OBSERVATION)
    obs, actions = (agent_observation_size(n, m, observation), 2) if agents else (n + m, n + 1)
    shapes = MemoryShapes(obs, actions, spec.num_slots(n, n_envs), n, m)
    estimate = {f"n_envs={n_envs}": n_envs * (n + m) * 16 * 8 + shapes.slots * obs * 4 * 4}
    if spec.native:
        return {**estimate, **trainer.memory(settings, shapes)}
    from containergym_marl.models import sb3_networks

    kwargs = spec.kwargs(shapes.slots, args.gamma, args.hyperparams)
    nets = sb3_networks(kwargs.get("policy_kwargs", {}), "hp: policy_kwargs")
    estimate["policy_kwargs.net_arch"] = shapes.networks(*nets)
    if spec.rollout:
        estimate[f"n_steps={kwargs['n_steps']}"] = shapes.rollout(kwargs["n_steps"], obs + 8 + actions, copies=2)
        batch = kwargs.get("batch_size", 64)
        estimate[f"batch_size={batch}"] = shapes.minibatch(batch, sum(map(sum, nets)), kwargs["n_steps"])
    else:
        size = kwargs.get("buffer_size", inspect.signature(spec.load_class().__init__).parameters["buffer_size"].default)
        estimate[f"buffer_size={size}"] = size * (2 * obs + 5) * 4
    return estimate


def _jsonable(x):
    return json.loads(json.dumps(x, default=str))


def prepare_run_dir(args: TrainArgs, plant, held_lock: RunLock | None = None) -> tuple[Path, RunLock]:
    """Create (or check, for ``args.resume``) the run directory and take its lock (or use
    ``held_lock``, the run's lock that the caller holds); returns both. Never overwrites results."""
    run = args.run_dir()
    if args.resume and not run_contents(run):
        raise RunError(f"--resume: run directory {str(run)!r} does not exist or is empty; nothing to resume")
    if held_lock is not None and not (held_lock.held and held_lock.path.parent.resolve() == run.resolve()):
        raise ValueError(f"held_lock: not a held lock of the run directory {str(run)!r}")
    lock = held_lock or RunLock(run).acquire()
    try:
        remove_stale_temporaries(run)
        existing = run_contents(run)
        if args.resume:
            saved = run_args(run)
            for key in ("algo", "config", "seed", "vec", "reward_mode", "arbitration", "overrides"):
                if saved.get(key) != _jsonable(getattr(args, key)):
                    raise RunError(f"--resume: {key}={getattr(args, key)!r} differs from the run's {saved.get(key)!r}")
            return run, lock
        if existing:
            raise RunError(
                f"run directory {str(run)!r} already holds results ({', '.join(existing[:5])}); refusing to "
                f"overwrite them: pass --resume to continue that run or choose another --out"
            )
        atomic_write_text(run / "config.toml", plant.to_toml())
        atomic_write_text(run / "args.json", json.dumps(_jsonable(dataclasses.asdict(args)), indent=2))
        return run, lock
    except BaseException:
        if held_lock is None:
            lock.release()
        raise


__all__ = ["REWARD_MODES", "TrainArgs", "memory_estimate", "prepare_run_dir"]
