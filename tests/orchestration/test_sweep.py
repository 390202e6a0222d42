"""compare on a local Ray instance (2 CPUs): a tiny sweep trains two runs and writes the table and
figures; rerunning it trains nothing, evaluates nothing and starts no Ray at all.

Slower checks (a two-node cluster through --address, a training worker killed mid-run) are in
test_sweep_slow.py."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("ray")

from containergym_marl.orchestration import CompareArgs, compare  # noqa: E402
from containergym_marl.evaluation import table as tables  # noqa: E402
from containergym_marl.rundir import RunLock  # noqa: E402

TINY = dict(configs=["n5_m2_dt120"], methods=["rule_based", "rule_based_agents", "ppo"], seeds=[1, 2],
            timesteps=1024, episodes=2, n_envs=1, checkpoint_every=512, bootstrap_reps=200, num_cpus=2,
            hyperparams={"n_steps": 128, "batch_size": 64})
RUNS = ("ppo_n5_m2_dt120_s1", "ppo_n5_m2_dt120_s2")


# a local Ray sweep of SB3 runs, ~1 min; test_compare_trains_and_evaluates_the_native_ppo_methods runs Ray in the default suite
@pytest.mark.slow
def test_tiny_sweep_on_local_ray_then_a_rerun_trains_nothing(tmp_path, capsys):
    out = tmp_path / "cmp"
    report = compare(CompareArgs(out=str(out), figures="all", **TINY))
    sweep = report["sweep"]
    assert sweep["ray"] == "local Ray instance: 1 node, 2 CPUs"
    assert sorted(r["name"] for r in sweep["trained"]) == list(RUNS)
    assert all(r["state"] == "new" and r["samples"] == 1024 and r["attempts"] == 1 for r in sweep["trained"])
    assert sorted(sweep["evaluated"]) == ["n5_m2_dt120/ppo_s1", "n5_m2_dt120/ppo_s2", "n5_m2_dt120/rule_based",
                                          "n5_m2_dt120/rule_based_agents"]
    printed = capsys.readouterr().out
    assert "runs 0/2 done" in printed and f"done {RUNS[0]}: trained, 1,024 samples" in printed
    # how long the training will take, said before it starts
    assert printed.index("training: 2,048 samples in 2 run(s), about ") < printed.index(f"done {RUNS[0]}")
    assert " ppo " in printed and "P(rule_based_agents > rule_based)" in printed  # the table, in the terminal
    assert f"table: {out / 'table.md'}" in printed and f"figures: {out / 'figures'}/" in printed

    for run in RUNS:
        files = {p.name for p in (out / "runs" / run).iterdir()}
        assert {"args.json", "config.toml", "best_model.zip", "final_model.zip", "checkpoints"} <= files
        RunLock(out / "runs" / run).acquire().release()  # the task released the run's lock when it ended
    rows = {r["method"]: r for r in report["rows"]}
    assert list(rows) == ["rule_based", "rule_based_agents", "ppo"]
    assert rows["ppo"]["seeds"] == 2 and rows["ppo"]["samples"] == 1024
    assert rows["ppo"]["best_mean"] >= rows["ppo"]["median_mean"]  # 2 seeds: the median is the worse one
    assert rows["ppo"]["median_mean"] == min(report["seed_means"]["n5_m2_dt120/ppo"])
    assert [(i["decentralised"], i["centralised"]) for i in report["improvements"]] == [
        ("rule_based_agents", "rule_based")]
    evaluation = json.loads((out / "evaluations" / "n5_m2_dt120" / "ppo_s1.json").read_text())
    assert evaluation["compare"]["run"] == RUNS[0] and len(evaluation["episodes"]) == 2
    figures = {p.name for p in (out / "figures").iterdir()}
    assert {"n5_m2_dt120_reward_ecdf.svg", "n5_m2_dt120_pu_timeline_ppo.png",
            "n5_m2_dt120_episode_rule_based_agents.png", "n5_m2_dt120_reward_function_C1-20.png"} <= figures
    # the one table builder: the committed evaluation files give back the same table
    regenerated = tables.build_table(tables.load_evaluations(out), reps=TINY["bootstrap_reps"])
    assert regenerated.markdown == (out / "table.md").read_text()
    assert json.loads((out / "sweep.json").read_text())["trained"][0]["name"] in RUNS

    # The same command again: finished runs and their evaluations are found from the files; no
    # training, no evaluation, no Ray; same numbers.
    stamps = {p: p.stat().st_mtime_ns for p in (out / "runs").rglob("*") if p.is_file()}
    again = compare(CompareArgs(out=str(out), **{**TINY, "figures": "none"}))
    assert again["sweep"]["trained"] == [] and again["sweep"]["evaluated"] == [] and again["sweep"]["ray"] is None
    assert sorted(again["sweep"]["reused"]) == list(RUNS)
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps
    assert json.dumps(again["rows"]) == json.dumps(report["rows"])  # (NaN shares compare equal as JSON)


@pytest.mark.slow  # kills and restarts compare on Ray, ~1 min
def test_compare_killed_once_then_the_same_command_resumes_and_finishes(tmp_path):
    """The short variant of test_sweep_slow.py's random kills: SIGKILL to every process of a running
    compare (driver, Ray, workers) once its run has a checkpoint. Nothing of it lives on, every file a
    rerun reads is whole, and the same command resumes the run from its checkpoint and finishes.
    The run's history up to that checkpoint (metrics rows, the checkpoints' policies) is that of a
    plain train() of the same run: training on one torch thread is deterministic (after the resume
    the simulations get fresh seeds, so the rest differs, see test_sweep_slow.py). The evaluation
    is of the run's best model as it ends, and no temporary file is left in the run."""
    import dataclasses
    import re
    import subprocess
    from pathlib import Path

    import numpy as np

    from containergym_marl.orchestration.plan import run_specs
    from containergym_marl.manifest import sha256_bytes
    from containergym_marl.training import train
    from containergym_marl.rundir import checkpoints, read_metrics, read_run_summary
    from containergym_marl.models import load_model
    from tests.orchestration import compare_kills as kills

    budget, name = 2048, "ppo_n5_m2_dt120_s1"
    argv = ("--methods", "rule_based", "ppo", "--seeds", "1", "--timesteps", str(budget), "--checkpoint-every",
            "512", "--hp", "n_steps=128", "batch_size=64", "--no-figures", "--num-cpus", "2")
    out = tmp_path / "cmp"
    run = out / "runs" / name
    marker, env = kills.marked_env()
    proc = kills.start(out, argv, env, tmp_path / "killed.log")
    try:
        kills.wait(lambda: proc.poll() is not None or any((run / "checkpoints").glob("ckpt_*_steps.zip")), 300,
                   "a checkpoint", every_s=0.05)
        assert proc.poll() is None, (tmp_path / "killed.log").read_text()[-3000:]
    finally:
        kills.kill_tree(marker)
        proc.wait()
    kills.wait_gone(marker)
    kills.check_intact(out)
    assert not (run / "final_model.zip").exists()

    again = subprocess.run(kills.compare_cmd(out, *argv), capture_output=True, text=True, env=env, timeout=600)
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr[-3000:]
    kills.check_intact(out)
    assert kills.temporary_files(out / "runs") == []
    point = read_run_summary(run)["resumed_from"]
    assert f"resume {name} from its checkpoint at {point:,} samples" in again.stdout
    assert re.findall(r"resume from (\d+) samples", (out / "runs" / ".sweep" / f"{name}.log").read_text()) == [
        str(point)]
    assert load_model(run / "final_model.zip", "ppo").num_timesteps == budget
    evaluation = json.loads((out / "evaluations" / "n5_m2_dt120" / "ppo_s1.json").read_text())
    assert evaluation["compare"]["model_sha256"] == sha256_bytes((run / "best_model.zip").read_bytes())

    args = CompareArgs(methods=["ppo"], seeds=[1], timesteps=budget, n_envs=1, checkpoint_every=512,
                       hyperparams={"n_steps": 128, "batch_size": 64})
    (spec,) = run_specs(args, out / "runs")
    plain = Path(train(dataclasses.replace(spec, run_dir=str(tmp_path / "plain")).train_args(False)))

    def upto(rows):
        return [{k: v for k, v in r.items() if k != "wall_time_s"} for r in rows if r["timesteps"] <= point]

    # a row per rollout, as the plain run: none lost, none twice
    assert [r["timesteps"] for r in read_metrics(run)] == [r["timesteps"] for r in read_metrics(plain)]
    assert upto(read_metrics(run)) == upto(read_metrics(plain))
    ours, theirs = dict(checkpoints(run)), dict(checkpoints(plain))
    for s in (s for s in ours if s <= point):
        a, b = (load_model(c[s], "ppo").policy.state_dict() for c in (ours, theirs))
        assert all(np.array_equal(a[k].numpy(), b[k].numpy()) for k in a), s


