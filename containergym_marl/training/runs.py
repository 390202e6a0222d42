"""Run directories: their layout, arguments, metrics, checkpoints, crash-safe writes and the lock.

A run directory holds everything needed to inspect, resume and evaluate a run::

    RUN/
      args.json           the TrainArgs of the run (resolved)
      config.toml         the plant the run trains on (after overrides)
      metrics.csv         one row per rollout: timesteps, plant return of training episodes…
      best_model.zip      the policy with the best training cumulative reward (paper, section 6.1);
                          absent when no training episode finished (run.json says so)
      final_model.zip     the policy at the end of the budget
      run.json            written when training ends: samples, episodes, training returns, notes
      checkpoints/        ckpt_<S>_steps.zip every checkpoint interval, used by --resume, with
                          ckpt_<S>_steps.json (episode counter, 100-episode window, best so far),
                          best_model_<S>_steps.zip (the best model at that point) and, for
                          replay-buffer algorithms, ckpt_replay_buffer_<S>_steps.npz (plain arrays)
      tb/                 TensorBoard logs
      .lock               held (flock) by the process training in the directory
      evaluation_best.json / evaluation_final.json   written by `containergym-marl evaluate RUN`

Every file is written crash-safe: to a temporary file in the same directory, flushed to disk, then
renamed over the target, so a reader sees the old or the new file, never a part (metrics.csv is
appended one fsynced row at a time, and a partial last row is ignored with a warning); the
temporary file of a write cut short by a kill has a hidden name no reader takes, and the next
process that trains the run removes it (:func:`remove_stale_temporaries`). Readers
treat an unreadable model file as broken and say so; --resume falls back to the newest intact
checkpoint.

Budgets are SB3 timesteps, i.e. samples: one per environment step for the centralised algorithms
and one per *agent* step for shared PPO (a simulation step of an n-container plant gives n samples).

MAPPO runs (``baselines/train_mappo.py``, BenchMARL) follow this layout where it applies: their
models are ``best_model.pt`` / ``final_model.pt`` (a plain torch actor), their checkpoints are
BenchMARL's (``benchmarl/<experiment>/checkpoints/``), their budget and metrics count plant steps,
and run.json's ``"training"`` states the budget in plant steps and agent steps.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import re
import socket
import time
import warnings
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

from containergym_marl.config import MAX_SIMS
from containergym_marl.files import atomic_write, atomic_write_text, temporary_target
from containergym_marl.training.algorithms import get_algorithm, require_training_extra

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows: no OS lock (documented in RunLock)
    fcntl = None


def run_name(method: str, config: str | Path, seed: int) -> str:
    """The name of a run directory: ``<method>_<config>_s<seed>``, the config by its file stem (a
    built-in name, or a path's stem). The one place this rule is written."""
    return f"{method}_{Path(str(config)).stem}_s{seed}"


@dataclass
class TrainArgs:
    """Arguments of one training run (also the CLI's ``train`` options).

    Attributes:
        algo: one of :data:`~containergym_marl.training.algorithms.ALGORITHMS` (ppo, trpo, dqn,
            maskable_ppo: centralised; shared_ppo: one policy shared by all container agents,
            trained on the decentralised view).
        config: built-in config name or path; training uses its δ and T (1500 for the paper's).
        seed: training seed (simulation b of the vectorised env is seeded seed + b).
        timesteps: budget in SB3 timesteps (samples), > 0; None = the paper's budget for the
            plant's size (2M for n <= 5 containers, 5M for more).
        out: run directory (default ``runs/<algo>_<config>_s<seed>``).
        resume: continue an interrupted run from its newest intact checkpoint.
        n_envs: parallel simulations, >= 1 (None: the algorithm's default, 8; DQN 1).
        vec: "native" (our batched vec envs) or "supersuit" (shared_ppo through SuperSuit).
        num_cpus: SuperSuit worker processes (vec="supersuit" only).
        reward_mode: shared_ppo's agent rewards, "individual" or "team".
        arbitration: shared_ppo's arbitration rule.
        checkpoint_every: samples between checkpoints (taken at the end of a rollout); None =
            min(200k, budget / 10) in whole vector steps, so every interrupted run can resume.
        gamma: discount factor (paper: 0.99).
        hyperparams: further keyword arguments for the SB3 algorithm (e.g. learning_rate).
        progress_bar: show a progress bar (samples, samples/s, latest training return).
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
    checkpoint_every: int | None = None
    gamma: float = 0.99
    hyperparams: dict[str, Any] = field(default_factory=dict)
    progress_bar: bool = True
    torch_threads: int = 1
    overrides: dict[str, Any] = field(default_factory=dict)

    def run_dir(self) -> Path:
        if self.out:
            return Path(self.out)
        return Path("runs") / run_name(self.algo, self.config, self.seed)

    def validate(self) -> None:
        """Refuse bad values up front (a ValueError naming the argument)."""
        spec = get_algorithm(self.algo)
        if not spec.trained_here:
            raise ValueError(f"algo: {self.algo} is not trained by containergym-marl train but by {spec.trainer}")
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
            require_training_extra(())  # torch, with a message naming the extra
            from containergym_marl.training.fast_ppo import PPOArgs

            PPOArgs.from_hyperparams(self.hyperparams)


#: The largest training seed: SB3 seeds numpy's global generator, which takes seeds below 2**32.
MAX_SEED = 2**32 - 1


def _check_sb3_settings(spec, hyperparams: dict[str, Any]) -> None:
    """Every ``--hp`` key is a keyword argument of the algorithm's SB3 class (a ValueError naming the
    unknown ones and the choices); the values are checked when the model is built, before the run
    directory is written."""
    import inspect

    cls = spec.load_class()
    accepted = set(inspect.signature(cls.__init__).parameters) - {"self", "policy", "env", "kwargs", "args"}
    unknown = sorted(set(hyperparams) - accepted)
    if unknown:
        raise ValueError(f"hp: unknown {cls.__name__} setting(s) {unknown}; choose from {sorted(accepted)}")


class RunError(RuntimeError):
    """A run directory cannot be used as asked (would overwrite results, nothing to resume, in use…)."""


class RunWarning(UserWarning):
    """Something in a run directory was unreadable or incomplete and was skipped (said what)."""


# ---- crash-safe writes (containergym_marl.files) ----------------------------------------------
def atomic_save_model(model: Any, path: str | Path) -> Path:
    """``model.save`` to a temporary file, then renamed over ``path``."""
    return atomic_write(path, lambda tmp: _save_via_file(model.save, tmp))


def _save_via_file(save: Callable[[Any], None], tmp: Path) -> None:
    with open(tmp, "wb") as f:  # a file object: SB3 would otherwise append ".zip"/".pkl" to the name
        save(f)


def _jsonable(x):
    return json.loads(json.dumps(x, default=str))


# ---- one writer per directory ---------------------------------------------------------------------
LOCK_NAME = ".lock"


class RunLock:
    """An exclusive OS lock (``flock``) on ``RUN/.lock`` for the process that writes the run.

    The OS releases it when the process ends, however it ends (a crash or ``kill -9`` included), so
    a stale lock file never blocks a rerun. A second writer fails at once with a :class:`RunError`
    naming the holder's pid and host (written into the lock file). Platforms without ``fcntl``
    (Windows) get no lock.
    """

    def __init__(self, run: str | Path):
        self.path = Path(run) / LOCK_NAME
        self._file = None

    def acquire(self) -> "RunLock":
        self.path.parent.mkdir(parents=True, exist_ok=True)
        f = open(self.path, "a+")
        if fcntl is not None:
            try:
                fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                f.seek(0)
                holder = f.read().strip() or "unknown process"
                f.close()
                raise RunError(
                    f"run directory {str(self.path.parent)!r} is in use by another writer ({holder}); "
                    f"wait for it to finish or stop it, or choose another directory"
                ) from None
        f.seek(0)
        f.truncate()
        f.write(f"pid {os.getpid()} on host {socket.gethostname()}, since {time.strftime('%Y-%m-%d %H:%M:%S')}\n")
        f.flush()
        self._file = f
        return self

    def release(self) -> None:
        if self._file is not None:
            self._file.close()  # closing the descriptor releases the flock
            self._file = None

    def __enter__(self) -> "RunLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


#: The files of a run directory that training writes (checkpoints/ is the training's too).
TRAINING_FILES = ("args.json", "config.toml", "metrics.csv", "best_model.zip", "final_model.zip", "best_model.pt",
                  "final_model.pt", "run.json")


def remove_stale_temporaries(run: str | Path) -> list[Path]:
    """Remove the temporary files that writers of the run killed while writing left behind (a
    hidden ``.<name>.<random>.tmp`` per file cut short, a half-written model or replay buffer among
    them); returns them. Only for the process that holds the run's :class:`RunLock`: no other
    writer of these files can be at work. Temporary files of other files (``containergym-marl
    evaluate`` writes evaluation_*.json without the lock) are left alone."""
    run = Path(run)
    found = [p for p in (run.iterdir() if run.is_dir() else []) if temporary_target(p.name) in TRAINING_FILES]
    ckpts = run / "checkpoints"
    found += [p for p in (ckpts.iterdir() if ckpts.is_dir() else []) if temporary_target(p.name)]
    for path in found:
        path.unlink(missing_ok=True)
    return found


def clear_run(run: str | Path) -> None:
    """Remove what training wrote in ``run`` (its files, ``checkpoints/``, ``tb/``, evaluations and
    temporary files), for a fresh start; the caller holds the run's :class:`RunLock`. Anything else
    found there is never deleted: a :class:`RunError` names it first."""
    import shutil

    from containergym_marl.files import temporary_target

    run = Path(run)
    ours = set(TRAINING_FILES) | {"checkpoints", "tb", LOCK_NAME}
    foreign = sorted(p.name for p in run.iterdir() if p.name not in ours and temporary_target(p.name) is None
                     and not (p.name.startswith("evaluation_") and p.suffix == ".json"))
    if foreign:
        raise RunError(f"run directory {str(run)!r} holds files that training does not write "
                       f"({', '.join(foreign[:5])}); refusing to clear it: move them or choose another directory")
    for path in run.iterdir():
        if path.name == LOCK_NAME:
            continue
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()


def _contents(run: Path) -> list[str]:
    """What a run directory holds, without the lock file and temporary files."""
    if not run.is_dir():
        return []
    return sorted(p.name for p in run.iterdir() if p.name != LOCK_NAME and not p.name.endswith(".tmp"))


# ---- arguments, summary, status -------------------------------------------------------------------
def run_args(run: str | Path) -> dict[str, Any]:
    path = Path(run) / "args.json"
    if not path.is_file():
        raise FileNotFoundError(f"{str(run)!r} is not a run directory (no args.json)")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise RunError(f"{str(path)!r} is broken (not valid JSON: {exc})") from exc


def read_run_summary(run: str | Path) -> dict[str, Any] | None:
    """``run.json`` (written when training ends), or None (unfinished run, or one trained before
    run.json existed)."""
    path = Path(run) / "run.json"
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError:
        warnings.warn(f"{path} is unreadable; ignored", RunWarning, stacklevel=2)
        return None


def run_status(run: str | Path) -> str:
    """"absent" (nothing there), "finished" (a final model: the file its algorithm's registry entry
    names, ``final_model.zip`` or a MAPPO run's ``final_model.pt``), or "interrupted" (started, not
    finished: rerunning with ``resume=True`` continues it)."""
    run = Path(run)
    if not _contents(run):
        return "absent"
    return "finished" if (run / model_file(run, "final")).is_file() else "interrupted"


def model_file(run: str | Path, which: str) -> str:
    """The name of a run's ``which`` ("best" or "final") model, from the algorithm its args.json
    names (SB3's ``.zip`` names for a run without a readable args.json: the only kind trained before
    args.json)."""
    try:
        spec = get_algorithm(run_args(run)["algo"])
    except (FileNotFoundError, RunError, KeyError, ValueError):
        spec = get_algorithm("ppo")
    return spec.model_file(which)


def model_suffix(run: str | Path) -> str:
    """The suffix of a run's model and checkpoint files (``.zip`` for SB3, ``.pt`` otherwise)."""
    return Path(model_file(run, "final")).suffix


