"""Run, results and output folders handed over by someone else (issue 35): no symbolic link in them
is followed, nothing outside them is read or written, every writer of a run holds its lock, and a
published run is checked against its manifest before anything reads it.

Each test builds a decoy tree beside the folder (the user's own files), points links at it, and
checks that its files are byte for byte what they were."""

from __future__ import annotations

import builtins
import hashlib
import io
import json
import os
import shutil
import zipfile
from pathlib import Path

import pytest

from containergym_marl.files import UnsafePathError, atomic_write_text
from containergym_marl.manifest import ManifestError, read_manifest
from containergym_marl.orchestration import publish as publish_results
from containergym_marl.orchestration.tasks import RunSpec, train_run
from containergym_marl.rundir import METRIC_FIELDS, RunError, RunLock, append_metrics
from containergym_marl.training import TrainArgs, train

CONFIG = "n5_m2_dt120"
FINISHED, INTERRUPTED = f"ppo_{CONFIG}_s1", f"ppo_{CONFIG}_s2"
TINY = dict(n_envs=2, hyperparams={"n_steps": 64, "batch_size": 64}, overrides={"episode_length_steps": 50})
LINKED = "is a symbolic link; nothing inside a run, results or output folder may be"


def _decoy(tmp_path: Path) -> Path:
    """The user's own files, outside every folder the package is given."""
    decoy = tmp_path / "decoy"
    (decoy / "folder").mkdir(parents=True)
    (decoy / "secret.txt").write_text("the user's own file\n")
    (decoy / "folder" / "ckpt_999_steps.zip").write_bytes(_model(b"the user's model"))
    (decoy / "folder" / "notes.txt").write_text("notes\n")
    return decoy


def _snapshot(folder: Path) -> dict[str, str]:
    """sha256 of every file below ``folder`` but hidden ones (a lock file's holder line changes)."""
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file() and not p.name.startswith(".")}


def _model(tag: bytes) -> bytes:
    """A stand-in SB3 model file: a zip with the members check_model_file asks for (publish and
    restore copy models; they never load them)."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as z:
        z.writestr("data", tag)
        z.writestr("policy.pth", tag)
    return buffer.getvalue()


def _fake_run(run: Path, finished: bool, timesteps: int = 256) -> Path:
    """A run directory as training leaves it, finished or interrupted after a checkpoint at 128."""
    run.mkdir(parents=True)
    (run / "args.json").write_text(json.dumps({"algo": "ppo", "config": CONFIG, "seed": 1, "timesteps": timesteps,
                                               "n_envs": 2}))
    (run / "config.toml").write_text("# the plant\n")
    (run / "metrics.csv").write_text(",".join(METRIC_FIELDS) + "\n128,1,1.0,50.0,1.0,1,0.5\n")
    (run / "best_model.zip").write_bytes(_model(b"best"))
    if finished:
        (run / "final_model.zip").write_bytes(_model(b"final"))
        (run / "run.json").write_text("{}")
    else:
        (run / "checkpoints").mkdir()
        (run / "checkpoints" / "ckpt_128_steps.zip").write_bytes(_model(b"ckpt"))
        (run / "checkpoints" / "ckpt_128_steps.json").write_text("{}")
    return run


def _published(tmp_path: Path) -> tuple[Path, Path, Path]:
    """compare's runs and out folders (a finished and an interrupted run) and what publish made of them."""
    runs, out, to = tmp_path / "runs", tmp_path / "cmp", tmp_path / "results"
    _fake_run(runs / FINISHED, finished=True)
    _fake_run(runs / INTERRUPTED, finished=False)
    (out / "evaluations").mkdir(parents=True)
    publish_results.publish(runs, out, to, with_checkpoints=True)
    return runs, out, to


