"""The training loop: :func:`train` turns :class:`~containergym_marl.training.train_args.TrainArgs` into a
run directory (see :mod:`containergym_marl.rundir` for its layout).

One callback follows the plant's return of every training episode, keeps the model with the best
mean return over the last 100 training episodes (``best_model.zip``), appends a metrics row at the
end of every rollout, takes checkpoints (model, best model, replay buffer, progress) at rollout ends
once the checkpoint interval has passed, and moves the run's progress bar (:mod:`containergym_marl.progress_bar`;
on a terminal only), which stops at the budget.

``--resume`` continues from the newest intact checkpoint: metrics rows after it are dropped, the
episode counter, the 100-episode window and the best model are those of the checkpoint, the
simulations get fresh seeds (``seed + samples``). A run with no intact checkpoint starts again
from the beginning, exactly as the uninterrupted run would have.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import shutil
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from containergym_marl.algorithms import (
    ROLLOUT_SAMPLES,
    AlgorithmSpec,
    get_algorithm,
    paper_budget,
)
from containergym_marl.config import PlantConfig, load_config
from containergym_marl.config.bounds import check_memory
from containergym_marl.config.hyperparams import plant_settings
from containergym_marl.files import atomic_write, atomic_write_text
from containergym_marl.rundir import (
    RunError,
    RunLock,
    RunWarning,
    append_metrics,
    config_stem,
    checkpoint_files,
    checkpoints,
    intact_checkpoints,
    read_metrics,
    read_run_summary,
    run_args,
    truncate_metrics,
)
from containergym_marl.models import load_model
from containergym_marl.progress_bar import Bar
from containergym_marl.training.checkpoints import (
    SegmentClock,
    TrainingProgress,
    atomic_save_model,
    checkpoint_interval,
    load_replay_buffer,
    read_progress,
    save_checkpoint,
    sync_run_files,
)
from containergym_marl.training.native import env_options
from containergym_marl.training.train_args import TrainArgs, memory_estimate, prepare_run_dir


def no_episode_note(best_name: str = "best_model.zip") -> str:
    """run.json's note for a run in which no training episode ended."""
    return (f"no training episode finished within the budget, so there is no best model "
            f"({best_name} is not written); evaluation uses the final model")


def make_training_env(spec: AlgorithmSpec, args: TrainArgs, plant: PlantConfig, n_envs: int,
                      options: dict[str, Any] | None = None):
    """The vectorised training env of ``spec`` (native by default); ``options``: the env's keyword
    arguments that a native trainer's settings choose (``NativeTrainer.env_options``: DAgger's
    ``observation``), for the native container-agent env."""
    options = dict(options or {})
    if options and not (spec.view == "decentralised" and args.vec == "native"):
        raise ValueError(f"{sorted(options)}: options of the native container-agent env, not of {args.algo}'s")
    if spec.view == "decentralised":
        if args.vec == "supersuit":
            from containergym_marl.training.supersuit_adapter import SuperSuitVecEnv

            return SuperSuitVecEnv(num_copies=n_envs, num_cpus=args.num_cpus, seed=args.seed, config=plant,
                                   arbitration=args.arbitration, reward_mode=args.reward_mode)
        from containergym_marl.envs.vector import ContainerAgentsVecEnv

        return ContainerAgentsVecEnv(plant, n_envs, arbitration=args.arbitration, reward_mode=args.reward_mode,
                                     **options)
    from containergym_marl.envs.vector import ContainerGymVecEnv

    return ContainerGymVecEnv(plant, n_envs)


def algorithm_kwargs(args: TrainArgs, num_slots: int) -> dict[str, Any]:
    """The SB3 keyword arguments of a run (the registry's settings, then ``args.hyperparams``)."""
    return get_algorithm(args.algo).kwargs(num_slots, args.gamma, args.hyperparams)


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