def prepare_run_dir(args: TrainArgs, plant) -> tuple[Path, RunLock]:
    """Create (or check, for ``args.resume``) the run directory and take its lock; returns both.
    Never overwrites results."""
    run = args.run_dir()
    if args.resume and not _contents(run):
        raise RunError(f"--resume: run directory {str(run)!r} does not exist or is empty; nothing to resume")
    lock = RunLock(run).acquire()
    try:
        remove_stale_temporaries(run)
        existing = _contents(run)
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
        lock.release()
        raise


# ---- metrics --------------------------------------------------------------------------------------
METRIC_FIELDS = ("timesteps", "episodes", "train_return_mean100", "train_episode_length_mean100",
                 "best_train_return", "saved_best", "wall_time_s")


def append_metrics(run: Path, row: dict) -> None:
    """Append one row to metrics.csv, flushed to disk before returning."""
    path = Path(run) / "metrics.csv"
    new = not path.exists() or path.stat().st_size == 0
    with path.open("a", newline="") as f:
        w = csv.DictWriter(f, fieldnames=METRIC_FIELDS)
        if new:
            w.writeheader()
        w.writerow(row)
        f.flush()
        os.fsync(f.fileno())


def truncate_metrics(run: Path, max_timesteps: int) -> int:
    """Keep the rows of metrics.csv up to ``max_timesteps`` samples (crash-safe rewrite, the kept
    rows byte for byte); returns how many rows were dropped (later ones, and a partial last row)."""
    path = Path(run) / "metrics.csv"
    if not path.is_file():
        return 0
    lines = path.read_bytes().decode(errors="replace").splitlines(keepends=True)
    kept, dropped = [",".join(METRIC_FIELDS) + "\r\n"], 0
    for line in lines[1:]:
        if _row_steps(line) <= max_timesteps:
            kept.append(line)
        else:
            dropped += 1
    if dropped or not lines or lines[0].strip() != kept[0].strip():
        atomic_write(path, lambda tmp: tmp.write_bytes("".join(kept).encode()))
    return dropped


