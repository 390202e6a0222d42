"""Run directories survive interruptions and refuse bad use: checkpoints that fit the budget,
broken files detected (and skipped), crash-safe writes, resume without duplicated metrics, one
writer per directory, clear errors for bad CLI values and missing extras (issues 12 and 14)."""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from containergym_marl.cli import main as cli_main
from containergym_marl.evaluation import EvalProtocol
from containergym_marl.evaluation.run_policies import evaluate_run, policy_from_run
from containergym_marl.training import RunError, RunWarning, TrainArgs, train
from containergym_marl.files import atomic_write_text
from containergym_marl.rundir import checkpoint_files, checkpoints, read_metrics, read_run_summary, RunLock
from containergym_marl.training.checkpoints import checkpoint_interval, read_progress

# RunWarnings are what these tests provoke; each test asserts the ones it is about.
pytestmark = pytest.mark.filterwarnings("ignore::containergym_marl.rundir.RunWarning")
REPO = Path(__file__).resolve().parents[2]
# 2 simulations, rollouts of 64 x 2 = 128 samples, training episodes of T = 50 steps (they finish)
TINY = dict(n_envs=2, progress_bar=False, hyperparams={"n_steps": 64, "batch_size": 64},
            overrides={"episode_length_steps": 50})


@pytest.fixture(scope="module")
def base_run(tmp_path_factory):
    """A finished run: rows at 128, 256, 384, 512 samples; checkpoints at 128, 256, 384."""
    out = tmp_path_factory.mktemp("base") / "run"
    return train(TrainArgs(algo="ppo", out=str(out), timesteps=512, checkpoint_every=128, **TINY))


@pytest.fixture
def run_copy(base_run, tmp_path):
    dst = tmp_path / "run"
    shutil.copytree(base_run, dst)
    return dst


def _steps(run) -> list[int]:
    return [int(r["timesteps"]) for r in read_metrics(run)]


# ---- checkpoints that fit the budget --------------------------------------------------------------
def test_checkpoint_interval_derives_from_the_budget():
    assert checkpoint_interval(2_000_000, 8) == 200_000
    assert checkpoint_interval(30_000, 8) == 3_000
    assert checkpoint_interval(30_000, 40) == 3_000
    assert checkpoint_interval(30_848, 8) == 3_080  # whole vector steps
    assert checkpoint_interval(50, 8) == 8  # at least one vector step
    assert checkpoint_interval(30_000, 8, every=1000) == 1000


def test_a_small_budget_leaves_checkpoints_so_an_interrupted_run_resumes(tmp_path):
    """The default interval (it was 200k samples) gives a budget of 1024 checkpoints before its end."""
    run = train(TrainArgs(algo="ppo", out=str(tmp_path / "r"), timesteps=1024, **TINY))
    saved = json.loads((run / "args.json").read_text())
    assert saved["checkpoint_every"] == 102
    steps = [s for s, _ in checkpoints(run)]
    assert steps and max(steps) < 1024
    # an interruption (no final model) resumes from the newest checkpoint
    (run / "final_model.zip").unlink()
    train(TrainArgs(algo="ppo", out=str(run), timesteps=1024, resume=True, **TINY))
    assert (run / "final_model.zip").is_file()


# ---- resume: metrics, episode window and best model as at the checkpoint -------------------------
def test_checkpoint_progress_matches_the_metrics(base_run):
    rows = {int(r["timesteps"]): r for r in read_metrics(base_run)}
    assert sorted(rows) == [128, 256, 384, 512]
    assert [s for s, _ in checkpoints(base_run)] == [384, 256, 128]
    for steps in (128, 256, 384):
        progress = read_progress(base_run, steps)
        assert progress.episodes == rows[steps]["episodes"]
        assert len(progress.returns) == min(progress.episodes, 100)
        assert np.mean(progress.returns) == pytest.approx(rows[steps]["train_return_mean100"])
        assert progress.best_train_return == pytest.approx(rows[steps]["best_train_return"])