# ---- the callback ---------------------------------------------------------------------------------
def _make_callback(run: Path, spec: AlgorithmSpec, args: TrainArgs, progress: TrainingProgress, n_envs: int,
                   interval: int, start: int, bar: Bar):
    from stable_baselines3.common.callbacks import BaseCallback

    budget = int(args.timesteps)
    # Rollout algorithms log (and may save the best model and a checkpoint) at every rollout end;
    # replay-buffer ones end a "rollout" every few steps, so they do it every ROLLOUT_SAMPLES.
    log_every = 0 if spec.rollout else ROLLOUT_SAMPLES

    class RunCallback(BaseCallback):
        def __init__(self):
            super().__init__()
            self.progress = progress
            self.last_row = start
            self.last_checkpoint = start
            self._acc = np.zeros(n_envs)
            self._len = np.zeros(n_envs, dtype=np.int64)
            self._clock = SegmentClock(progress)

        def _on_step(self) -> bool:
            rewards, dones = self.training_env.last_plant_step()
            self._acc += rewards
            self._len += 1
            for b in np.flatnonzero(dones):
                self.progress.add_episode(float(self._acc[b]), int(self._len[b]))
                self._acc[b], self._len[b] = 0.0, 0
            bar.advance_to(self.num_timesteps)
            return True

        def _on_rollout_end(self) -> None:
            steps = self.num_timesteps
            if steps - self.last_row >= log_every:
                self.last_row = steps
                self._log(steps)
            if steps - self.last_checkpoint >= interval and steps < budget:
                self._clock.update()
                self.last_checkpoint = save_checkpoint(run, self.model, self.progress,
                                                       replay_buffer=spec.replay_buffer)

        def _log(self, steps: int) -> None:
            """A metrics row, and the best model when the 100-episode mean improved."""
            p = self.progress
            if not p.returns:
                return
            recent = float(np.mean(p.returns))
            length = float(np.mean(p.lengths))
            self.logger.record("plant/train_return_mean100", recent)
            self.logger.record("plant/train_episode_length_mean100", length)
            improved = recent > p.best_train_return
            if improved:
                p.best_train_return, p.best_timesteps = recent, steps
                atomic_save_model(self.model, run / "best_model.zip")
            append_metrics(run, {
                "timesteps": steps,
                "episodes": p.episodes,
                "train_return_mean100": recent,
                "train_episode_length_mean100": length,
                "best_train_return": p.best_train_return,
                "saved_best": int(improved),
                "wall_time_s": self._clock.wall(),
            })
            bar.advance_to(steps, _return_text(p))

        def _on_training_end(self) -> None:
            if self.num_timesteps > self.last_row:  # replay-buffer algorithms: a last row at the end
                self.last_row = self.num_timesteps
                self._log(self.num_timesteps)
            self._clock.update()

    return RunCallback()


def _logger(run: Path, resume: bool):
    """SB3's logger writing TensorBoard files to ``RUN/tb/run_<k>`` (a resumed run continues the
    latest k), and nowhere else: no ``SB3-<date>`` folder in the temp directory."""
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.utils import get_latest_run_id

    latest = get_latest_run_id(str(run / "tb"), "run")
    k = max(latest, 1) if resume else latest + 1
    return configure(str(run / "tb" / f"run_{k}"), ["tensorboard"])


