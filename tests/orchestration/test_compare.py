"""compare without Ray: the method registry, budgets, argument checks, what a training task does with
a run directory, progress, and the one table builder (bootstrap streams independent of other rows).

The sweeps themselves (local Ray, a two-node cluster, a killed worker) are in test_sweep*.py."""

from __future__ import annotations

import io
import json
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from containergym_marl.cli import build_parser, main
from containergym_marl.orchestration import CompareArgs, compare
from containergym_marl.orchestration.compare_args import args_from_namespace
from containergym_marl.orchestration.plan import run_specs
from containergym_marl.evaluation import EvalProtocol
from containergym_marl.evaluation import table as tables
from containergym_marl.methods import METHODS, PAIRS
from containergym_marl.rundir import RunError, RunWarning, measured_rate, small_files
from containergym_marl.orchestration.sweep_progress import Progress
from containergym_marl.orchestration.tasks import MetricsReporter, RunSpec, prepare_run


# ---- methods, runs, budgets ---------------------------------------------------------------------
def test_method_registry_names_runs_and_gives_the_paper_budget(tmp_path):
    args = CompareArgs(configs=["n5_m2_dt120", "n11_m2_dt60"], methods=["rule_based", "ppo", "shared_ppo_team"],
                       seeds=[1, 2], timesteps=None)
    specs = {s.name: s for s in run_specs(args, tmp_path)}
    assert sorted(specs) == sorted(f"{m}_{c}_s{s}" for m in ("ppo", "shared_ppo_team")
                                   for c in ("n5_m2_dt120", "n11_m2_dt60") for s in (1, 2))
    assert specs["ppo_n5_m2_dt120_s1"].timesteps == 2_000_000  # the paper's budgets
    assert specs["ppo_n11_m2_dt60_s2"].timesteps == 5_000_000
    assert [s.timesteps for s in run_specs(args, tmp_path)][:4] == [5_000_000] * 4  # longest first
    team = specs["shared_ppo_team_n11_m2_dt60_s1"]
    assert team.run_dir == str(tmp_path / "shared_ppo_team_n11_m2_dt60_s1")
    ta = team.train_args(resume=True)
    # the δ = 60 row trains on its own config (δ = 60 s); team rewards; one torch thread
    assert (ta.algo, ta.config, ta.seed, ta.reward_mode, ta.resume, ta.torch_threads, ta.progress_bar) == (
        "shared_ppo", "n11_m2_dt60", 1, "team", True, 1, False)
    assert specs["ppo_n5_m2_dt120_s1"].train_args(False).reward_mode == "individual"
    assert METHODS["shared_ppo_team"].algo == METHODS["shared_ppo"].algo == "shared_ppo"
    assert {("shared_ppo", "ppo"), ("shared_ppo_team", "ppo"), ("rule_based_agents", "rule_based")} <= set(PAIRS)
    explicit = run_specs(CompareArgs(methods=["ppo"], seeds=[3], timesteps=4096), tmp_path)
    assert [(s.name, s.timesteps) for s in explicit] == [("ppo_n5_m2_dt120_s3", 4096)]


def test_duplicate_seeds_unknown_methods_and_configs_are_rejected_before_any_work(tmp_path, capsys):
    from containergym_marl import ConfigError

    out = tmp_path / "never"
    with pytest.raises(ValueError, match="seeds: 1 given more than once"):
        compare(CompareArgs(out=str(out), seeds=[1, 1]))
    with pytest.raises(ValueError, match="methods: ppo given more than once"):
        compare(CompareArgs(out=str(out), methods=["ppo", "ppo"]))
    with pytest.raises(ValueError, match="unknown method"):
        compare(CompareArgs(out=str(out), methods=["a2c"]))
    with pytest.raises(ConfigError):
        compare(CompareArgs(out=str(out), configs=["n9"]))
    assert not out.exists()
    assert main(["compare", "--train", "--seeds", "1", "1", "--out", str(out)]) == 2
    assert "seeds: 1 given more than once" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["compare", "--methods", "a2c"])
    assert not out.exists()


