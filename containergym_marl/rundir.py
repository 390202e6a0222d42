"""Run directories, the one module for their rules: layout and names, the lock, finished or not,
checkpoints and their integrity, metrics, and the small files a sweep brings back and publishes.
Training, the sweep, compare and publishing all read and write runs through it.

A run directory holds everything needed to inspect, resume and evaluate a run::

    RUN/
      args.json           the TrainArgs of the run (resolved)
      config.toml         the plant the run trains on (after overrides)
      metrics.csv         one row per rollout: timesteps, plant return of training episodes… (and,
                          for the native trainers, the update's diagnostics: UPDATE_FIELDS)
      best_model.zip      the policy with the best training cumulative reward (paper, section 6.1);
                          absent when no training episode finished (run.json says so)
      final_model.zip     the policy at the end of the budget
      run.json            written when training ends: samples, episodes, training returns, notes
      imitation.json      the imitation runs' (dagger_*) record per iteration: agreement with the
                          planner, its labelling CPU seconds
      checkpoints/        ckpt_<S>_steps.zip every checkpoint interval, used by --resume, with
                          ckpt_<S>_steps.json (episode counter, 100-episode window, best so far),
                          best_model_<S>_steps.zip (the best model at that point) and, for
                          replay-buffer algorithms, ckpt_replay_buffer_<S>_steps.npz (plain arrays)
      tb/                 TensorBoard logs
      .lock               held (flock) by the process training in the directory
      evaluation_best.json / evaluation_final.json   written by `containergym-marl evaluate RUN`

Every file is written crash-safe: to a temporary file in the same directory, flushed to disk, then
renamed over the target, so a reader sees the old or the new file, never a part (metrics.csv is
appended one row at a time, and a partial last row is ignored with a warning). The native trainers
write metrics.csv and the best model several times a second, so those two reach the disk with each
checkpoint and at the end of the run rather than at every write (a killed process loses nothing; a
crash of the machine at most what --resume drops anyway); every other file is flushed as written. The
temporary file of a write cut short by a kill has a hidden name no reader takes, and the next
process that trains the run removes it (:func:`remove_stale_temporaries`). Readers
treat an unreadable model file as broken and say so; --resume falls back to the newest intact
checkpoint.

No symbolic link inside a run directory is ever followed (a run folder may come from someone else):
taking the lock refuses a run directory that holds one, naming it, before anything is written, and
the lock file and metrics.csv are opened with ``O_NOFOLLOW`` (the rule of :mod:`containergym_marl.files`).

Budgets are SB3 timesteps, i.e. samples: one per environment step for the centralised algorithms
and one per *agent* step for shared PPO (a simulation step of an n-container plant gives n samples).

MAPPO runs (``baselines/train_mappo.py``, BenchMARL) follow this layout where it applies: their
models are ``best_model.pt`` / ``final_model.pt`` (a plain torch actor), their checkpoints are
BenchMARL's (``benchmarl/<experiment>/checkpoints/``), their budget and metrics count plant steps,
and run.json's ``"training"`` states the budget in plant steps and agent steps.
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
import shutil
import socket
import time
import warnings
import zipfile
from pathlib import Path
from typing import Any, Iterator

from containergym_marl.algorithms import get_algorithm
from containergym_marl.files import atomic_write, open_file, refuse_links, refuse_links_in, temporary_target

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows: no OS lock (documented in RunLock)
    fcntl = None

#: Folders of a run directory that stay on the node that trained it (not among its small files).
NODE_LOCAL = ("checkpoints", "tb")


def config_stem(config: str | Path) -> str:
    """A config's name in file and folder names: a built-in's name, or a path's stem."""
    return Path(str(config)).stem


def run_name(method: str, config: str | Path, seed: int) -> str:
    """The name of a run directory: ``<method>_<config>_s<seed>``, the config by its file stem (a
    built-in name, or a path's stem). The one place this rule is written."""
    return f"{method}_{config_stem(config)}_s{seed}"


