"""One progress style (containergym_marl.progress_bar): rich bars with rates and ETAs on a terminal for
training, evaluation and the sweep; nothing from training and evaluation, and only plain lines from
the sweep, when the stream is not a terminal."""

from __future__ import annotations

import io
import re
import sys
import time

import pytest

from containergym_marl.cli import main
from containergym_marl.orchestration.sweep_progress import Progress
from containergym_marl.progress_bar import Bar, format_duration
from containergym_marl.training import TrainArgs, train

# episodes of T = 20 steps, so that a tiny budget ends training episodes (the bar's training return)
TINY = dict(timesteps=512, n_envs=2, overrides={"episode_length_steps": 20}, checkpoint_every=256)
HYPERPARAMS = {"ppo": {"n_steps": 64, "batch_size": 64}, "fast_ppo": {"n_steps": 16, "minibatch_size": 32}}
CONTROL = re.compile(r"[\r\x1b]")


def _plain(text: str) -> str:
    """``text`` without rich's escape sequences (colours, cursor moves)."""
    return re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", text)


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.fixture(autouse=True)
def _wide(monkeypatch):
    """A wide terminal, so that no cell is cut; no FORCE_COLOR or TTY_COMPATIBLE from the caller's
    environment (one test sets them itself)."""
    monkeypatch.setenv("COLUMNS", "200")
    monkeypatch.delenv("FORCE_COLOR", raising=False)
    monkeypatch.delenv("TTY_COMPATIBLE", raising=False)


def _train(tmp_path, algo: str, **kw) -> None:
    train(TrainArgs(algo=algo, out=str(tmp_path / algo), hyperparams=HYPERPARAMS[algo], **TINY, **kw))


# ---- training -------------------------------------------------------------------------------------
@pytest.mark.parametrize("algo", ["ppo", "fast_ppo"])  # SB3's callback and the native loop
def test_training_bar_shows_samples_rate_eta_and_return_on_a_terminal(tmp_path, monkeypatch, algo):
    monkeypatch.setattr(sys, "stderr", Terminal())
    _train(tmp_path, algo)
    out = sys.stderr.getvalue()
    assert f"{algo} s1" in out and "512/512 samples" in out
    assert re.search(r"[\d,]+ samples/s", out) and "ETA " in out
    assert re.search(r"training return -?\d+\.\d\d", out)


@pytest.mark.parametrize("algo", ["ppo", "fast_ppo"])
def test_training_writes_nothing_when_stderr_is_not_a_terminal(tmp_path, monkeypatch, algo):
    monkeypatch.setattr(sys, "stderr", io.StringIO())
    monkeypatch.setenv("FORCE_COLOR", "1")  # colours asked for (CI services do) are not a terminal
    _train(tmp_path, algo)
    assert sys.stderr.getvalue() == ""


def test_no_progress_draws_nothing_even_on_a_terminal(tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "stderr", Terminal())
    _train(tmp_path, "fast_ppo", progress_bar=False)
    assert sys.stderr.getvalue() == ""


# ---- evaluation -----------------------------------------------------------------------------------
def test_evaluation_bar_on_a_terminal_and_nothing_otherwise(monkeypatch, capsys):
    command = ["evaluate", "rule_based_agents", "--config", "n5_m2_dt120", "--episodes", "2"]
    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    assert main(command) == 0
    out = terminal.getvalue()
    assert "evaluating" in out and "2/2 episodes" in out and "episodes/s" in out and "ETA " in out
    assert "seed 10001: return " in out  # the last episode's

    monkeypatch.undo()  # stderr: pytest's capture, not a terminal
    monkeypatch.setenv("COLUMNS", "200")
    assert main(command) == 0
    captured = capsys.readouterr()
    assert captured.err == ""
    assert "rule_based_agents on n5_m2_dt120" in captured.out  # the results on stdout, as before