def test_a_run_records_its_cpu_time_and_a_resume_adds_to_the_checkpoints(run_copy):
    """run.json's cpu_time_s: the training process's CPU seconds, carried by each checkpoint and
    continued by a resumed run; a checkpoint from before CPU times were kept leaves it unknown (None)."""
    run = run_copy
    at_384 = read_progress(run, 384)
    assert 0 < read_progress(run, 128).cpu_time_s <= at_384.cpu_time_s <= read_run_summary(run)["cpu_time_s"]
    (run / "final_model.zip").unlink()
    with pytest.warns(RunWarning, match="dropped 1 row"):
        train(TrainArgs(algo="ppo", out=str(run), timesteps=640, resume=True, **TINY))
    assert read_run_summary(run)["cpu_time_s"] > at_384.cpu_time_s
    progress_file = next(p for p in (run / "checkpoints").glob("*.json") if "384" in p.name)
    data = json.loads(progress_file.read_text())
    del data["cpu_time_s"]  # as written before
    progress_file.write_text(json.dumps(data))
    (run / "final_model.zip").unlink()
    for steps in (512,):
        for f in checkpoint_files(run, steps).values():
            f.unlink(missing_ok=True)
    with pytest.warns(RunWarning):
        train(TrainArgs(algo="ppo", out=str(run), timesteps=640, resume=True, **TINY))
    assert read_run_summary(run)["resumed_from"] == 384 and read_run_summary(run)["cpu_time_s"] is None


def test_segment_clock_adds_a_segments_time_to_the_progress():
    from containergym_marl.training.checkpoints import SegmentClock, TrainingProgress

    progress = TrainingProgress(wall_time_s=10.0, cpu_time_s=5.0)
    clock = SegmentClock(progress)
    end = time.process_time() + 0.05
    while time.process_time() < end:  # a segment of some CPU work
        pass
    clock.update()
    assert progress.wall_time_s >= 10.05 and progress.cpu_time_s >= 5.04
    unknown = TrainingProgress(wall_time_s=1.0, cpu_time_s=None)
    SegmentClock(unknown).update()
    assert unknown.cpu_time_s is None and unknown.wall_time_s >= 1.0
    assert TrainingProgress.from_json(json.dumps({"episodes": 0, "returns": [], "lengths": []})).cpu_time_s is None


def test_resume_from_an_older_checkpoint_restores_its_state(run_copy):
    """The checkpoint at 256 is older than the last metrics row (512): resuming there drops the
    rows after it, and the episode counter, window and best model are the checkpoint's."""
    run = run_copy
    for steps in (384,):  # the newest checkpoint is lost: the run was killed before it was written
        for f in checkpoint_files(run, steps).values():
            f.unlink(missing_ok=True)
    (run / "final_model.zip").unlink()
    snapshot = checkpoint_files(run, 256)["best"].read_bytes()
    with pytest.warns(RunWarning, match="dropped 2 row"):
        # a budget equal to the checkpoint: nothing more to train, the state is the checkpoint's
        train(TrainArgs(algo="ppo", out=str(run), timesteps=256, resume=True, **TINY))
    assert _steps(run) == [128, 256]
    assert (run / "best_model.zip").read_bytes() == snapshot
    summary = read_run_summary(run)
    assert summary["episodes"] == read_progress(run, 256).episodes == read_metrics(run)[-1]["episodes"]
    assert summary["resumed_from"] == 256