def _row_steps(line: str) -> float:
    """The timesteps of a complete metrics line; inf for a partial or unreadable one."""
    cells = next(csv.reader([line]), [])
    if not line.endswith("\n") or len(cells) != len(METRIC_FIELDS):
        return math.inf
    try:
        return float(cells[0])
    except ValueError:
        return math.inf


def read_metrics(run: str | Path) -> list[dict[str, float]]:
    """The rows of metrics.csv as floats. A row that cannot be read (a partial last row, cut by a
    crash while it was written) is skipped with a :class:`RunWarning`."""
    path = Path(run) / "metrics.csv"
    if not path.exists():
        return []
    text = path.read_bytes().decode(errors="replace")
    lines = text.splitlines(keepends=True)
    rows = []
    for number, row in enumerate(csv.DictReader(lines), start=2):
        try:
            if None in row or any(v is None or v == "" for v in row.values()) or set(row) != set(METRIC_FIELDS):
                raise ValueError("wrong number of fields")
            if number - 1 == len(lines) - 1 and not lines[-1].endswith("\n"):
                raise ValueError("the row was cut short")
            rows.append({k: float(row[k]) for k in METRIC_FIELDS})
        except (TypeError, ValueError) as exc:
            warnings.warn(f"{path}: row {number} is incomplete or unreadable ({exc}); ignored",
                          RunWarning, stacklevel=2)
    return rows