def test_a_bar_counts_rates_and_estimates_the_time_left():
    stream = Terminal()
    with Bar("ppo s1", 2_000_000, "samples", completed=100_000, stream=stream) as bar:
        bar.advance_to(150_000)
        time.sleep(0.1)
        bar.advance_to(200_000, "training return 1.50")
        bar.progress.refresh()
        frame = _plain(stream.getvalue().rsplit("\r", 1)[-1])  # the last redraw
    assert "200.0k/2.00M samples" in frame and " 10%" in frame and "training return 1.50" in frame
    rate = float(re.search(r"([\d,]+) samples/s", frame).group(1).replace(",", ""))
    assert 50_000 / 0.5 < rate <= 50_000 / 0.1  # 50,000 samples in a little over 0.1 s
    assert f"ETA {format_duration(1_800_000 / rate)}" in frame  # the samples left at that rate


# ---- the sweep ------------------------------------------------------------------------------------
def _sweep(stream, interval_s: float = 60.0) -> Progress:
    p = Progress({"a": 1000, "b": 1000, "c": 1000}, evaluations=3, cpus=2, stream=stream, interval_s=interval_s)
    p.tick(force=True)
    p.started("a", "host1", 11, "new", 0)
    p.started("b", "host2", 12, "resume", 400)
    p.sampled("a", 500, 100.0)
    p.sampled("b", 600, 100.0)
    p.tick()
    p.run_done("a", {"state": "new", "resumed_from": 0, "samples": 1000, "wall_s": 10.0, "samples_per_s": 100.0,
                     "host": "host1"})
    p.run_failed("c", "WorkerCrashedError")
    p.eval_done()
    p.tick()
    return p


def test_the_sweep_writes_plain_lines_when_not_on_a_terminal():
    stream = io.StringIO()
    p = _sweep(stream, interval_s=0.0)  # a status line at every tick
    p.finish()
    lines = stream.getvalue().splitlines()
    assert not CONTROL.search(stream.getvalue())
    assert [line for line in lines if line.startswith("  ")] == [
        "  resume b from its checkpoint at 400 samples",
        "  done a: trained, 1,000 samples in 10s (100 samples/s) on host1",
        "  FAILED c: WorkerCrashedError"]
    status = [line for line in lines if not line.startswith("  ")]
    assert len(status) == 3 and re.fullmatch(
        r"\[\d+s\] runs 0/3 done, 2 running, 1 queued · evaluations 0/3 · ETA 10s · a 50% 100/s · b 60% 100/s",
        status[1])
    # the format a `nohup compare > sweep.log` reader sees
    assert re.fullmatch(r"\[\d+s\] runs 0/3 done, 0 running, 3 queued · evaluations 0/3 · ETA \?", status[0])
    assert re.fullmatch(r"\[\d+s\] runs 2/3 done, 1 running, 0 queued · evaluations 1/3 · ETA 4s · b 60% 100/s",
                        status[-1])

    quiet = io.StringIO()
    p = _sweep(quiet)  # every 60 s: only the first tick's line
    assert [line for line in quiet.getvalue().splitlines() if not line.startswith("  ")] == [status[0]]


def test_the_sweep_draws_its_row_and_one_per_running_run_on_a_terminal():
    stream = Terminal()
    p = _sweep(stream)
    eta = p.eta_s()
    assert [t.description for t in p.display.progress.tasks] == ["sweep", "b"]  # a's row went when it ended
    p.finish()
    out = stream.getvalue()
    assert "\x1b[" in out  # drawn, not printed
    assert "2/3 runs" in out and f"ETA {format_duration(eta)}" in out and "evaluations 1/3 · 1 running" in out
    assert re.search(r"b +\S+ +60% +600/1,000 samples +100 samples/s +ETA 4s +on host2", _plain(out))
    for event in ("resume b from its checkpoint at 400 samples", "done a: trained, 1,000 samples in 10s",
                  "FAILED c: WorkerCrashedError"):
        assert event in out
    assert "runs 2/3 done" not in out  # the plain status line is for logs only