# ---- resume ---------------------------------------------------------------------------------------
def _resume(run: Path, spec: AlgorithmSpec, args: TrainArgs, env, load=None):
    """(model, samples, progress) from the newest intact checkpoint, the run directory made
    consistent with it; None when there is no intact checkpoint (the run directory is then cleared
    for a fresh start). ``load(path)`` reads a checkpoint's model (default: the SB3 model of
    ``args.algo``), raising a ValueError for a broken one."""
    load = load or (lambda path: load_model(path, algo=args.algo, env=env, hyperparams=args.hyperparams))
    suffix, best_name = spec.model_suffix, spec.model_file("best")
    # A checkpoint's model file is written after its progress file (runs.save_checkpoint). Runs
    # saved before that order may hold a model without its progress file after a kill: cut short
    # when an older checkpoint has one; otherwise such checkpoints are from before progress files.
    first_with_progress = min((s for s, _ in checkpoints(run) if checkpoint_files(run, s)["progress"].is_file()),
                              default=math.inf)
    for steps, path in intact_checkpoints(run):
        if path.suffix != suffix:
            continue
        if steps > first_with_progress and not checkpoint_files(run, steps)["progress"].is_file():
            warnings.warn(f"checkpoint {path.name} is incomplete (no progress file); trying the previous one",
                          RunWarning, stacklevel=3)
            continue
        try:
            model = load(path)
        except ValueError as exc:
            warnings.warn(f"{exc}; set aside as {path.name}.broken, trying the previous checkpoint",
                          RunWarning, stacklevel=3)
            os.replace(path, path.with_name(path.name + ".broken"))
            continue
        break
    else:
        warnings.warn(f"{run}: no intact checkpoint to resume from; the run starts again from the beginning",
                      RunWarning, stacklevel=3)
        for name in ("metrics.csv", best_name, "run.json"):
            (run / name).unlink(missing_ok=True)
        shutil.rmtree(run / "tb", ignore_errors=True)
        return None
    files = checkpoint_files(run, steps, suffix)
    if spec.replay_buffer:
        if files["replay_buffer"].is_file():
            try:
                load_replay_buffer(model, files["replay_buffer"])
            except Exception as exc:  # noqa: BLE001 - an unreadable buffer: continue with an empty one
                warnings.warn(f"replay buffer {files['replay_buffer']} is unreadable ({exc}); "
                              f"continuing with an empty one", RunWarning, stacklevel=3)
        else:
            warnings.warn(f"no replay buffer saved with {path.name}; continuing with an empty one",
                          RunWarning, stacklevel=3)
    rows_before = read_metrics(run)
    dropped = truncate_metrics(run, steps)
    if dropped:
        warnings.warn(f"{run}/metrics.csv: dropped {dropped} row(s) after the checkpoint at {steps} samples "
                      f"(training continues from there)", RunWarning, stacklevel=3)
    progress = read_progress(run, steps)
    if progress is None:  # a checkpoint from before progress files: what metrics.csv tells
        kept = read_metrics(run)
        best = max((r["best_train_return"] for r in rows_before), default=-math.inf)
        progress = TrainingProgress(
            episodes=int(kept[-1]["episodes"]) if kept else 0, best_train_return=best,
            wall_time_s=kept[-1]["wall_time_s"] if kept else 0.0, cpu_time_s=None,
            best_timesteps=max((int(r["timesteps"]) for r in rows_before if r["saved_best"]), default=None))
    elif files["best"].is_file():  # the best model as it was at the checkpoint
        atomic_write(run / best_name, lambda tmp: tmp.write_bytes(files["best"].read_bytes()))
    elif progress.best_timesteps is None:  # no best model yet at the checkpoint
        (run / best_name).unlink(missing_ok=True)
    (run / "run.json").unlink(missing_ok=True)
    # Fresh simulation seeds after a resume (an uninterrupted run's streams are not replayed).
    env.seed(args.seed + steps)
    return model, steps, progress


# ---- train ----------------------------------------------------------------------------------------
def run_settings(args: TrainArgs) -> dict[str, Any]:
    """The settings a run trains with: a new run, its method's file (``configs/hyperparams/``,
    :mod:`~containergym_marl.config.hyperparams`) with ``--hp`` on top; a resumed run, the settings
    its ``args.json`` recorded with ``--hp`` on top (not the file as it is now)."""
    if args.resume and (args.run_dir() / "args.json").is_file():
        base = run_args(args.run_dir()).get("hyperparams") or {}
    else:  # the file's settings for this plant's size and decision interval
        base = plant_settings(get_algorithm(args.algo).method_name(args.reward_mode),
                              load_config(args.config, **args.overrides))
    return {**base, **args.hyperparams}