# ---- the files.py rule ----------------------------------------------------------------------------
def test_atomic_write_refuses_a_link_below_the_folder_it_was_given_and_only_there(tmp_path):
    decoy = _decoy(tmp_path)
    before = _snapshot(decoy)
    (tmp_path / "disk").mkdir()
    (tmp_path / "home").symlink_to(tmp_path / "disk")  # the user's home on another disk: allowed
    out = tmp_path / "home" / "out"
    atomic_write_text(out / "evaluations" / "a.json", "{}", within=out)
    assert (tmp_path / "disk" / "out" / "evaluations" / "a.json").read_text() == "{}"
    (out / "tb").symlink_to(decoy / "folder")
    with pytest.raises(UnsafePathError, match=rf"out/tb' {LINKED}"):
        atomic_write_text(out / "tb" / "events", "x", within=out)
    (out / "run.json").symlink_to(decoy / "secret.txt")
    with pytest.raises(UnsafePathError, match=rf"run.json' {LINKED}"):
        atomic_write_text(out / "run.json", "{}")  # without ``within``: the file itself
    with pytest.raises(UnsafePathError, match="is not inside"):
        atomic_write_text(out / ".." / "escaped.json", "{}", within=out)
    assert _snapshot(decoy) == before and not (tmp_path / "disk" / "escaped.json").exists()


# ---- row 1: a linked .lock ------------------------------------------------------------------------
@pytest.mark.parametrize("writer", ["lock", "train", "train --resume", "compare --train"])
def test_a_linked_lock_file_is_refused_and_the_linked_file_is_untouched(tmp_path, writer):
    """Every writer of a run takes its lock; the lock file is opened without following a link. (It
    was opened through the link and truncated, even by a ``train`` then refused for the results
    the directory holds.)"""
    decoy = _decoy(tmp_path)
    before = _snapshot(decoy)
    run = tmp_path / "runs" / FINISHED
    run.mkdir(parents=True)
    (run / "args.json").write_text(json.dumps({"algo": "ppo", "config": CONFIG, "seed": 1, "n_envs": 2}))
    (run / ".lock").symlink_to(decoy / "secret.txt")
    with pytest.raises(UnsafePathError, match=rf"\.lock' {LINKED}"):
        if writer == "lock":
            RunLock(run).acquire()
        elif writer == "compare --train":  # the sweep's training task
            train_run(RunSpec(FINISHED, "ppo", "ppo", CONFIG, 1, 128, str(run), train=TINY))
        else:
            train(TrainArgs(algo="ppo", out=str(run), timesteps=128, progress_bar=False,
                            resume=writer == "train --resume", **TINY))
    assert _snapshot(decoy) == before
    assert sorted(p.name for p in run.iterdir()) == [".lock", "args.json"]


# ---- row 2: a linked metrics.csv or sweep log ------------------------------------------------------
def test_a_linked_metrics_file_gets_no_rows(tmp_path):
    decoy = _decoy(tmp_path)
    before = _snapshot(decoy)
    run = _fake_run(tmp_path / "run", finished=False)
    (run / "metrics.csv").unlink()
    (run / "metrics.csv").symlink_to(decoy / "secret.txt")
    row = dict.fromkeys(METRIC_FIELDS, 1.0)
    with pytest.raises(UnsafePathError, match=rf"metrics.csv' {LINKED}"):
        append_metrics(run, row)
    # --resume stops at the lock, which finds the link, before it truncates or appends anything
    with pytest.raises(UnsafePathError, match=rf"metrics.csv' {LINKED}"):
        train(TrainArgs(algo="ppo", out=str(run), timesteps=256, resume=True, progress_bar=False, **TINY))
    assert _snapshot(decoy) == before


@pytest.mark.parametrize("linked", ["log", ".sweep"])
def test_a_linked_sweep_log_gets_no_line_and_the_run_is_not_touched(tmp_path, linked):
    decoy = _decoy(tmp_path)
    before = _snapshot(decoy)
    runs = tmp_path / "runs"
    runs.mkdir()
    if linked == "log":
        (runs / ".sweep").mkdir()
        (runs / ".sweep" / f"{FINISHED}.log").symlink_to(decoy / "secret.txt")
    else:
        (runs / ".sweep").symlink_to(decoy / "folder")
    spec = RunSpec(FINISHED, "ppo", "ppo", CONFIG, 1, 128, str(runs / FINISHED), train=TINY)
    with pytest.raises(UnsafePathError, match=LINKED):
        train_run(spec)
    assert _snapshot(decoy) == before
    assert [p.name for p in (runs / FINISHED).iterdir()] == [".lock"]  # nothing trained


