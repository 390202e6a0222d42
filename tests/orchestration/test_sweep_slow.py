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
import re
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

from containergym_marl.orchestration import CompareArgs  # noqa: E402
from containergym_marl.orchestration.plan import run_specs  # noqa: E402
from containergym_marl.rundir import LOCK_NAME  # noqa: E402
from tests.orchestration import compare_kills as kills  # noqa: E402

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


_compare_cmd = kills.compare_cmd


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
    assert (out / "figures" / "n5_m2_dt120_episode_shared_ppo_team.png").is_file()  # a headline figure


KILL_ARGS = ("--methods", "ppo", "--seeds", "1", "2", "--timesteps", "12288", "--checkpoint-every", "2048",
             "--hp", "n_steps=256", "batch_size=64", "--no-figures", "--num-cpus", "2")


def _metrics(run: Path) -> list[dict]:
    with (run / "metrics.csv").open() as f:
        return [{k: v for k, v in row.items() if k != "wall_time_s"} for row in csv.DictReader(f)]


def _wait_for_checkpoint(out: Path, run: str, proc: subprocess.Popen) -> int:
    """The pid of ``run``'s training worker (the holder its run lock names) once the run has written a
    checkpoint."""
    lock = out / "runs" / run / LOCK_NAME
    ckpts = out / "runs" / run / "checkpoints"
    _wait(lambda: proc.poll() is not None or (lock.is_file() and any(ckpts.glob("ckpt_*_steps.zip"))),
          600, f"a checkpoint of {run}")
    assert proc.poll() is None, "the sweep ended before the run wrote a checkpoint"
    return int(re.match(r"pid (\d+) ", lock.read_text()).group(1))


def test_a_killed_training_worker_is_retried_and_resumes_the_others_are_identical(tmp_path):
    from containergym_marl.evaluation import EvalProtocol, evaluate
    from containergym_marl.evaluation.run_policies import policy_from_run
    from containergym_marl.training import train
    from containergym_marl.models import load_model

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


@contextlib.contextmanager
def _ctrl_c_reaches_children():
    """Start children with SIGINT at its default, as a terminal's foreground job has it. A shell
    starts a background job (``pytest ... &``, ``nohup``) with SIGINT ignored, an ignored signal
    stays ignored across exec, and the Ctrl-C of these tests would then never reach compare."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def test_ctrl_c_leaves_every_run_resumable_and_the_same_command_finishes_the_sweep(tmp_path):
    out = tmp_path / "cmp"
    cmd = _compare_cmd(out, *KILL_ARGS)
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    # its own process group, so that SIGINT reaches the group as Ctrl-C in a terminal does
    with _ctrl_c_reaches_children():
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


def test_sigterm_stops_compare_as_ctrl_c_does(tmp_path):
    """SIGTERM to compare alone (what a service manager or `kill` sends) ends it like Ctrl-C: exit
    143, runs resumable, Ray shut down; it used to abort with a stack dump (exit 134)."""
    out = tmp_path / "cmp"
    cmd = _compare_cmd(out, *KILL_ARGS)
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
                            start_new_session=True)
    try:
        _wait_for_checkpoint(out, RUN1, proc)
        proc.send_signal(signal.SIGTERM)
        output, _ = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 143, output[-4000:]
    assert "interrupted: finished runs are kept" in output


def _running(proc) -> bool:
    """Alive and not a zombie (one whose parent died lingers until init reaps it: it has ended)."""
    import psutil

    try:
        return proc.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def test_no_ray_process_outlives_a_killed_driver(tmp_path):
    """SIGKILL to compare's driver alone (an OOM kill): every process its local Ray instance started
    ends within seconds (the reaper), where Ray's own agents used to linger for a minute or more."""
    psutil = pytest.importorskip("psutil")
    out = tmp_path / "cmp"
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    proc = subprocess.Popen(_compare_cmd(out, *KILL_ARGS), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env=env, start_new_session=True)
    try:
        _wait_for_checkpoint(out, RUN1, proc)
        started = psutil.Process(proc.pid).children(recursive=True)
        assert any("raylet" in p.name() for p in started)
        proc.kill()
        proc.wait()
        deadline = time.monotonic() + 15
        while (alive := [p for p in started if _running(p)]) and time.monotonic() < deadline:
            time.sleep(0.5)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    assert not alive, [(p.pid, p.name()) for p in alive]


# ---- SIGKILL of the whole compare at random moments, and Ctrl-C under load ------------------------
SOAK_BUDGET = 8192
SOAK_ARGS = ("--methods", "rule_based", "ppo", "--seeds", "1", "2", "--timesteps", str(SOAK_BUDGET),
             "--checkpoint-every", "1024", "--hp", "n_steps=256", "batch_size=64", "--no-figures", "--num-cpus", "2")