def train(args: TrainArgs, held_lock: RunLock | None = None) -> Path:
    """Train one run; returns its directory. Resumable, crash-safe, never overwrites results,
    one writer per directory: the run's lock is taken here, or handed over as ``held_lock`` by a
    caller that holds it (a sweep task, which decides what to do with the run under it) and then
    left to that caller to release."""
    spec = get_algorithm(args.algo)
    args.validate()
    args = dataclasses.replace(args, hyperparams=run_settings(args))
    settings = args.validate()  # the settings from the method's file or the resumed run, checked as --hp's
    _check_resumed_env(spec, args, settings)
    # a MissingExtraError naming the extra, before anything is written
    algo_cls = spec.load_class() if spec.sb3 else None
    import torch

    plant = load_config(args.config, **args.overrides)  # raises ConfigError for unknown configs
    if args.timesteps is None:
        args = dataclasses.replace(args, timesteps=paper_budget(plant.n_containers))
    if args.resume and (args.run_dir() / "args.json").is_file():
        args = dataclasses.replace(args, n_envs=run_args(args.run_dir()).get("n_envs"))  # the model's shape
    n_envs = spec.default_sims(plant.n_containers, settings=settings) if args.n_envs is None else int(args.n_envs)
    interval = checkpoint_interval(args.timesteps, spec.num_slots(plant.n_containers, n_envs), args.checkpoint_every)
    args = dataclasses.replace(args, n_envs=n_envs, checkpoint_every=interval)
    torch.set_num_threads(max(int(args.torch_threads), 1))
    # The settings' memory is estimated, then the env and a new SB3 model are built, before anything
    # is written: a size that does not fit or settings the algorithm refuses leave no run directory behind.
    check_memory(memory_estimate(args, plant, n_envs, settings), "the run")
    try:
        env = make_training_env(spec, args, plant, n_envs, env_options(spec.trainer(), settings) if spec.native else None)
    except MemoryError:
        raise ValueError(f"n_envs: {n_envs} simulations do not fit in this machine's memory") from None
    try:
        model = None
        if spec.sb3 and not args.resume:
            env.seed(args.seed)
            model = _new_sb3_model(spec, algo_cls, args, env, args.run_dir())
        run, lock = prepare_run_dir(args, plant, held_lock)
        try:
            if _finished_already(run, spec, args):
                return run
            if spec.native:
                _train_native(run, spec, args, env, interval, settings)
            else:
                _train(run, spec, algo_cls, args, env, interval, model)
        finally:
            if held_lock is None:
                lock.release()
    finally:
        env.close()
    return run


def _check_resumed_env(spec: AlgorithmSpec, args: TrainArgs, settings) -> None:
    """A resumed native run keeps the env its settings chose (DAgger's ``observation``): a RunError
    naming the setting when ``--hp`` asks for another, before anything is written."""
    if not (spec.native and args.resume and (args.run_dir() / "args.json").is_file()):
        return
    trainer = spec.trainer()
    before = env_options(trainer, trainer.settings(run_args(args.run_dir()).get("hyperparams") or {}))
    now = env_options(trainer, settings)
    changed = sorted(k for k in {*before, *now} if before.get(k) != now.get(k))
    if changed:
        raise RunError(f"--resume: hp {', '.join(f'{k}={now.get(k)!r}' for k in changed)} differs from the run's "
                       f"{', '.join(f'{k}={before.get(k)!r}' for k in changed)}, the env it trains on")


def _new_sb3_model(spec: AlgorithmSpec, algo_cls, args: TrainArgs, env, run: Path):
    """A new SB3 model of the run; a ValueError naming the settings the algorithm refuses."""
    kwargs = spec.kwargs(env.num_envs, args.gamma, args.hyperparams)
    try:
        return algo_cls("MlpPolicy", env, seed=args.seed, verbose=0, tensorboard_log=str(run / "tb"), device="cpu",
                        **kwargs)
    except (TypeError, ValueError, AssertionError, KeyError) as exc:
        raise ValueError(f"hp: {algo_cls.__name__} refuses the settings {args.hyperparams}: {exc}") from None


def _finished_already(run: Path, spec: AlgorithmSpec, args: TrainArgs) -> bool:
    if args.resume and (run / spec.model_file("final")).is_file():
        done = read_run_summary(run)
        if done is not None and done["timesteps"] >= args.timesteps:
            print(f"{run} finished already ({done['timesteps']:,} samples); nothing to resume")
            return True
    return False