@pytest.mark.slow  # trains three native methods and evaluates them on a local Ray instance, ~40 s
def test_compare_trains_and_evaluates_the_native_ppo_methods(tmp_path):
    """fast_ppo, fast_shared_ppo and fast_shared_ppo_team through compare on Ray: tensor-only run
    directories, evaluations, and the decentralised-against-centralised pairs in the table; a rerun
    reuses the finished runs (their final_model.pt)."""
    args = dict(configs=["n5_m2_dt120"], methods=["fast_ppo", "fast_shared_ppo", "fast_shared_ppo_team"],
                seeds=[1], timesteps=2048, episodes=2, n_envs=2, checkpoint_every=1024, bootstrap_reps=200,
                num_cpus=2, figures="none", hyperparams={"n_steps": 32, "minibatch_size": 256})
    out = tmp_path / "cmp"
    report = compare(CompareArgs(out=str(out), **args))
    names = sorted(r["name"] for r in report["sweep"]["trained"])
    assert names == ["fast_ppo_n5_m2_dt120_s1", "fast_shared_ppo_n5_m2_dt120_s1", "fast_shared_ppo_team_n5_m2_dt120_s1"]
    for name in names:
        files = {p.name for p in (out / "runs" / name).iterdir()}
        assert {"final_model.pt", "args.json"} <= files and not any(f.endswith(".zip") for f in files)
    team = json.loads((out / "runs" / "fast_shared_ppo_team_n5_m2_dt120_s1" / "args.json").read_text())
    assert team["algo"] == "fast_shared_ppo" and team["reward_mode"] == "team"
    assert [(i["decentralised"], i["centralised"]) for i in report["improvements"]] == [
        ("fast_shared_ppo", "fast_ppo"), ("fast_shared_ppo_team", "fast_ppo")]
    again = compare(CompareArgs(out=str(out), **args))
    assert again["sweep"]["trained"] == []


def test_the_local_instances_workers_train_at_the_callers_priority(monkeypatch):
    """Ray starts its workers at nice + 15, below every other process: a sweep's trainings would starve
    beside anything else the machine runs. The local instance compare starts keeps them at the caller's."""
    import os

    import ray

    from containergym_marl.orchestration.cluster import Cluster

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    with Cluster(num_cpus=1) as cluster:
        cluster.ray()
        niceness = ray.get(ray.remote(num_cpus=1)(lambda: os.nice(0)).remote())
    assert niceness == os.nice(0)