def check_distinct_names(runs: list[Path]) -> None:
    """A ValueError naming both where two of ``runs`` are different folders of one name: a store that keys
    runs by their folder's name would keep only one of them."""
    named: dict[str, Path] = {}
    for run in runs:
        first = named.setdefault(run.name, run)
        if first.resolve() != run.resolve():
            raise ValueError(f"two runs named {run.name!r} ({str(first)!r} and {str(run)!r}): the results are kept "
                             f"by run name; give runs of distinct names, or one --out for each set")


def seeded_runs(root: str | Path, method: str, config: str | Path) -> list[tuple[int, Path]]:
    """The run directories of ``method`` on ``config`` under ``root`` as (seed, path), by seed: the
    folders named as :func:`run_name` names them."""
    prefix = run_name(method, config, 0)[:-1]  # "<method>_<config>_s"
    root = Path(root)
    found = [(int(p.name[len(prefix):]), p) for p in (root.iterdir() if root.is_dir() else [])
             if p.is_dir() and p.name.startswith(prefix) and re.fullmatch(r"[0-9]+", p.name[len(prefix):])]
    return sorted(found)


class RunError(RuntimeError):
    """A run directory cannot be used as asked (would overwrite results, nothing to resume, in use…)."""


class RunWarning(UserWarning):
    """Something in a run directory was unreadable or incomplete and was skipped (said what)."""


# ---- one writer per directory ---------------------------------------------------------------------
LOCK_NAME = ".lock"


class RunLock:
    """An exclusive OS lock (``flock``) on ``RUN/.lock`` for the process that writes the run.

    The OS releases it when the process ends, however it ends (a crash or ``kill -9`` included), so
    a stale lock file never blocks a rerun. A second writer, another process or the same one, fails
    at once with a :class:`RunError` naming the holder's pid and host (written into the lock file).
    A holder hands the lock to ``train(args, held_lock=...)`` rather than taking it twice. Platforms
    without ``fcntl`` (Windows) get no lock.

    Taking the lock also checks the run directory: a symbolic link anywhere in it (the lock file
    included, which is opened with ``O_NOFOLLOW``) is an :class:`~containergym_marl.files.UnsafePathError`
    naming it, raised before anything is written. So no writer of a run, all of which take its lock,
    follows a link out of it.
    """

    def __init__(self, run: str | Path):
        self.path = Path(run) / LOCK_NAME
        self._file = None

    def acquire(self) -> "RunLock":
        self.path.parent.mkdir(parents=True, exist_ok=True)
        f = open_file(self.path, "a+")
        try:
            if fcntl is not None:
                try:
                    fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError:
                    f.seek(0)
                    holder = f.read().strip() or "unknown process"
                    raise RunError(
                        f"run directory {str(self.path.parent)!r} is in use by another writer ({holder}); "
                        f"wait for it to finish or stop it, or choose another directory"
                    ) from None
            refuse_links_in(self.path.parent)  # under the lock: no writer adds one meanwhile
        except BaseException:
            f.close()
            raise
        f.seek(0)
        f.truncate()
        f.write(f"pid {os.getpid()} on host {socket.gethostname()}, since {time.strftime('%Y-%m-%d %H:%M:%S')}\n")
        f.flush()
        self._file = f
        return self

    @property
    def held(self) -> bool:
        return self._file is not None

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
                  "final_model.pt", "run.json", "imitation.json")


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


def run_contents(run: Path) -> list[str]:
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
    if not run_contents(run):
        return "absent"
    return "finished" if (run / model_file(run, "final")).is_file() else "interrupted"


#: A run's models: of the highest training return, at the end, of the highest validation return (the
#: checkpoint its sample-efficiency curve picked, :mod:`~containergym_marl.evaluation.curves`).
MODELS = ("best", "final", "validated")
#: The models that stand for a run's seed, the first the run has (then its final model).
STANDING_MODELS = ("validated", "best")