def _train(run: Path, spec: AlgorithmSpec, algo_cls, args: TrainArgs, env, interval: int, model=None):
    resumed = _resume(run, spec, args, env) if args.resume else None
    if resumed is None:
        if model is None:  # a resume that found no intact checkpoint starts again
            env.seed(args.seed)
            model = _new_sb3_model(spec, algo_cls, args, env, run)
        start, progress = 0, TrainingProgress()
    else:
        model, start, progress = resumed
    remaining = args.timesteps - model.num_timesteps
    if remaining > 0:
        model.set_logger(_logger(run, resume=resumed is not None))
        with _no_distribution_validation(), _training_bar(args, start) as bar:
            callback = _make_callback(run, spec, args, progress, args.n_envs, interval, start, bar)
            model.learn(total_timesteps=remaining, callback=callback, reset_num_timesteps=resumed is None,
                        progress_bar=False, tb_log_name="run")
    _finish(run, spec, args, int(model.num_timesteps), progress, start if resumed is not None else None,
            lambda path: atomic_save_model(model, path))


def _train_native(run: Path, spec: AlgorithmSpec, args: TrainArgs, env, interval: int, settings) -> None:
    """A native trainer (:class:`~containergym_marl.training.native.NativeTrainer`, the registry
    entry's ``native``) in the run directory, from its newest intact checkpoint on a resume."""
    trainer = spec.trainer()
    resumed = _resume(run, spec, args, env, load=lambda path: trainer.load_checkpoint(path, settings)) \
        if args.resume else None
    if resumed is None:
        env.seed(args.seed)
        meta = {"algo": args.algo, "config": config_stem(args.config), "seed": args.seed,
                "reward_mode": args.reward_mode if spec.reward_modes else None}
        state, start, progress = trainer.new_state(env, settings, spec.view, args.seed, meta), 0, TrainingProgress()
    else:
        state, start, progress = resumed
    with _training_bar(args, start) as bar:
        state = trainer.learn(run, state, env, int(args.timesteps), float(args.gamma), settings, progress, interval,
                              args.seed, on_samples=lambda steps, p: bar.advance_to(steps, _return_text(p)))
    _finish(run, spec, args, state.num_timesteps, progress, start if resumed is not None else None,
            lambda path: trainer.save_final(state, path), extra=trainer.run_summary(run))


def _training_bar(args: TrainArgs, start: int) -> Bar:
    """The run's bar on stderr (samples, samples/s, ETA, the latest training return); drawn only on a
    terminal and unless ``--no-progress``."""
    return Bar(f"{args.algo} s{args.seed}", int(args.timesteps), "samples", start, show=args.progress_bar)


def _return_text(progress: TrainingProgress) -> str | None:
    return f"training return {np.mean(progress.returns):.2f}" if progress.returns else None


def _finish(run: Path, spec: AlgorithmSpec, args: TrainArgs, timesteps: int, progress: TrainingProgress,
            resumed_from: int | None, save_final, extra: dict[str, Any] | None = None) -> None:
    """run.json (with ``extra``'s entries: what a trainer adds), then the final model
    (``save_final(path)``): the mark of a finished run."""
    best_name = spec.model_file("best")
    if progress.episodes == 0 and not progress.returns:
        (run / best_name).unlink(missing_ok=True)
    best = (run / best_name).is_file()
    summary = {
        "status": "finished",
        "algo": args.algo,
        "timesteps": int(timesteps),
        "budget": int(args.timesteps),
        "episodes": progress.episodes,
        "train_return_mean100": float(np.mean(progress.returns)) if progress.returns else None,
        "best_train_return": None if math.isinf(progress.best_train_return) else progress.best_train_return,
        "best_timesteps": progress.best_timesteps,
        "best_model": best_name if best else None,
        "resumed_from": resumed_from,
        "wall_time_s": progress.wall_time_s,
        "cpu_time_s": progress.cpu_time_s,
        "note": no_episode_note(best_name) if progress.episodes == 0 and not best else None,
        **(extra or {}),
    }
    # run.json first: the final model is the mark of a finished run (compare reuses such runs).
    sync_run_files(run, run / best_name)
    atomic_write_text(run / "run.json", json.dumps(summary, indent=2))
    save_final(run / spec.model_file("final"))