# ---- row 3: publish into a results folder with links -----------------------------------------------
@pytest.mark.parametrize("linked", [f"runs/{FINISHED}/checkpoints", f"runs/{FINISHED}", f"evaluations/{CONFIG}"])
def test_publish_into_a_results_folder_with_a_link_touches_nothing_outside(tmp_path, linked):
    """It emptied a linked checkpoints/ folder (then crashed), wrote models into a linked run
    folder and evaluations into a linked one, which the manifest then left out."""
    runs, out, to = _published(tmp_path)
    decoy = _decoy(tmp_path)
    before = _snapshot(decoy)
    link = to / linked
    if link.exists():
        shutil.rmtree(link)
    link.parent.mkdir(parents=True, exist_ok=True)
    link.symlink_to(decoy / "folder")
    (out / "evaluations" / CONFIG).mkdir(parents=True)
    (out / "evaluations" / CONFIG / "ppo_s1.json").write_text("{}")
    results = _snapshot(to)
    with pytest.raises(UnsafePathError, match=rf"{linked}' {LINKED}"):
        publish_results.publish(runs, out, to, with_checkpoints=True)
    assert _snapshot(decoy) == before and _snapshot(to) == results


def test_publish_never_copies_a_linked_file_of_a_run_into_the_results(tmp_path):
    runs, out, to = _published(tmp_path)
    decoy = _decoy(tmp_path)
    (runs / FINISHED / "run.json").unlink()
    (runs / FINISHED / "run.json").symlink_to(decoy / "secret.txt")
    with pytest.raises(UnsafePathError, match=rf"run.json' {LINKED}"):
        publish_results.publish(runs, out, to)
    assert (to / "runs" / FINISHED / "run.json").read_text() == "{}"


# ---- rows 4 and 5, and args.json: restore checks a published run before it reads it ----------------
def test_restore_refuses_a_linked_checkpoints_folder_and_an_unlisted_checkpoint(tmp_path):
    """copytree followed the link and copied a checkpoint the manifest does not list, unchecked."""
    _, _, to = _published(tmp_path)
    src = to / "runs" / INTERRUPTED
    outside = tmp_path / "outside"
    shutil.move(src / "checkpoints", outside)
    (outside / "ckpt_999_steps.zip").write_bytes(_model(b"unlisted"))
    (src / "checkpoints").symlink_to(outside)
    fresh, fresh_out = tmp_path / "fresh", tmp_path / "fresh_cmp"
    with pytest.raises(UnsafePathError, match=rf"checkpoints' {LINKED}"):
        publish_results.restore(to, fresh, fresh_out)
    assert not fresh.exists()
    (src / "checkpoints").unlink()
    shutil.copytree(outside, src / "checkpoints")  # the same files, plain: the unlisted one is refused
    with pytest.raises(ManifestError, match=rf"{INTERRUPTED}/checkpoints/ckpt_999_steps.zip: not listed"):
        publish_results.restore(to, fresh, fresh_out)
    assert not fresh.exists()


@pytest.fixture
def never_opened(monkeypatch):
    """The paths added to the returned list may not be opened (by os.open, open or pathlib)."""
    guarded: list[Path] = []

    def guard(real):
        def opener(path, *args, **kwargs):
            if isinstance(path, (str, os.PathLike)) and Path(path) in guarded:
                raise AssertionError(f"{path} was opened")
            return real(path, *args, **kwargs)
        return opener

    for module in (os, io, builtins):
        monkeypatch.setattr(module, "open", guard(module.open))
    return guarded


def test_restore_never_reads_a_large_file_unlisted_or_of_another_size(tmp_path, never_opened):
    """An 8 GB sparse file in a published run's tb/ was read whole into memory (before the suffix
    filter); a file the manifest lists is checked by size before it is hashed."""
    _, _, to = _published(tmp_path)
    big = to / "runs" / FINISHED / "tb" / "events.out.tfevents"
    big.parent.mkdir()
    with open(big, "wb") as f:
        f.truncate(8 * 2**30)  # sparse: no disk used
    never_opened.append(big)
    with pytest.raises(ManifestError, match=f"{FINISHED}/tb/events.out.tfevents: not listed"):
        publish_results.restore(to, tmp_path / "fresh", tmp_path / "fresh_cmp")
    shutil.rmtree(big.parent)
    model = to / "runs" / FINISHED / "best_model.zip"
    model.unlink()
    with open(model, "wb") as f:
        f.truncate(8 * 2**30)
    never_opened.append(model)
    with pytest.raises(ManifestError, match=f"{FINISHED}/best_model.zip: its size differs"):
        publish_results.restore(to, tmp_path / "fresh", tmp_path / "fresh_cmp")
    assert not (tmp_path / "fresh").exists()