#: How a compare is killed: SIGKILL to all its processes at once ("tree"); to its process group only
#: ("group", as ``kill -9 -PGID`` or a closed terminal: Ray's workers, in groups of their own, must
#: end by themselves); or to all at once the moment a file is being written ("mid-write": a
#: temporary file exists).
KILL_WAYS = ("tree", "group", "mid-write")


def _checkpoints_written(out: Path) -> int:
    return sum(1 for _ in out.glob("**/checkpoints/ckpt_*_steps.*"))


def _kill_at_a_random_moment(out: Path, env: dict, marker: str, rng: np.random.Generator, step_s: float,
                             log: Path) -> str | None:
    """Start compare and kill it in one of :data:`KILL_WAYS` at a random moment of its progress: once
    it has written 0, 1 or 2 more checkpoints (0: during its start), after a random share of
    ``step_s`` (the uninterrupted compare's time per checkpoint). Returns the way, or None when
    compare ended first (successfully: asserted). The moment follows the rerun's own progress, not
    the clock alone: a rerun resumes with less left to do, and the machine's load changes how long
    that takes, so a delay drawn from the first compare's duration could outlast every rerun."""
    before = _checkpoints_written(out)
    proc = kills.start(out, SOAK_ARGS, env, log)
    way = KILL_WAYS[int(rng.integers(len(KILL_WAYS)))]
    wanted, delay = int(rng.integers(3)), float(rng.uniform(0.0, 1.0)) * step_s
    with contextlib.suppress(TimeoutError):
        kills.wait(lambda: proc.poll() is not None or _checkpoints_written(out) >= before + wanted, 600,
                   f"{wanted} more checkpoint(s)", every_s=0.05)
    try:
        proc.wait(timeout=delay)
    except subprocess.TimeoutExpired:
        if way == "mid-write":
            before = set(kills.temporary_files(out))
            with contextlib.suppress(TimeoutError):
                kills.wait(lambda: proc.poll() is not None or bool(set(kills.temporary_files(out)) - before),
                           10, "a file being written", every_s=0.002)
        if way == "group":
            kills.kill_group(proc)
        else:
            kills.kill_tree(marker)
        proc.wait()
    kills.wait_gone(marker, timeout_s=30)  # no process of the compare outlives it (no orphaned worker)
    if proc.returncode == 0:
        return None
    assert proc.returncode == -signal.SIGKILL, log.read_text()[-3000:]
    return way


def _same_policy(a: Path, b: Path) -> bool:
    from containergym_marl.models import load_model

    pa, pb = (load_model(p, "ppo").policy.state_dict() for p in (a, b))
    return pa.keys() == pb.keys() and all(np.array_equal(pa[k].numpy(), pb[k].numpy()) for k in pa)