def test_resume_continues_metrics_without_duplicates_and_the_bar_stops_at_the_budget(run_copy, monkeypatch):
    run = run_copy

    class Terminal(io.StringIO):  # the bar is drawn on a terminal only
        def isatty(self) -> bool:
            return True

    monkeypatch.setattr(sys, "stderr", Terminal())
    monkeypatch.setenv("COLUMNS", "200")
    (run / "final_model.zip").unlink()
    before = {int(r["timesteps"]): r["episodes"] for r in read_metrics(run)}
    with pytest.warns(RunWarning, match="dropped 1 row"):  # the row at 512, after the checkpoint at 384
        train(TrainArgs(algo="ppo", out=str(run), timesteps=700, resume=True, **{**TINY, "progress_bar": True}))
    steps = _steps(run)
    assert steps == [128, 256, 384, 512, 640, 768]  # whole rollouts of 128 up to the budget, each once
    rows = read_metrics(run)
    episodes = [r["episodes"] for r in rows]
    assert episodes[:3] == [before[128], before[256], before[384]]
    assert all(b > a for a, b in zip(episodes, episodes[1:]))  # the counter continues, never restarts
    bars = re.findall(r"([\d,]+)/([\d,]+) samples", sys.stderr.getvalue())
    assert bars and all(int(n) <= int(total) == 700 for n, total in bars)
    assert bars[0][0] == "384" and bars[-1][0] == "700"  # from the checkpoint to the budget, not beyond


def test_resume_of_a_run_from_before_progress_files(run_copy):
    """Run directories written before checkpoints carried progress files (and before run.json)
    still resume: the episode counter continues from metrics.csv, the best model is kept."""
    run = run_copy
    for p in [*run.glob("checkpoints/*.json"), *run.glob("checkpoints/best_model_*"), run / "run.json",
              run / "final_model.zip"]:
        p.unlink()
    best = (run / "best_model.zip").read_bytes()
    episodes_at_384 = read_metrics(run)[2]["episodes"]
    with pytest.warns(RunWarning, match="dropped 1 row"):
        train(TrainArgs(algo="ppo", out=str(run), timesteps=640, resume=True, **TINY))
    rows = read_metrics(run)
    assert _steps(run) == [128, 256, 384, 512, 640]
    assert rows[3]["episodes"] > episodes_at_384 and rows[4]["episodes"] > rows[3]["episodes"]
    assert any(r["saved_best"] for r in rows[3:]) or (run / "best_model.zip").read_bytes() == best


