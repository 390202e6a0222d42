"""Checkpoints of a training run: what one carries besides the model (:class:`TrainingProgress`, the
best-model tracker), how often they are taken, saving them crash-safe and reading them back.

Checkpoint names and their integrity are :mod:`containergym_marl.rundir`'s.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
import warnings
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from containergym_marl.files import atomic_write, atomic_write_text, sync_file
from containergym_marl.policies.actor_critic import ZIP_ERRORS
from containergym_marl.rundir import RunWarning, checkpoint_files


def atomic_save_model(model: Any, path: str | Path) -> Path:
    """``model.save`` to a temporary file, then renamed over ``path``."""
    return atomic_write(path, lambda tmp: _save_via_file(model.save, tmp))


def _save_via_file(save: Callable[[Any], None], tmp: Path) -> None:
    with open(tmp, "wb") as f:  # a file object: SB3 would otherwise append ".zip"/".pkl" to the name
        save(f)



WINDOW = 100  # training episodes in the best-model criterion (as SB3's episode buffer)


@dataclass
class TrainingProgress:
    """The state of the best-model tracker: training episodes finished so far, the returns and
    lengths of the last :data:`WINDOW` of them (and whether each reached the time limit rather than
    overflowing, where the trainer tells), the best window mean and when it was reached."""

    episodes: int = 0
    returns: list[float] = field(default_factory=list)
    lengths: list[int] = field(default_factory=list)
    best_train_return: float = -math.inf
    best_timesteps: int | None = None
    wall_time_s: float = 0.0
    truncated: list[bool] = field(default_factory=list)
    # CPU seconds of the training process (all its threads); None when a segment before went unmeasured
    cpu_time_s: float | None = 0.0

    def add_episode(self, ret: float, length: int, truncated: bool | None = None) -> None:
        self.episodes += 1
        self.returns = (self.returns + [float(ret)])[-WINDOW:]
        self.lengths = (self.lengths + [int(length)])[-WINDOW:]
        if truncated is not None:
            self.truncated = (self.truncated + [bool(truncated)])[-WINDOW:]

    @property
    def time_limit_share(self) -> float:
        """The share of the windowed episodes that reached the time limit (nan if none is known)."""
        return sum(self.truncated) / len(self.truncated) if self.truncated else math.nan

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
                   best_timesteps=data.get("best_timesteps"), wall_time_s=float(data.get("wall_time_s", 0.0)),
                   truncated=[bool(x) for x in data.get("truncated", [])][-WINDOW:],
                   cpu_time_s=None if data.get("cpu_time_s") is None else float(data["cpu_time_s"]))


class SegmentClock:
    """The wall and CPU time of one training segment (a resumed run's earlier segments are what its
    ``progress`` holds already): :meth:`wall` for metrics rows, :meth:`update` into ``progress``."""

    def __init__(self, progress: TrainingProgress):
        self.progress = progress
        self._wall0, self._cpu0 = progress.wall_time_s, progress.cpu_time_s
        self._t0, self._c0 = time.perf_counter(), time.process_time()

    def wall(self) -> float:
        return round(self._wall0 + time.perf_counter() - self._t0, 2)

    def update(self) -> TrainingProgress:
        self.progress.wall_time_s = self.wall()
        if self._cpu0 is not None:
            self.progress.cpu_time_s = round(self._cpu0 + time.process_time() - self._c0, 2)
        return self.progress


def checkpoint_interval(budget: int, num_slots: int, every: int | None = None) -> int:
    """Samples between checkpoints: ``every`` if given, else min(200k, budget / 10), in whole
    vector steps (``num_slots`` samples each) and at least one, so a run of any budget leaves
    checkpoints before its end (once its first rollout is done) and an interruption loses at most
    a tenth of it."""
    samples = every if every is not None else min(200_000, budget // 10)
    return max(samples // num_slots, 1) * num_slots


def sync_run_files(run: Path, best: Path) -> None:
    """Flush to disk what a native trainer writes without flushing (metrics.csv, the best model),
    before a checkpoint vouches for them or the run is marked finished."""
    sync_file(Path(run) / "metrics.csv")
    sync_file(best)


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
    sync_run_files(run, best)
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


#: Bytes a .npy header may take beyond its array's data (numpy reads at most 10,000 by default).
_NPY_HEADER_BYTES = 16_384


def load_replay_buffer(model: Any, path: Path) -> None:
    """Fill the model's replay buffer from :func:`save_replay_buffer`'s file; a ValueError naming the
    file and the array when it does not fit the buffer. Every array's declared size and header (shape
    and dtype) are checked before it is read, so a small crafted file cannot make us allocate more
    than the buffer itself; then the write position (0 ≤ pos < buffer_size) and the actions (within the
    action space). Nothing is pickled; the buffer's ``pos`` and ``full`` are set last, so a file found
    bad part-way leaves the buffer empty."""
    import numpy as np

    buffer = model.replay_buffer
    source = f"replay buffer {str(path)!r}"
    mine = {name: getattr(buffer, name) for name in REPLAY_ARRAYS if getattr(buffer, name, None) is not None}
    wanted = {**mine, "pos": np.zeros((), np.int64), "full": np.zeros((), np.bool_)}
    try:
        with zipfile.ZipFile(path) as archive:
            for name, array in wanted.items():
                _check_npy_header(archive, name, array, source)
            pos, full = _read_npy(archive, "pos"), _read_npy(archive, "full")
            if not 0 <= pos < buffer.buffer_size:
                raise ValueError(f"{source}: pos={int(pos)} lies outside the buffer [0, {buffer.buffer_size})")
            read = {}
            if "actions" in mine and hasattr(buffer.action_space, "n"):
                actions = read["actions"] = _read_npy(archive, "actions")
                if actions.size and not (0 <= actions.min() and actions.max() < buffer.action_space.n):
                    raise ValueError(f"{source}: actions must lie in [0, {buffer.action_space.n}), got "
                                     f"{actions.min()} to {actions.max()}")
            for name, array in mine.items():
                array[...] = read[name] if name in read else _read_npy(archive, name)
    except ZIP_ERRORS as exc:
        raise ValueError(f"{source} is unreadable ({exc})") from exc
    buffer.pos, buffer.full = int(pos), bool(full)


def _check_npy_header(archive: zipfile.ZipFile, name: str, like: Any, source: str) -> None:
    """Member ``name``.npy of ``archive`` declares no more bytes than ``like`` (plus a header) and its
    header says ``like``'s shape and dtype (a ValueError naming ``source`` and ``name`` otherwise)."""
    import numpy as np

    try:
        info = archive.getinfo(f"{name}.npy")
    except KeyError:
        raise ValueError(f"{source}: no {name} array") from None
    if info.file_size > like.nbytes + _NPY_HEADER_BYTES:
        raise ValueError(f"{source}: {name} unpacks to {info.file_size} bytes; the buffer's {like.shape} "
                         f"{like.dtype} array has {like.nbytes}")
    with archive.open(info) as f:
        try:
            major, _ = np.lib.format.read_magic(f)
            read_header = np.lib.format.read_array_header_1_0 if major == 1 else np.lib.format.read_array_header_2_0
            shape, _, dtype = read_header(f)
        except (ValueError, TypeError, SyntaxError) as exc:
            raise ValueError(f"{source}: {name} has no readable .npy header ({exc})") from None
    if shape != like.shape or dtype != like.dtype:
        raise ValueError(f"{source}: {name} is a {shape} {dtype} array; the buffer's is {like.shape} {like.dtype}")


def _read_npy(archive: zipfile.ZipFile, name: str) -> Any:
    """The array of member ``name``.npy (its header checked by :func:`_check_npy_header`)."""
    import numpy as np

    with archive.open(f"{name}.npy") as f:
        return np.lib.format.read_array(f, allow_pickle=False)


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