def test_compare_killed_at_random_moments_then_rerun_ends_as_an_uninterrupted_compare(tmp_path):
    """The issue's check of crash safety at the level of ``compare``: a tiny sweep (rule_based and
    PPO, seeds 1 and 2, 8192 samples, a checkpoint every 1024) is SIGKILLed at random moments (a
    fixed-seed generator draws when, after 0-2 more checkpoints and a share of the uninterrupted
    compare's time per checkpoint, and how: the whole process tree, the process group only, or the
    moment a file is being written), and the
    same command is run again after each kill, at least 3 and up to 6 times, then once more to its
    end. After every kill every file a rerun reads is whole (tests/compare_kills.check_intact) and
    no process of the killed compare lives on.

    The last rerun is compared with an uninterrupted compare of the same command in another folder:

    * the same table.json keys and arguments (but --out), the same rows with the same columns, the
      rule-based row identical, the same evaluation files with the same protocol and test episodes,
      the rule-based evaluation identical; table.md is the table of the evaluation files on disk,
      and every learned evaluation is of the best model now in its run (sha256): no evaluation of a
      model that a later resume replaced is reused;
    * a run that never resumed (never killed, or killed before its first checkpoint, when it starts
      over) is the uninterrupted run exactly: metrics (but wall time), every checkpoint, the best and
      the final model, its evaluation. With torch on one thread training is deterministic, and when
      no run resumed the whole table.json (but --out) is the uninterrupted one;
    * a run that resumed cannot be identical: a checkpoint holds neither the simulations in the
      middle of their episodes nor the random streams of the simulators and of the policy's
      sampling, so a resume starts fresh episodes with fresh seeds (seed + samples,
      training/loop.py) and what the run learns after it differs. For such a run the history up to
      the first checkpoint it resumed from is the uninterrupted run's exactly (metrics rows, the
      checkpoints' policies), and after it the run is consistent: no duplicated or missing metrics
      rows, episode counts never decreasing, the full budget, run.json naming the last resume. Its
      table row has the same shape and budget, not the same numbers.

    Then no temporary file is left in any run directory: the process that resumed a run removed
    those that killed writers had left."""
    from containergym_marl.evaluation import table as tables
    from containergym_marl.manifest import sha256_bytes
    from containergym_marl.rundir import checkpoints, read_metrics, read_run_summary
    from containergym_marl.models import load_model

    marker, env = kills.marked_env("CONTAINERGYM_SOAK")
    reference = tmp_path / "reference"
    started = time.monotonic()
    plain = subprocess.run(kills.compare_cmd(reference, *SOAK_ARGS), capture_output=True, text=True, env=env,
                           timeout=900)
    horizon = time.monotonic() - started
    assert plain.returncode == 0, plain.stdout[-3000:] + plain.stderr[-3000:]
    kills.wait_gone(marker)

    rng = np.random.default_rng(14)
    out, ways = tmp_path / "cmp", []
    step_s = horizon / max(_checkpoints_written(reference), 1)
    for attempt in range(10):
        way = _kill_at_a_random_moment(out, env, marker, rng, step_s, tmp_path / f"attempt_{attempt}.log")
        if way is None:
            break
        ways.append(way)
        kills.check_intact(out)
        if len(ways) == 6:
            break
    assert len(ways) >= 3, ways

    final = subprocess.run(kills.compare_cmd(out, *SOAK_ARGS), capture_output=True, text=True, env=env,
                           timeout=900)
    assert final.returncode == 0, final.stdout[-3000:] + final.stderr[-3000:]
    kills.check_intact(out)
    assert kills.temporary_files(out / "runs") == []

    # The table: the same shape; the rule-based row identical; the table of the evaluations on disk.
    ours, theirs = (json.loads((d / "table.json").read_text()) for d in (out, reference))
    assert (ours["args"].pop("out"), theirs["args"].pop("out")) == (str(out), str(reference))
    assert ours.keys() == theirs.keys() and ours["args"] == theirs["args"]
    rows, expected_rows = ({(r["config"], r["method"]): r for r in t["rows"]} for t in (ours, theirs))
    assert rows.keys() == expected_rows.keys() and all(rows[k].keys() == expected_rows[k].keys() for k in rows)
    assert rows[("n5_m2_dt120", "rule_based")] == expected_rows[("n5_m2_dt120", "rule_based")]
    assert (rows[("n5_m2_dt120", "ppo")]["seeds"], rows[("n5_m2_dt120", "ppo")]["samples"]) == (2, SOAK_BUDGET)
    assert ours["seed_means"].keys() == theirs["seed_means"].keys()
    regenerated = tables.build_table(tables.load_evaluations(out), reps=200)
    assert regenerated.markdown == (out / "table.md").read_text()

    # The evaluations: the same files and test episodes; each learned one of its run's best model.
    files = sorted(p.relative_to(out) for p in (out / "evaluations").glob("*/*.json"))
    assert files == sorted(p.relative_to(reference) for p in (reference / "evaluations").glob("*/*.json"))
    for rel in files:
        mine, plain_eval = (json.loads((d / rel).read_text()) for d in (out, reference))
        assert mine.keys() == plain_eval.keys() and mine["protocol"] == plain_eval["protocol"]
        assert [e["seed"] for e in mine["episodes"]] == [e["seed"] for e in plain_eval["episodes"]]
        run = mine["compare"]["run"]
        if run is None:
            assert mine == plain_eval, rel
        else:
            assert mine["compare"]["model_sha256"] == sha256_bytes((out / "runs" / run / "best_model.zip").read_bytes())
            assert {**mine["compare"], "model_sha256": None} == {**plain_eval["compare"], "model_sha256": None}

    # The runs.
    resumed = {}
    for seed in (1, 2):
        name = f"ppo_n5_m2_dt120_s{seed}"
        run, plain_run = out / "runs" / name, reference / "runs" / name
        log = (out / "runs" / ".sweep" / f"{name}.log").read_text()
        points = [int(n) for n in re.findall(r"resume from (\d+) samples", log)]
        rows_run, rows_plain = _metrics(run), _metrics(plain_run)
        steps = [int(r["timesteps"]) for r in read_metrics(run)]
        episodes = [r["episodes"] for r in read_metrics(run)]
        assert steps == sorted(set(steps)) and steps[-1] == SOAK_BUDGET, name
        assert all(b >= a for a, b in zip(episodes, episodes[1:])), name  # a rollout may end no episode
        assert load_model(run / "final_model.zip", "ppo").num_timesteps == SOAK_BUDGET
        assert read_run_summary(run)["resumed_from"] == (points[-1] if points else None), name
        ours_ckpts, plain_ckpts = dict(checkpoints(run)), dict(checkpoints(plain_run))
        if points:  # identical up to the first checkpoint it resumed from
            resumed[name] = points
            first = points[0]
            assert [r for r in rows_run if int(r["timesteps"]) <= first] == \
                [r for r in rows_plain if int(r["timesteps"]) <= first], name
            assert first in ours_ckpts
            assert all(_same_policy(ours_ckpts[s], plain_ckpts[s]) for s in ours_ckpts if s <= first), name
        else:  # never resumed: the uninterrupted run exactly
            assert rows_run == rows_plain, name
            assert ours_ckpts.keys() == plain_ckpts.keys()
            assert all(_same_policy(ours_ckpts[s], plain_ckpts[s]) for s in ours_ckpts), name
            assert _same_policy(run / "final_model.zip", plain_run / "final_model.zip"), name
            assert _same_policy(run / "best_model.zip", plain_run / "best_model.zip"), name
            evaluation = f"evaluations/n5_m2_dt120/ppo_s{seed}.json"
            assert json.loads((out / evaluation).read_text())["episodes"] == \
                json.loads((reference / evaluation).read_text())["episodes"], name
    if not resumed:
        assert ours == theirs
    print(f"kills: {ways}; resumed runs: {resumed or 'none'}; uninterrupted compare {horizon:.0f} s")


