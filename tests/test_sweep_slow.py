"""compare on Ray, the slow checks (``pytest -m slow``): the same tiny sweep on a two-node Ray
cluster started on this machine, a training worker killed mid-run (Ray retries the task, which
resumes from the run's checkpoint; the other run is bit-identical to a plain ``train``), and
Ctrl-C followed by the same command (every run resumes or is reused).

The cluster is started with ``ray start --block`` processes that the test owns and stops by their
process ids (``ray stop`` would stop every Ray instance on the machine)."""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import os
import secrets
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ray")

from containergym_marl.compare import CompareArgs, run_specs  # noqa: E402

pytestmark = pytest.mark.slow

BIN = Path(sys.executable).parent
RUN1, RUN2 = "ppo_n5_m2_dt120_s1", "ppo_n5_m2_dt120_s2"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _ray_env() -> dict:
    env = {**os.environ, "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(32)}
    env.pop("RAY_ADDRESS", None)
    return env


def _active_nodes(address: str, env: dict) -> int:
    r = subprocess.run([str(BIN / "ray"), "status", "--address", address], env=env, capture_output=True, text=True)
    if r.returncode != 0 or "Active:" not in r.stdout:
        return 0
    active = r.stdout.split("Active:")[1].split("Pending:")[0]
    return sum(line.strip().startswith("1 node_") for line in active.splitlines())


def _wait(predicate, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError(f"waited {timeout_s:.0f} s for {what}")
        time.sleep(0.5)


@contextlib.contextmanager
def two_node_cluster(tmp_path: Path):
    """A head node and a second node, one CPU each, on this machine; yields (address, env)."""
    env, port = _ray_env(), _free_port()
    address = f"127.0.0.1:{port}"
    procs = []
    try:
        with (tmp_path / "head.log").open("w") as log:
            procs.append(subprocess.Popen([str(BIN / "ray"), "start", "--head", "--block", "--port", str(port),
                                           "--num-cpus", "1", "--include-dashboard=false", "--disable-usage-stats"],
                                          env=env, stdout=log, stderr=subprocess.STDOUT))
        _wait(lambda: _active_nodes(address, env) >= 1, 120, "the head node")
        with (tmp_path / "node.log").open("w") as log:
            procs.append(subprocess.Popen([str(BIN / "ray"), "start", "--block", "--address", address,
                                           "--num-cpus", "1"], env=env, stdout=log, stderr=subprocess.STDOUT))
        _wait(lambda: _active_nodes(address, env) >= 2, 120, "the second node")
        yield address, env
    finally:
        for p in reversed(procs):
            p.terminate()  # `ray start --block` stops the Ray processes of its node on SIGTERM
        for p in reversed(procs):
            try:
                p.wait(timeout=60)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        # `ray start --head` recorded this cluster as the machine's latest, where a plain ray.init()
        # would look for it; `ray stop` would forget it, so forget it here.
        latest = Path(os.environ.get("RAY_TMPDIR", "/tmp")) / "ray" / "ray_current_cluster"
        with contextlib.suppress(OSError):
            if latest.read_text().strip().endswith(f":{port}"):
                latest.unlink()


def _compare_cmd(out: Path, *extra: str) -> list[str]:
    return [str(BIN / "containergym-marl"), "compare", "--out", str(out), "--episodes", "2", "--n-envs", "1",
            "--bootstrap-reps", "200", *extra]


def test_the_tiny_sweep_on_a_two_node_cluster_through_address(tmp_path):
    out = tmp_path / "cmp"
    with two_node_cluster(tmp_path) as (address, env):
        r = subprocess.run(_compare_cmd(out, "--address", address, "--methods", "ppo", "shared_ppo_team",
                                        "--seeds", "1", "--timesteps", "1024", "--checkpoint-every", "512",
                                        "--hp", "n_steps=128", "batch_size=64"),
                           env=env, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    sweep = json.loads((out / "sweep.json").read_text())
    assert sweep["ray"] == f"cluster at {address}: 2 nodes, 2 CPUs"
    assert sorted(t["name"] for t in sweep["trained"]) == ["ppo_n5_m2_dt120_s1", "shared_ppo_team_n5_m2_dt120_s1"]
    assert len({t["node"] for t in sweep["trained"]}) == 2  # one run on each node (one CPU each)
    team = json.loads((out / "runs" / "shared_ppo_team_n5_m2_dt120_s1" / "args.json").read_text())
    assert (team["algo"], team["reward_mode"]) == ("shared_ppo", "team")
    table = (out / "table.md").read_text()
    assert "| n5_m2_dt120 | shared_ppo_team | decentralised | 1 |" in table and "P(shared_ppo_team > ppo)" in table
    assert (out / "figures" / "n5_m2_dt120_pu_timeline_shared_ppo_team.png").is_file()


KILL_ARGS = ("--methods", "ppo", "--seeds", "1", "2", "--timesteps", "12288", "--checkpoint-every", "2048",
             "--hp", "n_steps=256", "batch_size=64", "--no-figures", "--num-cpus", "2")


def _metrics(run: Path) -> list[dict]:
    with (run / "metrics.csv").open() as f:
        return [{k: v for k, v in row.items() if k != "wall_time_s"} for row in csv.DictReader(f)]


def _wait_for_checkpoint(out: Path, run: str, proc: subprocess.Popen) -> int:
    """The pid of ``run``'s training worker once the run has written a checkpoint."""
    pid_file = out / "runs" / ".sweep" / f"{run}.pid"
    ckpts = out / "runs" / run / "checkpoints"
    _wait(lambda: proc.poll() is not None or (pid_file.is_file() and any(ckpts.glob("ckpt_*_steps.zip"))),
          600, f"a checkpoint of {run}")
    assert proc.poll() is None, "the sweep ended before the run wrote a checkpoint"
    return int(pid_file.read_text())


def test_a_killed_training_worker_is_retried_and_resumes_the_others_are_identical(tmp_path):
    from containergym_marl.evaluation import EvalProtocol, evaluate
    from containergym_marl.training.runs import load_model, policy_from_run, train

    out = tmp_path / "cmp"
    proc = subprocess.Popen(_compare_cmd(out, *KILL_ARGS), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, env={k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"})
    try:
        os.kill(_wait_for_checkpoint(out, RUN1, proc), signal.SIGKILL)
        output, _ = proc.communicate(timeout=900)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, output[-4000:]
    assert f"retry {RUN1} (attempt 2, resume from" in output
    trained = {t["name"]: t for t in json.loads((out / "sweep.json").read_text())["trained"]}
    assert (trained[RUN1]["attempts"], trained[RUN1]["state"]) == (2, "resume")
    assert trained[RUN1]["resumed_from"] >= 2048
    assert (trained[RUN2]["attempts"], trained[RUN2]["state"]) == (1, "new")
    log = (out / "runs" / ".sweep" / f"{RUN1}.log").read_text().splitlines()
    assert len(log) == 2 and log[0].endswith(": start") and "resume from" in log[1]
    assert json.loads((out / "runs" / RUN1 / "args.json").read_text())["timesteps"] == 12288
    assert load_model(out / "runs" / RUN1 / "final_model.zip", "ppo").num_timesteps == 12288

    # The run that was not killed is identical to the same run trained by a plain train() call.
    args = CompareArgs(methods=["ppo"], seeds=[2], timesteps=12288, n_envs=1, checkpoint_every=2048,
                       hyperparams={"n_steps": 256, "batch_size": 64})
    (spec,) = run_specs(args, out / "runs")
    reference = Path(train(dataclasses.replace(spec, run_dir=str(tmp_path / "reference")).train_args(False)))
    swept = out / "runs" / RUN2
    assert _metrics(swept) == _metrics(reference)
    a, b = (load_model(run / "final_model.zip", "ppo").policy.state_dict() for run in (swept, reference))
    assert a.keys() == b.keys() and all(np.array_equal(a[k].numpy(), b[k].numpy()) for k in a)
    expected = evaluate(policy_from_run(reference, "best"), "n5_m2_dt120", EvalProtocol(episodes=2), keep_records=False)
    saved = json.loads((out / "evaluations" / "n5_m2_dt120" / "ppo_s2.json").read_text())
    assert [e["cumulative_reward"] for e in saved["episodes"]] == expected.returns.tolist()


def test_ctrl_c_leaves_every_run_resumable_and_the_same_command_finishes_the_sweep(tmp_path):
    out = tmp_path / "cmp"
    cmd = _compare_cmd(out, *KILL_ARGS)
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    # its own process group, so that SIGINT reaches the group as Ctrl-C in a terminal does
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
                            start_new_session=True)
    try:
        _wait_for_checkpoint(out, RUN1, proc)
        os.killpg(proc.pid, signal.SIGINT)
        output, _ = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, output[-4000:]
    assert "interrupted: finished runs are kept" in output
    assert not (out / "table.md").exists()

    again = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=900)
    assert again.returncode == 0, again.stdout[-4000:] + again.stderr[-4000:]
    sweep = json.loads((out / "sweep.json").read_text())
    states = {t["name"]: t["state"] for t in sweep["trained"]}
    states.update({name: "reused" for name in sweep["reused"]})
    assert states[RUN1] in ("resume", "reused") and set(states) == {RUN1, RUN2}
    assert "resume" in states.values()  # at least the run with a checkpoint went on from it
    for run in (RUN1, RUN2):
        assert json.loads((out / "runs" / run / "args.json").read_text())["timesteps"] == 12288
    assert (out / "table.md").is_file()


# ---- SIGKILL of the whole compare at random moments ---------------------------------------------
def _processes_with(marker: str) -> list[int]:
    """Pids of live processes whose environment holds ``marker`` (the compare and every Ray process it
    started inherit it; nothing else on the machine does)."""
    found = []
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            with contextlib.suppress(OSError):
                if marker.encode() in (proc / "environ").read_bytes():
                    found.append(int(proc.name))
    return found


def _wait_gone(marker: str, timeout_s: float = 60.0) -> None:
    _wait(lambda: not _processes_with(marker), timeout_s, "the killed compare's processes to end")


def _check_every_file_readable(root: Path) -> None:
    """What a later compare may read is whole: every JSON parses, every model zip is intact, every
    complete metrics row is well formed. Files still being written are only ever *.tmp names (the
    package writes through a temporary file and a rename); logs, pid files, locks and TensorBoard
    event files are not read back."""
    import zipfile

    from containergym_marl.training.runs import read_metrics

    for path in root.rglob("*"):
        if not path.is_file() or path.suffix == ".tmp" or ".tmp" in path.name or "tb" in path.parts:
            continue
        if path.suffix == ".json":
            json.loads(path.read_text())
        elif path.suffix == ".zip":
            with zipfile.ZipFile(path) as z:
                assert z.testzip() is None, path
        elif path.name == "metrics.csv":
            rows = read_metrics(path.parent)
            assert all(r["timesteps"] > 0 for r in rows), path


def _table_rows(out: Path) -> dict[tuple[str, str], dict]:
    rows = json.loads((out / "table.json").read_text())["rows"]
    return {(r["config"], r["method"]): r for r in rows}


def test_compare_killed_at_random_moments_then_rerun_ends_as_an_uninterrupted_compare(tmp_path):
    """SIGKILL to compare's whole process tree (driver, Ray, training and evaluation workers) at
    random moments, then the same command again, several times. After every kill every file a
    rerun would read is intact; the last rerun finishes; its table equals an uninterrupted run's for
    everything that does not depend on where a run was cut: the rule-based row, and every learned
    run that never resumed from a checkpoint (a run killed before its first checkpoint starts
    again from scratch, so it is bit-identical). A run that resumed draws fresh simulation seeds
    (seed + samples, see training/loop.py), so its numbers legitimately differ; for it the test
    checks that it completed its budget with consistent metrics."""
    from containergym_marl.training.runs import load_model, read_metrics

    rng = np.random.default_rng(0)
    args = ("--methods", "rule_based", "ppo", "--seeds", "1", "2", "--timesteps", "8192", "--checkpoint-every",
            "1024", "--hp", "n_steps=256", "batch_size=64", "--no-figures", "--num-cpus", "2")
    out = tmp_path / "cmp"
    marker = f"CONTAINERGYM_SOAK_{secrets.token_hex(8)}"
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"} | {marker: "1"}
    kills = 0
    for _ in range(8):
        proc = subprocess.Popen(_compare_cmd(out, *args), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                env=env, start_new_session=True)
        try:
            proc.wait(timeout=float(rng.uniform(4.0, 30.0)))
        except subprocess.TimeoutExpired:
            for pid in _processes_with(marker):  # the whole tree, Ray's own process groups included
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
            proc.wait()
            _wait_gone(marker)
            kills += 1
            _check_every_file_readable(out)
            continue
        assert proc.returncode == 0
        break
    assert kills >= 3

    final = subprocess.run(_compare_cmd(out, *args), capture_output=True, text=True, env=env, timeout=900)
    assert final.returncode == 0, final.stdout[-3000:] + final.stderr[-3000:]
    _check_every_file_readable(out)
    reference = tmp_path / "reference"
    uninterrupted = subprocess.run(_compare_cmd(reference, *args), capture_output=True, text=True, env=env,
                                   timeout=900)
    assert uninterrupted.returncode == 0, uninterrupted.stderr[-3000:]

    ours, theirs = _table_rows(out), _table_rows(reference)
    assert ours.keys() == theirs.keys()
    assert ours[("n5_m2_dt120", "rule_based")] == theirs[("n5_m2_dt120", "rule_based")]
    resumed = set()
    for seed in (1, 2):
        run = f"ppo_n5_m2_dt120_s{seed}"
        log = (out / "runs" / ".sweep" / f"{run}.log").read_text()
        rows = read_metrics(out / "runs" / run)
        assert [r["timesteps"] for r in rows] == sorted({r["timesteps"] for r in rows})  # no duplicated rows
        assert load_model(out / "runs" / run / "final_model.zip", "ppo").num_timesteps == 8192
        evaluation = json.loads((out / "evaluations" / "n5_m2_dt120" / f"ppo_s{seed}.json").read_text())
        expected = json.loads((reference / "evaluations" / "n5_m2_dt120" / f"ppo_s{seed}.json").read_text())
        if "resume from" in log:
            resumed.add(run)
        else:  # started over from nothing each time it was cut: the same run as the uninterrupted one
            assert evaluation["episodes"] == expected["episodes"], run
            assert _metrics(out / "runs" / run) == _metrics(reference / "runs" / run), run
    if not resumed:
        assert ours[("n5_m2_dt120", "ppo")] == theirs[("n5_m2_dt120", "ppo")]


def test_ctrl_c_under_load_ends_compare_quickly_and_leaves_no_process(tmp_path):
    """Ctrl-C while two trainings keep both cores busy: compare ends within 30 s with exit status 130,
    and none of the processes it started (Ray's included) outlives it."""
    out = tmp_path / "cmp"
    marker = f"CONTAINERGYM_CTRLC_{secrets.token_hex(8)}"
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"} | {marker: "1"}
    proc = subprocess.Popen(_compare_cmd(out, *KILL_ARGS), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, env=env, start_new_session=True)
    try:
        _wait_for_checkpoint(out, RUN1, proc)
        started = time.monotonic()
        os.killpg(proc.pid, signal.SIGINT)
        output, _ = proc.communicate(timeout=120)
        elapsed = time.monotonic() - started
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, output[-3000:]
    assert elapsed < 30, f"compare took {elapsed:.0f} s to stop after Ctrl-C"
    _wait_gone(marker, timeout_s=30)