def test_compare_help_shows_the_defaults(capsys):
    with pytest.raises(SystemExit):
        main(["compare", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for expected in ("--timesteps N|paper", "(default with --train: 30000)", "(default: 1 2 3)",
                     "(default: paper)", "(default: the protocol's)", "(default: results/compare)",
                     "; n5_m2_dt120 with --train)",
                     "(default: results/paper_rows,", "(default: 200000)", "(default: 3)", "(default: 2000)",
                     "$RAY_ADDRESS", "shared_ppo_team"):
        assert expected in text, expected
    parse = build_parser().parse_args
    assert not hasattr(parse(["compare"]), "timesteps")  # not given: the shipped policies, nothing trained
    assert args_from_namespace(parse(["compare", "--train", "--timesteps", "paper"])).timesteps is None  # paper budget
    assert args_from_namespace(parse(["compare", "--train", "--timesteps", "2e6"])).timesteps == 2_000_000


def _zip(path, payload=b"x"):
    """A file with an SB3 model zip's members (what the run-directory rules check, not load)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("data", payload)
        z.writestr("policy.pth", payload)


def _spec(run_dir, timesteps=256) -> RunSpec:
    return RunSpec("ppo_n5_m2_dt120_s1", "ppo", "ppo", "n5_m2_dt120", 1, timesteps, str(run_dir))


def test_a_finished_run_with_another_budget_is_refused_without_ray(tmp_path):
    run = tmp_path / "runs" / "ppo_n5_m2_dt120_s1"
    _zip(run / "final_model.zip")
    (run / "args.json").write_text(json.dumps({"algo": "ppo", "timesteps": 256}))
    args = dict(out=str(tmp_path), methods=["ppo"], seeds=[1], figures="none")
    with pytest.raises(ValueError, match="budget of 256 samples, not 512"):
        compare(CompareArgs(timesteps=512, **args))
    assert prepare_run(_spec(run, 256)) == ("finished", 256)
    with pytest.raises(ValueError, match="budget of 256 samples, not 512"):
        prepare_run(_spec(run, 512))


def test_a_training_task_resumes_from_the_latest_intact_checkpoint(tmp_path):
    run = tmp_path / "ppo_n5_m2_dt120_s1"
    (run / "checkpoints").mkdir(parents=True)
    (run / "args.json").write_text(json.dumps({"algo": "ppo", "timesteps": 4096}))
    _zip(run / "checkpoints" / "ckpt_1024_steps.zip")
    (run / "checkpoints" / "ckpt_2048_steps.zip").write_bytes(b"PK\x03\x04 cut short by a kill")
    (run / "best_model.zip").write_bytes(b"PK\x03\x04 cut short")
    (run / "final_model.zip").write_bytes(b"PK\x03\x04 cut short")  # not a finished run
    with pytest.warns(RunWarning, match="set aside"):
        assert prepare_run(_spec(run, 4096)) == ("resume", 1024)
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["ckpt_1024_steps.zip",
                                                                        "ckpt_2048_steps.zip.broken"]
    assert not (run / "best_model.zip").exists()
    # died before its first checkpoint: start over, with what training wrote cleared
    (run / "checkpoints" / "ckpt_1024_steps.zip").unlink()
    assert prepare_run(_spec(run, 4096)) == ("new", 0)
    assert [p.name for p in run.iterdir()] == [".lock"]
    assert prepare_run(_spec(run, 4096)) == ("new", 0)


def test_a_run_directory_with_foreign_files_is_never_cleared(tmp_path):

    run = tmp_path / "ppo_n5_m2_dt120_s1"
    run.mkdir()
    (run / "notes.txt").write_text("mine")
    with pytest.raises(RunError, match="notes.txt"):
        prepare_run(_spec(run, 4096))
    assert (run / "notes.txt").read_text() == "mine"


def test_a_run_that_a_running_train_holds_is_never_cleared(tmp_path):
    """compare --train against a run that `containergym-marl train` is training (it holds the run's
    lock, before its first checkpoint): the sweep's preparation fails naming the holder and deletes
    nothing (it used to remove the directory under the running writer)."""
    import subprocess
    import sys
    import time


    run = tmp_path / "ppo_n5_m2_dt120_s1"
    proc = subprocess.Popen([sys.executable, "-m", "containergym_marl.cli", "train", "--algo", "ppo", "--out", str(run),
                             "--timesteps", "10000000", "--no-progress"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        # wait for what is asserted: the writer takes the lock, then writes args.json (waiting for the
        # lock alone raced the second step on a busy machine); the deadline only guards against a hang
        deadline = time.time() + 600
        while proc.poll() is None and time.time() < deadline and not (
                (run / "args.json").is_file() and (run / ".lock").is_file() and (run / ".lock").read_text()):
            time.sleep(0.1)
        assert proc.poll() is None, "the training process ended before the test could check its run"
        assert (run / "args.json").is_file()
        with pytest.raises(RunError, match="in use by another writer"):
            prepare_run(_spec(run, 10_000_000))
        assert (run / "args.json").is_file() and proc.poll() is None
    finally:
        proc.kill()
        proc.wait()


def test_a_training_task_returns_what_a_driver_without_shared_storage_needs(tmp_path):
    """The task body without Ray: it trains, returns the run's small files (no checkpoints, no
    TensorBoard logs) from which another machine's copy is a finished run that evaluates the same;
    run again, it trains nothing."""
    from containergym_marl.manifest import sha256_bytes
    from containergym_marl.rundir import finished_budget, write_files
    from containergym_marl.orchestration.tasks import EvalSpec, evaluate_policy, train_run

    spec = RunSpec("ppo_n5_m2_dt120_s1", "ppo", "ppo", "n5_m2_dt120", 1, 256, str(tmp_path / "node" / "run"),
                   {"n_envs": 1, "checkpoint_every": 128, "hyperparams": {"n_steps": 128, "batch_size": 64}})
    result = train_run(spec)
    assert (result["state"], result["samples"], result["resumed_from"]) == ("new", 256, 0)
    assert any((tmp_path / "node" / "run" / "checkpoints").iterdir())
    assert {"args.json", "config.toml", "best_model.zip", "final_model.zip"} <= set(result["files"])
    assert not any(f.startswith(("checkpoints/", "tb/")) for f in result["files"])
    assert sorted(p.name for p in (tmp_path / "node" / ".sweep").iterdir()) == ["ppo_n5_m2_dt120_s1.log"]

    driver = tmp_path / "driver" / "run"
    assert write_files(driver, result["files"]) == len(result["files"])
    assert write_files(driver, result["files"]) == 0  # same content: nothing rewritten
    assert finished_budget(driver) == 256
    spec_eval = EvalSpec("ppo_s1", "ppo", "n5_m2_dt120", EvalProtocol(episodes=1), seed=1)
    here, sha = evaluate_policy(spec_eval, {"files": small_files(driver)})
    there, _ = evaluate_policy(spec_eval, result)
    assert sha == sha256_bytes(result["files"]["best_model.zip"]) and here.returns.tolist() == there.returns.tolist()
    assert here.records == []  # records only when the figures ask for them

    again = train_run(spec)
    assert (again["state"], again["samples"]) == ("finished", 0) and again["files"] == result["files"]


def test_a_run_returns_to_the_driver_neither_temporary_files_nor_its_lock(tmp_path):
    """What a training task ships to the driver is the run's files, not the temporary file of a
    write a kill cut short, nor the lock file of the process that trained it."""
    run = tmp_path / "run"
    _zip(run / "final_model.zip")
    (run / "args.json").write_text("{}")
    (run / ".lock").write_text("pid 4242 on host node-2\n")
    (run / ".best_model.zip.k1ll3d_0.tmp").write_bytes(b"PK\x03\x04 cut short by a kill")
    (run / "checkpoints").mkdir()
    _zip(run / "checkpoints" / "ckpt_128_steps.zip")
    assert sorted(small_files(run)) == ["args.json", "final_model.zip"]


def test_the_driver_writes_a_run_s_files_crash_safe(tmp_path, monkeypatch):
    """write_files goes through a temporary file that is renamed: when the write fails (or the driver
    is killed) the old file stays whole and no part of the new one is left behind."""
    import os

    from containergym_marl.rundir import write_files

    run = tmp_path / "run"
    write_files(run, {"args.json": b'{"timesteps": 1}'})
    real = os.replace

    def disk_full(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", disk_full)
    with pytest.raises(OSError, match="No space"):
        write_files(run, {"args.json": b'{"timesteps": 2}', "best_model.zip": b"PK"})
    monkeypatch.setattr(os, "replace", real)
    assert sorted(p.name for p in run.iterdir()) == ["args.json"]
    assert (run / "args.json").read_bytes() == b'{"timesteps": 1}'


def test_two_sweeps_never_train_one_run_at_once(tmp_path):
    """A training task takes the run's lock (the one `train` takes); while another process holds it,
    the task fails naming the holder and leaves the run untouched."""
    pytest.importorskip("fcntl")
    import subprocess
    import sys

    from containergym_marl.orchestration.tasks import train_run

    spec = _spec(tmp_path / "runs" / "ppo_n5_m2_dt120_s1")
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time; from containergym_marl.rundir import RunLock; "
                               f"lock = RunLock({spec.run_dir!r}).acquire(); print('held', flush=True); time.sleep(60)"],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(RunError, match=rf"in use by another writer \(pid {holder.pid} "):
            train_run(spec)
    finally:
        holder.kill()
        holder.wait()
    assert sorted(p.name for p in Path(spec.run_dir).iterdir()) == [".lock"]


def _metrics(run: Path, rows: list[tuple[int, float]]) -> None:
    from containergym_marl.rundir import METRIC_FIELDS

    run.mkdir(parents=True, exist_ok=True)
    full = [{**dict.fromkeys(METRIC_FIELDS, 0), "timesteps": t, "wall_time_s": w} for t, w in rows]
    (run / "metrics.csv").write_text(",".join(METRIC_FIELDS) + "\n" + "".join(
        ",".join(str(r[k]) for k in METRIC_FIELDS) + "\n" for r in full))


def test_samples_per_second_of_the_last_uninterrupted_stretch(tmp_path):
    rows = [(1000, 1.0), (2000, 2.0), (3000, 3.0)]
    _metrics(tmp_path, rows)
    assert measured_rate(tmp_path) == pytest.approx(1000.0)
    rows += [(4000, 0.5), (6000, 1.5)]  # resumed: wall time starts again
    _metrics(tmp_path, rows)
    assert measured_rate(tmp_path) == pytest.approx(2000.0)
    assert measured_rate(tmp_path / "missing") is None


def test_the_eta_rate_is_the_median_of_the_sweeps_own_runs(tmp_path):
    """estimate_rate reads the SB3 runs of the runs folder; MAPPO runs trained beside them (plant
    steps, ~250/s) do not drag the sweep's estimate down (they did when every metrics.csv counted)."""
    from containergym_marl.orchestration.sweep_progress import DEFAULT_RATE, estimate_rate

    def run(name: str, algo: str, rate: float) -> None:
        folder = tmp_path / name
        _metrics(folder, [(round(rate), 1.0), (round(2 * rate), 2.0)])
        (folder / "args.json").write_text(json.dumps({"algo": algo}))

    assert estimate_rate(tmp_path) == DEFAULT_RATE
    run("ppo_a_s1", "ppo", 3000)
    run("shared_ppo_a_s1", "shared_ppo", 3200)
    run("ppo_a_s2", "ppo", 2800)
    for seed in (1, 2, 3, 4):
        run(f"mappo_a_s{seed}", "mappo", 250)
    assert estimate_rate(tmp_path) == pytest.approx(3000.0)


def test_a_training_task_reports_samples_and_rate_from_its_metrics(tmp_path):
    class Events(list):
        put_nowait = list.append

    _metrics(tmp_path, [(1000, 9.0)])  # a row of an earlier attempt
    events = Events()
    reporter = MetricsReporter(tmp_path, "run", events, start_samples=1000, every_s=0.02)
    reporter.start()
    time.sleep(0.2)
    assert events == []
    _metrics(tmp_path, [(1000, 9.0), (1500, 1.0), (2000, 2.0)])
    deadline = time.monotonic() + 10
    while not events and time.monotonic() < deadline:
        time.sleep(0.02)
    reporter.stop()
    reporter.join(5)
    assert events[-1] == ("progress", "run", 2000, pytest.approx(500.0))


def test_progress_line_counts_runs_and_estimates_the_time_left():
    stream = io.StringIO()
    p = Progress({"a": 1000, "b": 1000, "c": 1000}, evaluations=3, cpus=2, stream=stream)
    p.started("a", "host1", 11, "new", 0)
    p.started("b", "host2", 12, "resume", 400)
    p.sampled("a", 500, 100.0)
    p.sampled("b", 600, 100.0)
    line = p.line()
    assert "runs 0/3 done, 2 running, 1 queued" in line and "evaluations 0/3" in line
    assert "a 50% 100/s" in line and "b 60% 100/s" in line
    assert p.eta_s() == pytest.approx((500 + 400 + 1000) / (100.0 * 2))
    p.run_done("a", {"state": "new", "resumed_from": 0, "samples": 1000, "wall_s": 10.0, "samples_per_s": 100.0,
                     "host": "host1"})
    p.started("b", "host1", 13, "resume", 600)  # its worker died; Ray runs it again
    p.eval_done()
    assert "runs 1/3 done, 1 running, 1 queued" in p.line() and "evaluations 1/3" in p.line()
    text = stream.getvalue()
    assert "resume b from its checkpoint at 400 samples" in text
    assert "done a: trained, 1,000 samples in 10s (100 samples/s) on host1" in text
    assert "retry b (attempt 2, resume from 600 samples) on host1" in text
    p.tick(force=True)
    assert stream.getvalue().splitlines()[-1].startswith("[")


# ---- the table ----------------------------------------------------------------------------------
def _evaluation(returns, view="centralised", overflow=0.0, timesteps=None) -> dict:
    data = {"view": view, "protocol": {"timestep_s": 120.0, "episode_length_steps": 600, "episodes": len(returns)},
            "summary": {"overflow_rate": overflow, "emptyings_mean": 60.0, "good_emptying_share": 0.9,
                        "denied_requests_mean": 1.0, "pu_utilisation": 0.2},
            "episodes": [{"cumulative_reward": float(r)} for r in returns]}
    if timesteps:
        data["compare"] = {"timesteps": timesteps}
    return data


def _write(directory, name, data):
    directory.mkdir(parents=True, exist_ok=True)
    (directory / f"{name}.json").write_text(json.dumps(data))


def _results(root, rng):
    """An output folder with two configs, rule-based controllers and 5 seeds of two learned methods."""
    for config in ("n5_m2_dt120", "n11_m2_dt120"):
        d = root / "evaluations" / config
        _write(d, "rule_based", _evaluation(rng.normal(50, 3, 15)))
        _write(d, "rule_based_agents", _evaluation(rng.normal(52, 3, 15), "decentralised"))
        for seed in range(1, 6):
            _write(d, f"ppo_s{seed}", _evaluation(rng.normal(40 + 3 * seed, 2, 15), timesteps=2_000_000))
            _write(d, f"shared_ppo_s{seed}", _evaluation(rng.normal(45 + seed, 2, 15), "decentralised",
                                                         timesteps=2_000_000))


def test_table_rows_best_median_order_and_improvements(tmp_path):
    _results(tmp_path, np.random.default_rng(1))
    groups = tables.load_evaluations(tmp_path)
    assert [(g.config, g.method) for g in groups][:4] == [
        ("n5_m2_dt120", "rule_based"), ("n5_m2_dt120", "rule_based_agents"), ("n5_m2_dt120", "ppo"),
        ("n5_m2_dt120", "shared_ppo")]  # paper order of configs, rule-based first
    table = tables.build_table(groups, reps=500)
    row = next(r for r in table.rows if (r["config"], r["method"]) == ("n5_m2_dt120", "ppo"))
    ppo = next(g for g in groups if (g.config, g.method) == ("n5_m2_dt120", "ppo"))
    means = ppo.seed_means
    assert row["best_mean"] == pytest.approx(means.max()) and row["best_seed"] == int(np.argmax(means)) + 1
    assert row["median_mean"] == pytest.approx(np.sort(means)[2])
    even = tables.MethodEvaluations("c", "m", [1, 2, 3, 4], [_evaluation([v]) for v in (3.0, 1.0, 4.0, 2.0)])
    assert (even.best, even.median) == (2, 3)  # 4.0 best; of the middle 3.0 and 2.0, the lower
    assert row["iqm_low"] <= row["iqm"] <= row["iqm_high"] and row["seeds"] == 5 and row["samples"] == 2_000_000
    assert "| n5_m2_dt120 | ppo | centralised | 5 |" in table.markdown and "| 2M |" in table.markdown
    assert "| n11_m2_dt120 | paper DQN (15 seeds) | centralised | 15 | 72.19 ± 16.20 |" in table.markdown
    pairs = {(i["config"], i["decentralised"], i["centralised"]): i for i in table.improvements}
    assert set(pairs) == {(c, d, e) for c in ("n5_m2_dt120", "n11_m2_dt120")
                          for d, e in (("shared_ppo", "ppo"), ("rule_based_agents", "rule_based"))}
    assert pairs[("n5_m2_dt120", "rule_based_agents", "rule_based")]["unit"] == "test episodes"
    assert table.markdown.index("n5_m2_dt120 | rule_based") < table.markdown.index("n11_m2_dt120 | rule_based")


def test_bootstrap_intervals_do_not_depend_on_the_other_rows(tmp_path):
    """Each interval has its own stream (TABLE_SEED and its names): the same data give the same
    interval alone, with other methods and configs, and in any order."""
    _results(tmp_path, np.random.default_rng(2))
    groups = tables.load_evaluations(tmp_path)
    full = tables.build_table(groups, reps=400)
    key = ("n11_m2_dt120", "ppo")
    alone = tables.build_table([g for g in groups if (g.config, g.method) == key], reps=400)
    row = next(r for r in full.rows if (r["config"], r["method"]) == key)
    assert row["iqm_low"] < row["iqm_high"]  # a real interval, not a degenerate one
    assert (alone.rows[0]["iqm_low"], alone.rows[0]["iqm_high"]) == (row["iqm_low"], row["iqm_high"])

    pair = [g for g in groups if g.config == "n11_m2_dt120" and g.method in ("ppo", "shared_ppo")]
    only_pair = tables.build_table(pair[::-1], reps=400).improvements
    in_full = [i for i in full.improvements if i["config"] == "n11_m2_dt120" and i["decentralised"] == "shared_ppo"]
    assert only_pair == in_full and in_full[0]["low"] < in_full[0]["high"]
    # one stream per interval, named by what it is about
    draw = lambda *names: tables.bootstrap_rng(*names).integers(2**62, size=4).tolist()  # noqa: E731
    assert draw("iqm", "n11_m2_dt120", "ppo") == draw("iqm", "n11_m2_dt120", "ppo")
    assert draw("iqm", "n11_m2_dt120", "ppo") != draw("iqm", "n11_m2_dt120", "shared_ppo")
    assert draw("iqm", "n11_m2_dt120", "ppo") != draw("iqm", "n5_m2_dt120", "ppo")


def test_the_table_is_regenerated_from_the_evaluation_files(tmp_path, capsys):
    _results(tmp_path, np.random.default_rng(3))
    assert tables.main([str(tmp_path), "--out", str(tmp_path / "again"), "--bootstrap-reps", "300"]) == 0
    printed = capsys.readouterr().out
    expected = tables.build_table(tables.load_evaluations(tmp_path / "evaluations"), reps=300)
    assert (tmp_path / "again" / "table.md").read_text() == expected.markdown
    assert printed.startswith(expected.markdown)
    saved = json.loads((tmp_path / "again" / "table.json").read_text())
    assert saved["rows"] == json.loads(json.dumps(expected.rows))
    one_config = tables.markdown_table(tmp_path / "evaluations" / "n5_m2_dt120", reps=300)
    assert "n11_m2_dt120" not in one_config and "| n5_m2_dt120 | shared_ppo | decentralised | 5 |" in one_config
    with pytest.raises(FileNotFoundError, match="no evaluation files"):
        tables.load_evaluations(tmp_path / "again")


def test_the_terminal_table_keeps_the_iqm_and_drops_other_columns_where_they_do_not_fit(tmp_path):
    _results(tmp_path, np.random.default_rng(5))
    table = tables.build_table(tables.load_evaluations(tmp_path), reps=200)
    wide, narrow = io.StringIO(), io.StringIO()
    tables.print_table(table, wide)
    tables.print_table(table, narrow, width=100)
    for text, width in ((wide.getvalue(), 140), (narrow.getvalue(), 100)):
        lines = text.splitlines()
        assert all(len(line) <= width and line == line.rstrip() for line in lines)
        assert "…" not in text  # nothing cut short
        assert "P(" in text
    assert "IQM [95 % CI]" in wide.getvalue() and "decentralised" in wide.getvalue()
    assert "IQM [95 % CI]" in narrow.getvalue() and "(views, medians, budgets, TRPO" in " ".join(narrow.getvalue().split())
    row = tables.table_rows(tables.load_evaluations(tmp_path), reps=200)[0]
    assert f"{row['best_mean']:.2f} ± {row['best_std']:.2f}" in narrow.getvalue()
    learned = next(r for r in tables.table_rows(tables.load_evaluations(tmp_path), reps=200) if r["seeds"])
    assert f"{learned['iqm']:.2f} [{learned['iqm_low']:.2f}, {learned['iqm_high']:.2f}]" in narrow.getvalue()
    assert f"{learned['median_mean']:.2f} ± {learned['median_std']:.2f}" not in narrow.getvalue()
