"""Checkpoints of a training run: what one carries besides the model (:class:`TrainingProgress`, the
best-model tracker), how often they are taken, saving them crash-safe and reading them back.

Checkpoint names and their integrity are :mod:`containergym_marl.rundir`'s.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from containergym_marl.files import atomic_write, atomic_write_text
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
                   truncated=[bool(x) for x in data.get("truncated", [])][-WINDOW:])


def checkpoint_interval(budget: int, num_slots: int, every: int | None = None) -> int:
    """Samples between checkpoints: ``every`` if given, else min(200k, budget / 10), in whole
    vector steps (``num_slots`` samples each) and at least one, so a run of any budget leaves
    checkpoints before its end (once its first rollout is done) and an interruption loses at most
    a tenth of it."""
    samples = every if every is not None else min(200_000, budget // 10)
    return max(samples // num_slots, 1) * num_slots


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