def model_file(run: str | Path, which: str) -> str:
    """The name of a run's ``which`` (one of :data:`MODELS`) model, from the algorithm its args.json
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


# ---- metrics --------------------------------------------------------------------------------------
METRIC_FIELDS = ("timesteps", "episodes", "train_return_mean100", "train_episode_length_mean100",
                 "best_train_return", "saved_best", "wall_time_s")
#: The native trainers' diagnostics of each update, after METRIC_FIELDS in their rows: the policy's
#: entropy (nats), approx-KL and clip fraction (means over the update's minibatches, as SB3 logs them),
#: the critic's explained variance on the rollout, and the share of the last 100 training episodes
#: that reached the time limit rather than overflowing. nan where a phase has none (imitation).
UPDATE_FIELDS = ("entropy", "approx_kl", "clip_fraction", "explained_variance", "time_limit_share")
#: The headers a metrics.csv may have: SB3 and MAPPO runs write the first, the native trainers the second.
METRIC_HEADERS = (METRIC_FIELDS, METRIC_FIELDS + UPDATE_FIELDS)


def append_metrics(run: Path, row: dict, durable: bool = True) -> None:
    """Append one row to metrics.csv, flushed to disk before returning unless ``durable`` is False (a
    trainer that writes a row every few hundred milliseconds: its rows reach the disk with the next
    checkpoint, and --resume drops the rows after the newest checkpoint anyway). A new file with a
    row of the update diagnostics (:data:`UPDATE_FIELDS`) gets the longer header; a file keeps the
    header it has (a run begun before the diagnostics existed goes on without them, the rest is nan)."""
    with open_file(Path(run) / "metrics.csv", "a+", within=run, newline="", encoding="utf-8", errors="replace") as f:
        new = os.fstat(f.fileno()).st_size == 0
        if new:
            fields = METRIC_HEADERS[1] if UPDATE_FIELDS[0] in row else METRIC_HEADERS[0]
        else:
            f.seek(0)
            fields = _header([f.readline()])
            f.seek(0, os.SEEK_END)
        w = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore", restval="nan")
        if new:
            w.writeheader()
        w.writerow(row)
        f.flush()
        if durable:
            os.fsync(f.fileno())


def _header(lines: list[str]) -> tuple[str, ...]:
    """The file's header if it is one of :data:`METRIC_HEADERS`, else the base one (rewritten)."""
    first = tuple(lines[0].strip().split(",")) if lines else ()
    return first if first in METRIC_HEADERS else METRIC_FIELDS


def truncate_metrics(run: Path, max_timesteps: int) -> int:
    """Keep the rows of metrics.csv up to ``max_timesteps`` samples (crash-safe rewrite, the kept
    rows byte for byte); returns how many rows were dropped (later ones, and a partial last row)."""
    path = Path(run) / "metrics.csv"
    if not path.is_file():
        return 0
    lines = path.read_bytes().decode(errors="replace").splitlines(keepends=True)
    fields = _header(lines)
    kept, dropped = [",".join(fields) + "\r\n"], 0
    for line in lines[1:]:
        if _row_steps(line, len(fields)) <= max_timesteps:
            kept.append(line)
        else:
            dropped += 1
    if dropped or not lines or lines[0].strip() != kept[0].strip():
        atomic_write(path, lambda tmp: tmp.write_bytes("".join(kept).encode()))
    return dropped


def _row_steps(line: str, columns: int) -> float:
    """The timesteps of a complete metrics line; inf for a partial or unreadable one."""
    cells = next(csv.reader([line]), [])
    if not line.endswith("\n") or len(cells) != columns:
        return math.inf
    try:
        return float(cells[0])
    except ValueError:
        return math.inf