# ---- training progress: what a checkpoint must carry besides the model ----------------------------
WINDOW = 100  # training episodes in the best-model criterion (as SB3's episode buffer)


@dataclass
class TrainingProgress:
    """The state of the best-model tracker: training episodes finished so far, the returns and
    lengths of the last :data:`WINDOW` of them, the best window mean and when it was reached."""

    episodes: int = 0
    returns: list[float] = field(default_factory=list)
    lengths: list[int] = field(default_factory=list)
    best_train_return: float = -math.inf
    best_timesteps: int | None = None
    wall_time_s: float = 0.0

    def add_episode(self, ret: float, length: int) -> None:
        self.episodes += 1
        self.returns = (self.returns + [float(ret)])[-WINDOW:]
        self.lengths = (self.lengths + [int(length)])[-WINDOW:]

    def to_json(self) -> str:
        data = dataclasses.asdict(self)
        data["best_train_return"] = None if math.isinf(self.best_train_return) else self.best_train_return
        return json.dumps(data)

    @classmethod
    def from_json(cls, text: str) -> "TrainingProgress":
        data = json.loads(text)
        best = data.get("best_train_return")
        return cls(episodes=int(data["episodes"]), returns=[float(x) for x in data["returns"]][-WINDOW:],
                   lengths=[int(x) for x in data["lengths"]][-WINDOW:],
                   best_train_return=-math.inf if best is None else float(best),
                   best_timesteps=data.get("best_timesteps"), wall_time_s=float(data.get("wall_time_s", 0.0)))