def test_restore_refuses_a_published_run_whose_args_changed(tmp_path):
    """args.json decides what a run is and how far it got: edited (a larger budget), it made restore
    clear the user's finished run and put the published one, to be trained again, in its place."""
    _, _, to = _published(tmp_path)
    assert f"runs/{FINISHED}/args.json" in read_manifest(to)
    fresh, fresh_out = tmp_path / "fresh", tmp_path / "fresh_cmp"
    assert publish_results.restore(to, fresh, fresh_out)["runs"] == [FINISHED, INTERRUPTED]
    before = _snapshot(fresh)
    args = to / "runs" / FINISHED / "args.json"
    args.write_text(args.read_text().replace('"timesteps": 256', '"timesteps": 999'))
    with pytest.raises(ManifestError, match=f"{FINISHED}/args.json: its sha256 differs"):
        publish_results.restore(to, fresh, fresh_out)
    assert _snapshot(fresh) == before


# ---- row 6: the run's lock, held by publish and restore while they copy ----------------------------
def test_publish_refuses_a_run_that_a_process_trains(tmp_path):
    """publish took no lock: it deleted the checkpoints of a run being trained in the results
    folder and replaced its files."""
    runs, out, to = _published(tmp_path)
    dst = to / "runs" / FINISHED
    (dst / "checkpoints").mkdir()
    (dst / "checkpoints" / "ckpt_128_steps.zip").write_bytes(_model(b"the trainer's"))
    (runs / FINISHED / "best_model.zip").write_bytes(_model(b"a newer best"))
    before = _snapshot(dst)
    with RunLock(dst):
        with pytest.raises(RunError, match=rf"{FINISHED}' is in use by another writer \(pid {os.getpid()} "):
            publish_results.publish(runs, out, to)
    assert _snapshot(dst) == before


@pytest.fixture
def writes_while_unlocked(monkeypatch):
    """Every file written into a run folder under the returned list's first element (the folder of
    runs), with whether that run's lock was held by another open file (the writer's) at the time."""
    seen: list = []

    def unlocked(dst) -> bool:
        rel = Path(dst).relative_to(seen[0])
        try:
            RunLock(seen[0] / rel.parts[0]).acquire().release()
        except RunError:
            return False
        return True

    def watch(real):
        def write(src, dst, *args, **kwargs):
            if seen and Path(dst).is_relative_to(seen[0]):
                seen.append((Path(dst).name, unlocked(dst)))
            return real(src, dst, *args, **kwargs)
        return write

    monkeypatch.setattr(os, "replace", watch(os.replace))
    monkeypatch.setattr(shutil, "copyfile", watch(shutil.copyfile))
    return seen


def test_restore_copies_only_while_it_holds_the_run_s_lock(tmp_path, writes_while_unlocked):
    """restore released the lock after clearing the run, then copied into it."""
    _, _, to = _published(tmp_path)
    fresh = tmp_path / "fresh"
    writes_while_unlocked.append(fresh)
    with RunLock(fresh / FINISHED):
        with pytest.raises(RunError, match=rf"{FINISHED}' is in use by another writer \(pid {os.getpid()} "):
            publish_results.restore(to, fresh, tmp_path / "fresh_cmp")
    assert [p.name for p in (fresh / FINISHED).iterdir()] == [".lock"]
    shutil.rmtree(fresh)
    assert publish_results.restore(to, fresh, tmp_path / "fresh_cmp")["runs"] == [FINISHED, INTERRUPTED]
    copied = writes_while_unlocked[1:]
    assert {"args.json", "best_model.zip", "ckpt_128_steps.zip"} <= {name for name, _ in copied}
    assert [name for name, unlocked in copied if unlocked] == []


def test_publish_copies_only_while_it_holds_the_run_s_lock(tmp_path, writes_while_unlocked):
    runs, out, to = _published(tmp_path)
    (runs / FINISHED / "best_model.zip").write_bytes(_model(b"a newer best"))
    writes_while_unlocked.append(to / "runs")
    publish_results.publish(runs, out, to, with_checkpoints=True)
    copied = writes_while_unlocked[1:]
    assert {"args.json", "best_model.zip", "ckpt_128_steps.zip"} <= {name for name, _ in copied}
    assert [name for name, unlocked in copied if unlocked] == []