def read_metrics(run: str | Path, quiet: bool = False) -> list[dict[str, float]]:
    """The rows of metrics.csv as floats (:data:`METRIC_FIELDS`, and :data:`UPDATE_FIELDS` in a
    native run's, nan where a phase has none). A row that cannot be read (a partial last row, cut by
    a crash while it was written) is skipped with a :class:`RunWarning`."""
    path = Path(run) / "metrics.csv"
    if not path.exists():
        return []
    text = path.read_bytes().decode(errors="replace")
    lines = text.splitlines(keepends=True)
    fields = _header(lines)
    rows = []
    for number, row in enumerate(csv.DictReader(lines), start=2):
        try:
            if None in row or any(v is None or v == "" for v in row.values()) or set(row) != set(fields):
                raise ValueError("wrong number of fields")
            if number - 1 == len(lines) - 1 and not lines[-1].endswith("\n"):
                raise ValueError("the row was cut short")
            values = {k: float(row[k]) for k in fields}
            if any(math.isnan(values[k]) for k in METRIC_FIELDS):
                raise ValueError("a number is missing")
            rows.append(values)
        except (TypeError, ValueError) as exc:
            if not quiet:  # quiet: a reader of a run that is being written, where a last row may be partial
                warnings.warn(f"{path}: row {number} is incomplete or unreadable ({exc}); ignored",
                              RunWarning, stacklevel=2)
    return rows


# ---- checkpoints ----------------------------------------------------------------------------------
_CKPT = re.compile(r"^ckpt_(\d+)_steps\.(zip|pt)$")


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


def latest_intact_checkpoint(run: str | Path) -> int | None:
    """Samples of the newest intact checkpoint (broken ones set aside), or None."""
    return next((steps for steps, _ in intact_checkpoints(Path(run))), None)


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


# ---- finished or not, across machines -------------------------------------------------------------
def finished_budget(run: str | Path) -> int | None:
    """The budget of a finished run (an intact final model and ``args.json``), else None. Reads
    small files; no Ray, no torch."""
    run = Path(run)
    final = run / model_file(run, "final")
    if not final.is_file():
        return None
    try:
        check_model_file(final)
        return int(run_args(run)["timesteps"])
    except (ValueError, KeyError, TypeError, FileNotFoundError, RunError):
        return None


def small_files(run: str | Path) -> dict[str, bytes]:
    """The run directory's files except :data:`NODE_LOCAL` folders, the lock file and temporary files
    of writes cut short, as ``{relative path: bytes}``: what a sweep brings back from the node that
    trained the run, and what is published."""
    run = Path(run)
    out = {}
    for path in sorted(run.rglob("*")):
        rel = path.relative_to(run)
        if (path.is_file() and rel.parts[0] not in NODE_LOCAL and path.name != LOCK_NAME
                and temporary_target(path.name) is None):
            out[rel.as_posix()] = path.read_bytes()
    return out


def write_files(run: str | Path, files: dict[str, bytes]) -> int:
    """Write ``files`` (:func:`small_files`' output) into ``run`` where they differ from what is there,
    each crash-safe; returns how many were written."""
    run = Path(run)
    written = 0
    for rel, data in files.items():
        path = refuse_links(run / rel, run)  # before reading what is there
        if path.is_file() and path.read_bytes() == data:
            continue
        atomic_write(path, lambda tmp, data=data: tmp.write_bytes(data), within=run)
        written += 1
    return written


def measured_rate(run: str | Path) -> float | None:
    """Samples per second of a run's last uninterrupted stretch, from its metrics.csv (read while the
    run may be writing it: a partial last row is skipped silently)."""
    rows = read_metrics(run, quiet=True)
    if not rows:
        return None
    start = len(rows) - 1
    while start > 0 and rows[start - 1]["wall_time_s"] < rows[start]["wall_time_s"]:
        start -= 1  # wall time restarts at 0 when a run resumes
    first, last = rows[start], rows[-1]
    if last is first:
        return last["timesteps"] / last["wall_time_s"] if last["wall_time_s"] > 0 and start == 0 else None
    dt = last["wall_time_s"] - first["wall_time_s"]
    return (last["timesteps"] - first["timesteps"]) / dt if dt > 0 else None