# ---- broken files ---------------------------------------------------------------------------------
def _cut(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def test_resume_skips_a_checkpoint_cut_short(run_copy):
    run = run_copy
    (run / "final_model.zip").unlink()
    _cut(checkpoint_files(run, 384)["model"])
    with pytest.warns(RunWarning, match=r"ckpt_384_steps.zip.*broken"):
        train(TrainArgs(algo="ppo", out=str(run), timesteps=512, resume=True, **TINY))
    assert read_run_summary(run)["resumed_from"] == 256
    assert (run / "checkpoints" / "ckpt_384_steps.zip.broken").is_file()
    assert _steps(run) == [128, 256, 384, 512]


def test_resume_skips_a_checkpoint_whose_progress_file_was_not_written(run_copy):
    """Killed between the checkpoint's model and its progress file: that checkpoint is incomplete."""
    run = run_copy
    (run / "final_model.zip").unlink()
    checkpoint_files(run, 384)["progress"].unlink()
    with pytest.warns(RunWarning, match="ckpt_384_steps.zip is incomplete"):
        train(TrainArgs(algo="ppo", out=str(run), timesteps=512, resume=True, **TINY))
    assert read_run_summary(run)["resumed_from"] == 256


def test_resume_without_an_intact_checkpoint_starts_again(run_copy):
    """Every checkpoint broken: the rerun starts from the beginning and gives the uninterrupted run."""
    run = run_copy
    final = (run / "final_model.zip").read_bytes()
    (run / "final_model.zip").unlink()
    for _, path in checkpoints(run):
        _cut(path)
    with pytest.warns(RunWarning, match="starts again from the beginning"):
        train(TrainArgs(algo="ppo", out=str(run), timesteps=512, resume=True, checkpoint_every=128, **TINY))
    from containergym_marl.models import load_model

    a = load_model(run / "final_model.zip", "ppo").policy.state_dict()
    (run / "x.zip").write_bytes(final)
    b = load_model(run / "x.zip", "ppo").policy.state_dict()
    assert all((a[k] == b[k]).all() for k in a)


def test_evaluate_says_a_model_file_is_broken(run_copy, capsys):
    _cut(run_copy / "best_model.zip")
    assert cli_main(["evaluate", str(run_copy), "--episodes", "1"]) == 2
    err = capsys.readouterr().err
    assert "best_model.zip" in err and "broken" in err and "Traceback" not in err


def test_read_metrics_ignores_a_partial_last_row(run_copy):
    path = run_copy / "metrics.csv"
    text = path.read_text()
    path.write_text(text + "640,99,-1.5")  # a row cut short by a kill
    with pytest.warns(RunWarning, match="row 6 is incomplete"):
        rows = read_metrics(run_copy)
    assert [int(r["timesteps"]) for r in rows] == [128, 256, 384, 512]
    path.write_text(text + "640,99,-1.5,10.0,-1.0,0,3.2")  # every field, but no line end: still cut
    with pytest.warns(RunWarning, match="cut short"):
        assert len(read_metrics(run_copy)) == 4


def test_metrics_files_of_both_headers_read_and_truncate(tmp_path):
    """A native run's rows carry the update diagnostics (nan where a phase has none); an older file
    without them keeps its header when rows are appended, and both kinds truncate row by row."""
    from containergym_marl.rundir import METRIC_FIELDS, UPDATE_FIELDS, append_metrics, truncate_metrics

    base = dict(episodes=1, train_return_mean100=2.0, train_episode_length_mean100=3.0, best_train_return=2.0,
                saved_best=0, wall_time_s=1.0)
    new = tmp_path / "new"
    new.mkdir()
    for steps in (100, 200, 300):
        append_metrics(new, {"timesteps": steps, **base, **dict.fromkeys(UPDATE_FIELDS, float("nan")),
                             "entropy": 0.5 if steps > 100 else float("nan")})
    rows = read_metrics(new)
    assert [r["entropy"] for r in rows][1:] == [0.5, 0.5] and np.isnan(rows[0]["entropy"])
    assert truncate_metrics(new, 200) == 1 and [r["timesteps"] for r in read_metrics(new)] == [100, 200]
    old = tmp_path / "old"
    old.mkdir()
    append_metrics(old, {"timesteps": 100, **base})
    append_metrics(old, {"timesteps": 200, **base, **dict.fromkeys(UPDATE_FIELDS, 0.1)})  # a resumed run
    assert (old / "metrics.csv").read_text().splitlines()[0] == ",".join(METRIC_FIELDS)
    assert [set(r) for r in read_metrics(old)] == [set(METRIC_FIELDS)] * 2
    assert truncate_metrics(old, 100) == 1 and len(read_metrics(old)) == 1
    (new / "metrics.csv").write_text((new / "metrics.csv").read_text().replace("100,1,2.0", "100,1,nan"))
    with pytest.warns(RunWarning, match="missing"):  # a base column may not be nan
        assert [r["timesteps"] for r in read_metrics(new)] == [200]


# ---- crash-safe writes ----------------------------------------------------------------------------
def test_atomic_write_keeps_the_old_file_when_the_writer_dies(tmp_path):
    path = tmp_path / "args.json"
    atomic_write_text(path, "old")
    from containergym_marl.files import atomic_write

    def dies(tmp):
        tmp.write_text("half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        atomic_write(path, dies)
    assert path.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["args.json"]


def test_training_writes_no_file_in_place(run_copy, monkeypatch, tmp_path):
    """Every file a run writes appears by a rename of a complete temporary file."""
    (run_copy / "final_model.zip").unlink()
    renamed = []
    real = os.replace
    monkeypatch.setattr(os, "replace", lambda a, b: (renamed.append(Path(b).name), real(a, b)))
    train(TrainArgs(algo="ppo", out=str(run_copy), timesteps=768, resume=True, checkpoint_every=128, **TINY))
    assert {"final_model.zip", "run.json", "ckpt_512_steps.zip", "ckpt_512_steps.json"} <= set(renamed)
    assert not list(run_copy.rglob("*.tmp"))


@pytest.mark.parametrize("algo", ["ppo", "shared_ppo"])
def test_training_leaves_nothing_in_the_temp_dir(tmp_path, monkeypatch, algo):
    """No empty SB3-<date> folder per run (SB3's logger is given the run's tb/ folder)."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    run = train(TrainArgs(algo=algo, out=str(tmp_path / "r"), timesteps=256, checkpoint_every=128, **TINY))
    (run / "final_model.zip").unlink()
    train(TrainArgs(algo=algo, out=str(run), timesteps=384, resume=True, **TINY))
    evaluate_run(run, protocol=EvalProtocol(episodes=1), write=False)
    assert not [p.name for p in tmp.iterdir() if p.name.startswith("SB3-")]
    assert sorted(p.name for p in (run / "tb").iterdir()) == ["run_1"]


class _Killed(BaseException):
    """Stands for SIGKILL in the middle of a checkpoint (a BaseException: nothing may catch it)."""


def _metrics_without_wall_time(run: Path) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "wall_time_s"} for r in read_metrics(run)]


@pytest.mark.parametrize("writes_done", [0, 1, 2])
def test_a_kill_while_the_first_checkpoint_is_saved_never_loses_the_episode_window(
        base_run, tmp_path, monkeypatch, writes_done):
    """Killed after each file write of the first checkpoint (best model snapshot, model, progress):
    the rerun must not resume from a checkpoint that lacks its progress file. (With the model
    written before the progress file, a kill between the two left a first checkpoint that --resume
    took for one from before progress files: the 100-episode window and the best return were lost.)
    With no complete checkpoint the rerun starts over, so it is the uninterrupted run exactly."""
    from containergym_marl.training import loop
    from containergym_marl.training import checkpoints as runs_module

    saved = loop.save_checkpoint
    count = {"writes": 0}

    def killed_while_saving(*args, **kwargs):
        def dies_after(real):
            def write(*a, **k):
                if count["writes"] == writes_done:
                    raise _Killed
                count["writes"] += 1
                return real(*a, **k)
            return write

        monkeypatch.setattr(runs_module, "atomic_write", dies_after(runs_module.atomic_write))
        monkeypatch.setattr(runs_module, "atomic_write_text", dies_after(runs_module.atomic_write_text))
        return saved(*args, **kwargs)

    monkeypatch.setattr(loop, "save_checkpoint", killed_while_saving)
    run = tmp_path / "run"
    args = dict(algo="ppo", out=str(run), timesteps=512, checkpoint_every=128, **TINY)
    with pytest.raises(_Killed):
        train(TrainArgs(**args))
    monkeypatch.undo()
    assert not (run / "final_model.zip").exists()

    train(TrainArgs(**args, resume=True))
    assert read_run_summary(run)["resumed_from"] is None  # no complete checkpoint: started over
    assert _metrics_without_wall_time(run) == _metrics_without_wall_time(base_run)
    from containergym_marl.models import load_model

    a, b = (load_model(r / "final_model.zip", "ppo").policy.state_dict() for r in (run, base_run))
    assert all(np.array_equal(a[k].numpy(), b[k].numpy()) for k in a)


def test_the_next_writer_removes_the_temporary_files_killed_writers_left(run_copy):
    """A kill while a file is written leaves its temporary file (a hidden name no reader takes);
    the next process that trains the run (it holds the run's lock) removes those of the training's
    files. A half-written replay buffer or model would otherwise stay forever."""
    run = run_copy
    (run / "final_model.zip").unlink()
    stale = [run / ".best_model.zip.k1ll3d_0.tmp", run / ".metrics.csv.k1ll3d_1.tmp",
             run / "checkpoints" / ".ckpt_512_steps.zip.k1ll3d_2.tmp",
             run / "checkpoints" / ".ckpt_replay_buffer_512_steps.pkl.k1ll3d_3.tmp"]
    for path in stale:
        path.write_bytes(b"PK\x03\x04 cut short by a kill")
    # `containergym-marl evaluate RUN` writes into the run without its lock: not the trainer's to remove
    evaluation = run / ".evaluation_best.json.k1ll3d_4.tmp"
    evaluation.write_text("{")
    train(TrainArgs(algo="ppo", out=str(run), timesteps=512, resume=True, **TINY))
    assert [p.name for p in stale if p.exists()] == []
    assert evaluation.exists()
    assert (run / "final_model.zip").is_file()


# ---- no training episode finished ----------------------------------------------------------------
def test_a_run_without_a_finished_episode_says_so(tmp_path, capsys):
    out = tmp_path / "r"
    # T = 1500 steps: 2 x 128 steps of this seed end no episode (no overflow either)
    assert cli_main(["train", "--algo", "ppo", "--timesteps", "256", "--n-envs", "2", "--hp", "n_steps=64",
                     "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    summary = read_run_summary(out)
    assert summary["episodes"] == 0 and summary["best_model"] is None
    assert "no training episode finished" in summary["note"]
    assert not (out / "best_model.zip").exists()  # the final model is not passed off as the best
    assert "no training episode finished" in printed and f"evaluate {out} --model final" in printed
    with pytest.warns(RunWarning, match="no training episode finished"):
        policy = policy_from_run(out, "best")
    assert "final: no training episode finished" in policy.name
    assert cli_main(["evaluate", str(out), "--episodes", "1"]) == 0
    assert "no training episode finished" in capsys.readouterr().err

    # compare evaluates such a run too (its final model, named so), from the files it ships to a worker
    from containergym_marl.orchestration.plan import run_files
    from containergym_marl.manifest import sha256_bytes
    from containergym_marl.orchestration.tasks import EvalSpec, evaluate_policy

    source = run_files(out)
    assert sorted(source["files"]) == ["args.json", "final_model.zip", "run.json"]
    with pytest.warns(RunWarning, match="no training episode finished"):
        spec = EvalSpec("ppo_s1", "ppo", "n5_m2_dt120", EvalProtocol(episodes=1), seed=1)
        result, model_sha = evaluate_policy(spec, source)
    assert model_sha == sha256_bytes((out / "final_model.zip").read_bytes()) and len(result.returns) == 1


def test_train_ends_with_the_training_return_and_the_next_command(tmp_path, capsys):
    out = tmp_path / "r"
    assert cli_main(["train", "--algo", "ppo", "--timesteps", "256", "--n-envs", "2", "--hp", "n_steps=64",
                     "--out", str(out), "--no-progress", "--override", "episode_length_steps=20"]) == 0
    printed = capsys.readouterr().out
    summary = read_run_summary(out)
    assert f"training return (mean of the last {summary['episodes']} of {summary['episodes']}" in printed
    assert f"{summary['train_return_mean100']:.2f} after 256 samples" in printed
    assert printed.rstrip().endswith(f"next: containergym-marl evaluate {out}")


def test_train_shows_samples_per_second_and_the_latest_training_return_while_it_runs(tmp_path, monkeypatch):
    class Terminal(io.StringIO):  # the bar is drawn on a terminal only
        def isatty(self) -> bool:
            return True

    monkeypatch.setattr(sys, "stderr", Terminal())
    monkeypatch.setenv("COLUMNS", "200")
    out = tmp_path / "r"
    assert cli_main(["train", "--algo", "ppo", "--timesteps", "256", "--n-envs", "2", "--hp", "n_steps=64",
                     "--out", str(out), "--override", "episode_length_steps=20"]) == 0
    drawn = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", sys.stderr.getvalue())  # without colours and cursor moves
    last = [line for line in re.split(r"[\r\n]", drawn) if line.startswith("ppo s1 ")][-1]
    summary = read_run_summary(out)
    assert "256/256 samples" in last and "samples/s" in last
    assert f"training return {summary['train_return_mean100']:.2f}" in last


# ---- one writer per run directory -----------------------------------------------------------------
def test_a_second_writer_fails_fast_naming_the_holder(tmp_path):
    out = tmp_path / "r"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from containergym_marl.rundir import RunLock; "
         "lock = RunLock(sys.argv[1]).acquire(); print('locked', flush=True); time.sleep(60)", str(out)],
        stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        assert holder.stdout.readline().strip() == "locked"
        start = time.perf_counter()
        with pytest.raises(RunError, match=rf"in use .*pid {holder.pid} on host {re.escape(socket.gethostname())}"):
            train(TrainArgs(algo="ppo", out=str(out), timesteps=256, **TINY))
        assert time.perf_counter() - start < 5
    finally:
        holder.kill()  # a killed holder releases the lock
        holder.wait()
    run = train(TrainArgs(algo="ppo", out=str(out), timesteps=256, **TINY))
    assert (run / "final_model.zip").is_file()
    with RunLock(run):  # held by this process: a resume in the same process is refused too
        with pytest.raises(RunError, match=f"pid {os.getpid()}"):
            train(TrainArgs(algo="ppo", out=str(out), timesteps=384, resume=True, **TINY))


# ---- bad values refused up front ------------------------------------------------------------------
@pytest.mark.parametrize("argv", [
    ["train", "--algo", "ppo", "--timesteps", "-5"],
    ["train", "--algo", "ppo", "--timesteps", "0"],
    ["train", "--algo", "ppo", "--n-envs", "0"],
    ["train", "--algo", "ppo", "--checkpoint-every", "0"],
    ["evaluate", "rule_based", "--episodes", "0"],
])
def test_cli_refuses_non_positive_counts(argv, capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        cli_main([*argv, "--out", str(tmp_path / "r")] if argv[0] == "train" else argv)
    assert exc.value.code == 2
    assert "expected a positive integer" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


def test_train_args_refuse_zero_simulations(tmp_path):
    """n_envs=0 was silently replaced by the default of 8."""
    for bad in ({"n_envs": 0}, {"timesteps": -5}, {"timesteps": 0}, {"checkpoint_every": 0}):
        with pytest.raises(ValueError, match=f"{next(iter(bad))}: expected a positive integer"):
            train(TrainArgs(algo="ppo", out=str(tmp_path / "r"), **{**TINY, **bad}))
    assert not (tmp_path / "r").exists()


# ---- a missing optional dependency ----------------------------------------------------------------
BLOCKED = ("import sys; sys.modules['torch'] = None; sys.modules['stable_baselines3'] = None; "
           "from containergym_marl.cli import main; sys.exit(main(sys.argv[1:]))")


def test_missing_training_extra_is_named(tmp_path, run_copy):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    out = tmp_path / "r"
    train_cmd = subprocess.run([sys.executable, "-c", BLOCKED, "train", "--algo", "ppo", "--out", str(out)],
                               capture_output=True, text=True, env=env)
    assert train_cmd.returncode == 2, train_cmd.stderr
    assert "pip install 'containergym-marl[train]'" in train_cmd.stderr and "Traceback" not in train_cmd.stderr
    assert not out.exists()
    evaluate = subprocess.run([sys.executable, "-c", BLOCKED, "evaluate", str(run_copy), "--episodes", "1"],
                              capture_output=True, text=True, env=env)
    assert evaluate.returncode == 2, evaluate.stderr
    assert "pip install 'containergym-marl[train]'" in evaluate.stderr and "Traceback" not in evaluate.stderr


# ---- kill -9 and rerun ----------------------------------------------------------------------------
def _train_argv(out: Path, budget: int, resume: bool = False) -> list[str]:
    return ["train", "--algo", "ppo", "--timesteps", str(budget), "--n-envs", "2", "--hp", "n_steps=64",
            "--checkpoint-every", "128", "--override", "episode_length_steps=50", "--no-progress",
            "--out", str(out), *(["--resume"] if resume else [])]


def _start(out: Path, budget: int, resume: bool = False) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "containergym_marl.cli", *_train_argv(out, budget, resume)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            env={**os.environ, "PYTHONPATH": str(REPO)})


def _wait_for(predicate, proc: subprocess.Popen, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert proc.poll() is None, f"training ended before it could be killed: {proc.stderr.read()}"
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)


def _check_consistent(run: Path, budget: int) -> None:
    steps = _steps(run)
    assert steps == sorted(set(steps)) and steps[-1] >= budget  # no duplicated or missing order
    episodes = [r["episodes"] for r in read_metrics(run)]
    assert all(b > a for a, b in zip(episodes, episodes[1:]))
    summary = read_run_summary(run)
    assert summary["timesteps"] == steps[-1] and summary["episodes"] == episodes[-1]
    assert not list(run.rglob("*.tmp"))
    evaluate_run(run, protocol=EvalProtocol(episodes=1), write=False)


@pytest.mark.slow  # ~20 s; the native trainer's kill-9 resume is in the default suite
def test_kill_9_after_the_first_checkpoint_then_resume(tmp_path):
    out, budget = tmp_path / "r", 1536
    proc = _start(out, budget)
    _wait_for(lambda: bool(list((out / "checkpoints").glob("ckpt_*_steps.json"))), proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (out / "final_model.zip").exists()
    assert cli_main(_train_argv(out, budget, resume=True)) == 0
    _check_consistent(out, budget)


@pytest.mark.slow
def test_kill_9_at_random_points_many_times(tmp_path):
    """Killed at random moments (while saving models, metrics, checkpoints…), rerun each time:
    the run always resumes, and ends consistent."""
    rng = np.random.default_rng(0)
    # a budget that an idle machine does not finish within the first kills (8192 samples did, in two)
    out, budget, kills = tmp_path / "r", 32768, 0
    for _ in range(10):
        proc = _start(out, budget, resume=(out / "args.json").exists())
        # the kill's moment counts from the run's start (its args.json), not the process's: on a busy
        # machine the imports alone took longer than the sleep, every kill came before the run began
        # and nothing was left to resume
        deadline = time.monotonic() + 300
        while not (out / "args.json").exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(float(rng.uniform(0.5, 4.0)))
        if proc.poll() is not None:
            assert proc.returncode == 0, proc.stderr.read()
            break
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        kills += 1
    assert kills >= 3
    if not (out / "final_model.zip").exists():
        assert cli_main(_train_argv(out, budget, resume=True)) == 0
    _check_consistent(out, budget)


def test_the_policy_of_a_team_reward_run_is_named_after_its_method(tmp_path):
    """A shared-PPO run trained with the team reward evaluates as compare's "shared_ppo_team" (figure
    titles and evaluation files show this name), one with the default individual reward as "shared_ppo"."""
    names = {}
    for mode in ("individual", "team"):
        out = tmp_path / mode
        assert cli_main(["train", "--algo", "shared_ppo", "--reward-mode", mode, "--timesteps", "64", "--n-envs", "1",
                         "--hp", "n_steps=64", "--hp", "batch_size=64", "--out", str(out), "--no-progress",
                         "--override", "episode_length_steps=5"]) == 0
        names[mode] = policy_from_run(out, "best").name
    assert names == {"individual": "shared_ppo[s1,best]", "team": "shared_ppo_team[s1,best]"}


def test_an_atomic_rewrite_keeps_the_file_s_mode_and_a_new_file_follows_the_umask(tmp_path):
    import stat

    kept = tmp_path / "README.md"
    kept.write_text("old")
    kept.chmod(0o644)
    atomic_write_text(kept, "new")
    assert stat.S_IMODE(kept.stat().st_mode) == 0o644 and kept.read_text() == "new"
    kept.chmod(0o600)
    atomic_write_text(kept, "newer")
    assert stat.S_IMODE(kept.stat().st_mode) == 0o600
    old = os.umask(0o027)
    try:
        from containergym_marl import files

        expected = 0o666 & ~files._UMASK
    finally:
        os.umask(old)
    fresh = tmp_path / "table.md"
    atomic_write_text(fresh, "x")
    assert stat.S_IMODE(fresh.stat().st_mode) == expected