def test_ctrl_c_under_load_ends_compare_quickly_and_leaves_no_process(tmp_path):
    """Ctrl-C (SIGINT to the process group, as a terminal sends it) while two trainings keep both
    cores busy: compare ends within 30 s with exit status 130 saying that the runs resume, and none
    of the processes it started (Ray's included) outlives it by more than 30 s."""
    out = tmp_path / "cmp"
    marker, env = kills.marked_env("CONTAINERGYM_CTRLC")
    with _ctrl_c_reaches_children():
        proc = subprocess.Popen(kills.compare_cmd(out, *KILL_ARGS), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True, env=env, start_new_session=True)
    orphans = []
    try:
        _wait_for_checkpoint(out, RUN1, proc)
        # both trainings under way: each has logged a rollout (RUN1 has a checkpoint already)
        kills.wait(lambda: all((out / "runs" / run / "metrics.csv").is_file() for run in (RUN1, RUN2)), 120,
                   "both runs to train")
        started = time.monotonic()
        os.killpg(proc.pid, signal.SIGINT)
        output, _ = proc.communicate(timeout=120)
        elapsed = time.monotonic() - started
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        try:
            kills.wait_gone(marker, timeout_s=30)
        except TimeoutError:
            orphans = kills.processes_with(marker)
            kills.kill_tree(marker)  # so that a failed check leaves no process behind
    assert proc.returncode == 130, output[-3000:]
    assert elapsed < 30, f"compare took {elapsed:.0f} s to stop after Ctrl-C"
    assert "interrupted: finished runs are kept, the others resume from their last checkpoint" in output
    assert orphans == [], f"processes of the compare outlived it by 30 s: {orphans}"


_PROBE = """
import sys
import ray
try:
    ray.init(address=sys.argv[1], logging_level="ERROR", log_to_driver=False)
    print("CONNECTED")
except Exception as exc:
    print("REFUSED", type(exc).__name__)
"""


def test_a_local_instance_refuses_clients_without_its_token(tmp_path):
    """A local instance's servers listen on every interface (Ray 2.60 cannot bind them to
    localhost, whatever ``_node_ip_address`` says); what keeps other hosts out is Ray's token
    authentication, which Ray turns on for every new local instance (its token in
    ``~/.ray/auth_token``, readable by this user only through the home folder). A client without the
    token, or with another one, is refused; the driver's own processes have it."""
    import ray

    from containergym_marl.orchestration.cluster import Cluster

    if os.environ.get("RAY_AUTH_MODE", "token") != "token":
        pytest.skip("RAY_AUTH_MODE turns Ray's token authentication off here")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("RAY_AUTH", "RAY_ADDRESS"))}
    with pytest.MonkeyPatch.context() as mp:
        mp.delenv("RAY_ADDRESS", raising=False)
        with Cluster(num_cpus=1) as cluster:
            cluster.ray()
            gcs = ray.get_runtime_context().gcs_address

            def probe(extra: dict) -> str:
                r = subprocess.run([sys.executable, "-c", _PROBE, gcs], env={**env, **extra}, capture_output=True,
                                   text=True, timeout=120)
                return r.stdout.strip()

            assert probe({}) == "REFUSED ConnectionError"
            assert probe({"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": "0" * 64}) == "REFUSED ConnectionError"
            assert probe({"RAY_AUTH_MODE": "token"}) == "CONNECTED"  # the token Ray keeps for this user