# ---- checkpoints ----------------------------------------------------------------------------------
_CKPT = re.compile(r"^ckpt_(\d+)_steps\.(zip|pt)$")


def checkpoint_interval(budget: int, num_slots: int, every: int | None = None) -> int:
    """Samples between checkpoints: ``every`` if given, else min(200k, budget / 10), in whole
    vector steps (``num_slots`` samples each) and at least one, so a run of any budget leaves
    checkpoints before its end (once its first rollout is done) and an interruption loses at most
    a tenth of it."""
    samples = every if every is not None else min(200_000, budget // 10)
    return max(samples // num_slots, 1) * num_slots


def checkpoint_files(run: str | Path, steps: int, suffix: str = ".zip") -> dict[str, Path]:
    """The files of the checkpoint at ``steps``; ``suffix`` is the algorithm's model suffix (SB3's
    ``.zip``, the native PPO's ``.pt``)."""
    d = Path(run) / "checkpoints"
    return {"model": d / f"ckpt_{steps}_steps{suffix}", "progress": d / f"ckpt_{steps}_steps.json",
            "best": d / f"best_model_{steps}_steps{suffix}",
            "replay_buffer": d / f"ckpt_replay_buffer_{steps}_steps.npz"}


def checkpoints(run: str | Path) -> list[tuple[int, Path]]:
    """(samples, model file) of every checkpoint, newest first."""
    found = []
    for p in (Path(run) / "checkpoints").glob("ckpt_*_steps.*"):
        m = _CKPT.match(p.name)
        if m:
            found.append((int(m.group(1)), p))
    return sorted(found, reverse=True)


def latest_checkpoint(run: str | Path) -> tuple[Path, int] | None:
    """The newest checkpoint by name (intact or not): (model file, samples), or None."""
    found = checkpoints(run)
    return (found[0][1], found[0][0]) if found else None


def save_checkpoint(run: Path, model: Any, progress: TrainingProgress, replay_buffer: bool = False,
                    suffix: str = ".zip") -> int:
    """Save a checkpoint at ``model.num_timesteps``: the best model so far (a hard link, or a copy),
    the replay buffer, the progress sidecar, then the model, each crash-safe. The model comes last:
    it is what makes the checkpoint exist (:func:`checkpoints` lists model files), so a kill while
    saving leaves no checkpoint rather than a model without its sidecar (which --resume would take
    for a checkpoint from before sidecars existed, losing the episode window), and files of a
    checkpoint that was never completed are overwritten by the next one at the same samples."""
    steps = int(model.num_timesteps)
    files = checkpoint_files(run, steps, suffix)
    best = Path(run) / f"best_model{suffix}"
    if best.is_file():
        _link_or_copy(best, files["best"])
    if replay_buffer:
        atomic_write(files["replay_buffer"], lambda tmp: save_replay_buffer(model, tmp))
    atomic_write_text(files["progress"], progress.to_json())
    atomic_save_model(model, files["model"])
    return steps


#: The arrays of an SB3 replay buffer that a checkpoint keeps (as .npz: numbers only, no pickle).
REPLAY_ARRAYS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")


def save_replay_buffer(model: Any, path: Path) -> None:
    """The model's replay buffer as plain arrays (``np.savez``), with its write position and fill flag.
    (SB3's own ``save_replay_buffer`` pickles the buffer object, which a reader would unpickle.)"""
    import numpy as np

    buffer = model.replay_buffer
    arrays = {name: getattr(buffer, name) for name in REPLAY_ARRAYS if getattr(buffer, name, None) is not None}
    with open(path, "wb") as f:
        np.savez(f, pos=np.int64(buffer.pos), full=np.bool_(buffer.full), **arrays)


def load_replay_buffer(model: Any, path: Path) -> None:
    """Fill the model's replay buffer from :func:`save_replay_buffer`'s file (``allow_pickle=False``);
    a ValueError when the arrays do not fit the buffer."""
    import numpy as np

    buffer = model.replay_buffer
    with np.load(path, allow_pickle=False) as saved:
        for name in REPLAY_ARRAYS:
            mine = getattr(buffer, name, None)
            if mine is None:
                continue
            if name not in saved or saved[name].shape != mine.shape:
                raise ValueError(f"{name} does not fit the buffer ({mine.shape})")
            mine[...] = saved[name]
        buffer.pos, buffer.full = int(saved["pos"]), bool(saved["full"])


def _link_or_copy(src: Path, dst: Path) -> None:
    def write(tmp: Path) -> None:
        tmp.unlink()
        try:
            os.link(src, tmp)  # best_model.zip is replaced by rename, never rewritten: a link is a snapshot
        except OSError:
            tmp.write_bytes(src.read_bytes())

    atomic_write(dst, write)


def read_progress(run: str | Path, steps: int) -> TrainingProgress | None:
    """The progress sidecar of the checkpoint at ``steps``, or None (absent or unreadable)."""
    path = checkpoint_files(run, steps)["progress"]
    if not path.is_file():
        return None
    try:
        return TrainingProgress.from_json(path.read_text())
    except (ValueError, KeyError, TypeError) as exc:
        warnings.warn(f"{path} is unreadable ({exc}); the episode window restarts", RunWarning, stacklevel=2)
        return None


# ---- models ---------------------------------------------------------------------------------------
_MODEL_MEMBERS = ("data", "policy.pth")


def check_model_file(path: str | Path) -> None:
    """Raise a ValueError saying the file is broken unless ``path`` is a complete model file: an SB3
    model zip (``.zip``) or a torch file (``.pt``, itself a zip holding a ``data.pkl``). Reads the
    archive's members, never their contents."""
    path = Path(path)
    try:
        with zipfile.ZipFile(path) as z:
            names = z.namelist()
            if path.suffix == ".pt":
                missing = [] if any(n.endswith("/data.pkl") for n in names) else ["data.pkl"]
            else:
                missing = [m for m in _MODEL_MEMBERS if m not in names]
            if missing:
                raise ValueError(f"it lacks {', '.join(missing)}")
            bad = z.testzip()
            if bad is not None:
                raise ValueError(f"member {bad!r} is corrupt")
    except (zipfile.BadZipFile, ValueError, EOFError, OSError) as exc:
        raise ValueError(f"cannot read model file {str(path)!r}: the file is broken (cut short or "
                         f"corrupt: {exc})") from exc


def load_model(path: str | Path, algo: str, env=None, hyperparams: dict[str, Any] | None = None):
    """Load a model file of ``algo`` with a clear error when it is missing, broken or not a model of
    ``algo``: an SB3 model, or for an algorithm trained outside SB3 (mappo) what its policy
    adapter's ``load_model`` reads (``env`` is then unused)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"model file {str(path)!r} does not exist")
    spec = get_algorithm(algo)
    if not spec.sb3:
        return spec.policy_adapter.load_model(path)
    cls = spec.load_class()
    check_model_file(path)
    from containergym_marl.training.safe_sb3 import safe_custom_objects

    objects = safe_custom_objects(path, cls, hyperparams)  # every pickled entry replaced: nothing from the file runs
    try:
        return cls.load(path, env=env, device="cpu", custom_objects=objects)
    except (zipfile.BadZipFile, KeyError, ValueError, RuntimeError, EOFError, OSError, AssertionError) as exc:
        raise ValueError(f"cannot read model file {str(path)!r} as a {algo} model: {exc}") from exc


def intact_checkpoints(run: Path) -> Iterator[tuple[int, Path]]:
    """Checkpoints newest first, skipping (with a warning, and renaming to ``*.broken``) the
    broken ones."""
    for steps, path in checkpoints(run):
        try:
            check_model_file(path)
        except ValueError as exc:
            warnings.warn(f"{exc}; set aside as {path.name}.broken, trying the previous checkpoint",
                          RunWarning, stacklevel=2)
            os.replace(path, path.with_name(path.name + ".broken"))
            continue
        yield steps, path


__all__ = [
    "clear_run", "LOCK_NAME", "METRIC_FIELDS", "RunError", "RunLock", "RunWarning", "TrainArgs",
    "TrainingProgress", "append_metrics", "atomic_save_model", "atomic_write", "atomic_write_text",
    "check_model_file", "checkpoint_files", "load_replay_buffer", "save_replay_buffer", "checkpoint_interval", "checkpoints", "intact_checkpoints",
    "latest_checkpoint", "load_model", "model_suffix", "prepare_run_dir", "read_metrics", "read_progress",
    "read_run_summary", "remove_stale_temporaries", "run_args", "run_name", "run_status", "model_file", "save_checkpoint",
    "truncate_metrics",
]

