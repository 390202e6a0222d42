"""benchmarks/throughput.py runs at tiny sizes and prints the documented tables (structure, not speed).

The run compares this checkout with itself (``--compare-with``, the before/after path) and has no
reference venv, so the earlier implementation's columns must be left out with a message.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "benchmarks" / "throughput.py"


def _table(lines: list[str], heading: str) -> tuple[list[str], list[list[str]]]:
    start = next(i for i, line in enumerate(lines) if line.startswith(heading))
    rows = []
    for line in lines[start + 1:]:
        if line.startswith("## "):
            break
        if line.startswith("|") and not line.startswith("|---"):
            rows.append([c.strip() for c in line.strip("|").split("|")])
    return rows[0], rows[1:]


def _number(cell: str) -> float:
    return float(cell.replace(",", "").rstrip("×"))


@pytest.mark.slow  # ~20 s
def test_smoke_run_prints_every_table(tmp_path):
    out_json = tmp_path / "throughput.json"
    env = {k: v for k, v in os.environ.items() if k != "CONTAINERGYM_REFERENCE_PYTHON"}
    proc = subprocess.run([sys.executable, str(SCRIPT), "--smoke", "--quiet", "--json", str(out_json),
                           "--compare-with", str(REPO)],
                          capture_output=True, text=True, timeout=300, check=True, env=env)
    lines = proc.stdout.splitlines()
    assert lines[0] == "# Throughput (smoke run)"
    assert any(line.startswith("- skipped: the earlier implementation: no --reference-python") for line in lines)
    assert any(line.startswith("- **ours**:") for line in lines)
    assert any(line.startswith("- **before**:") for line in lines)

    # B = 1: no reference columns without the reference venv
    header, rows = _table(lines, "## B = 1")
    assert header == ["path", "n", "B", "ours steps/s", "µs per call", "ours steps per CPU-second", "before steps/s",
                      "ours ÷ before"]
    assert {(r[0], r[1]) for r in rows} == {
        (path, n) for path in ("centralised env step (ContainerGymEnv)", "reset() alone (ContainerGymEnv)",
                               "PettingZoo parallel_env step (dict API)") for n in ("5", "11")}
    for r in rows:
        assert r[2] == "1" and all(_number(c) > 0 for c in r[3:7])
        assert r[7].endswith("×") and _number(r[7]) > 0
    assert any(line.startswith("PettingZoo parallel_env step time ÷ centralised step time: n = 5: ours ")
               for line in lines)

    header, rows = _table(lines, "## Vectorised envs")
    assert header == ["path", "n", "B", "ours env steps/s", "µs per call", "ours env steps per CPU-second",
                      "ours agent steps/s", "before env steps/s", "ours ÷ before"]
    assert [(r[0], r[1]) for r in rows] == [
        ("ContainerGymVecEnv (SB3)", "5"), ("ContainerGymVecEnv (SB3)", "11"),
        ("ContainerGymVectorEnv (Gymnasium make_vec)", "5"), ("ContainerGymVectorEnv (Gymnasium make_vec)", "11"),
        ("ContainerAgentsVecEnv (SB3)", "5"), ("ContainerAgentsVecEnv (SB3)", "11")]
    for r in rows:
        assert _number(r[3]) > 0 and _number(r[5]) > 0 and _number(r[7]) > 0 and r[8].endswith("×")
        if r[0].startswith("ContainerAgentsVecEnv"):  # agent steps = n × env steps
            assert abs(_number(r[6]) - int(r[1]) * _number(r[3])) <= int(r[1])
        else:
            assert r[6] == "–"
    from containergym_marl.core.dynamics import PARALLEL_MIN_BATCH
    assert (f"The step of a large batch runs in {os.cpu_count()} threads (ours from B = {PARALLEL_MIN_BATCH}, "
            f"before from B = {PARALLEL_MIN_BATCH})") in proc.stdout

    header, rows = _table(lines, "## Where the time goes at B = 1")
    assert header[:5] == ["path", "n", "untimed", "with timers", "kernel"] and "resets" in header
    assert len(rows) == 4 and all(len(r) == len(header) for r in rows)
    # every path steps the kernel and the core around it (both read 0.0 while the timers wrapped
    # functions the simulator no longer called)
    for r in rows:
        parts = dict(zip(header, r))
        assert _number(parts["kernel"]) > 0 and _number(parts["core around the kernel"]) > 0, parts

    header, rows = _table(lines, "## SB3 PPO training")
    assert header == ["algorithm", "env slots", "samples/s", "env share of wall time", "projected 2M samples (min)"]
    assert [r[0] for r in rows] == ["ppo", "shared_ppo"] and all(r[3].endswith("%") for r in rows)

    header, rows = _table(lines, "## Targets")
    assert header == ["target", "this run", "status"] and len(rows) == 8
    assert all(r[2] == "not judged (smoke sizes)" for r in rows)
    assert rows[0][1] == "reference not run"

    data = json.loads(out_json.read_text())
    assert set(data) >= {"meta", "implementations", "skipped", "summary", "raw", "profile", "ppo", "targets"}
    assert list(data["implementations"]) == ["ours", "before"] and data["meta"]["smoke"] is True
    assert len(data["summary"]["rows"]) == 12


def test_kernel_benchmark_compares_two_checkouts():
    """benchmarks/kernel.py times the compiled step of ours and of another checkout (here: this one
    again) and prints one row per case with the ratio."""
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "kernel.py"), "--rounds", "1", "--smoke",
                           "--compare-with", str(REPO), "--compare-label", "again"],
                          capture_output=True, text=True, timeout=300, check=True)
    lines = [line for line in proc.stdout.splitlines() if line.startswith("|") and not line.startswith("|---")]
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    assert header == ["case (n = 11)", "ours µs", "ours ns per simulation", "again µs", "again ns per simulation",
                      "again ÷ ours"]
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in lines[1:]]
    assert [r[0] for r in rows] == ["B=1 p=0.01", "B=1 p=0.5", "B=512 p=0.01", "B=4096 p=0.01", "B=4096 p=0.5"]
    for r in rows:
        bsz = int(r[0].split()[0][2:])
        assert _number(r[1]) > 0 and _number(r[3]) > 0 and r[5].endswith("×")
        assert abs(_number(r[2]) - 1000 * _number(r[1]) / bsz) <= 1000 * 0.05 / bsz + 1  # µs shown to 0.1


@pytest.mark.slow  # starts fresh processes, ~12 s
def test_startup_benchmark_shows_a_warm_process_compiling_nothing():
    """benchmarks/startup.py runs a cold and a warm process per rule on a private numba cache; the
    warm one loads the kernel (one hit, no miss) and writes no cache file."""
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "startup.py"), "--rules", "index"],
                          capture_output=True, text=True, timeout=300, check=True)
    lines = [line for line in proc.stdout.splitlines() if line.startswith("|") and not line.startswith("|---")]
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in lines[1:]]
    assert [r[:3] for r in rows] == [["ours", "index", "cold"], ["ours", "index", "warm"]]
    assert rows[0][7] == "0 / 1" and int(rows[0][8]) > 0
    assert rows[1][7] == "1 / 0" and rows[1][8] == "0"


@pytest.mark.slow  # times SB3 and the native trainer, ~30 s
def test_trainer_throughput_smoke_prints_both_ratios(tmp_path):
    """benchmarks/trainer_throughput.py end to end at one rollout a burst: the four algorithms and
    the two native/SB3 ratios, also as JSON (structure, not speed)."""
    out_json = tmp_path / "trainer.json"
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "trainer_throughput.py"), "--smoke",
                           "--rounds", "1", "--config", "n5_m2_dt120", "--json", str(out_json)],
                          capture_output=True, text=True, timeout=300, check=True, cwd=tmp_path)
    assert "| fast_shared_ppo / shared_ppo |" in proc.stdout and "| fast_ppo / ppo |" in proc.stdout
    summary = json.loads(out_json.read_text())
    assert set(summary["algorithms"]) == {"ppo", "fast_ppo", "shared_ppo", "fast_shared_ppo"}
    assert all(v["samples_per_cpu_s"] > 0 for v in summary["algorithms"].values())
    assert not any(tmp_path.glob("runs"))  # bursts train in a temporary folder


def test_trainer_profile_smoke_accounts_for_the_whole_run(tmp_path):
    """benchmarks/trainer_profile.py end to end at one rollout: every phase of the native trainer is
    timed at the shape the run trains with (its method's settings file), the whole run is that one
    rollout, and the phases and the rest add up to it (structure, not speed)."""
    from containergym_marl.config.hyperparams import method_settings

    out_json, out_md = tmp_path / "profile.json", tmp_path / "profile" / "table.md"
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "trainer_profile.py"), "--smoke",
                           "--json", str(out_json), "--md", str(out_md)], capture_output=True, text=True,
                          timeout=300, check=True, cwd=tmp_path)
    result = json.loads(out_json.read_text())
    settings = method_settings("fast_shared_ppo")
    n_steps = settings.get("n_steps", 64)
    sims = max(1, round(settings.get("rollout_samples", 4096) / (n_steps * 11)))  # 11 agents per simulation
    samples = sims * 11 * n_steps
    assert (result["simulations"], result["samples_per_update"]) == (sims, samples)
    assert result["minibatches"] == max(1, round(samples / settings.get("minibatch_size", 1024)))
    assert result["run_samples"] == samples  # the whole run: one rollout of the same shape
    phases = result["us_per_sample"]
    assert {"env step", "policy step (forward, sample, log-probability)", "GAE", "update (one compiled call)"} <= set(phases)
    assert sum(phases.values()) == pytest.approx(result["whole_us_per_sample"])
    assert "| **whole run** |" in proc.stdout
    assert out_md.read_text().strip() in proc.stdout and "load average before" in out_md.read_text()


@pytest.mark.slow  # ~25 s
def test_threads_smoke_times_both_layouts(tmp_path):
    """benchmarks/threads.py trains whole runs in both layouts and writes what it judged from."""
    out_json = tmp_path / "threads.json"
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "threads.py"), "--smoke", "--json", str(out_json)],
                          capture_output=True, text=True, timeout=600, cwd=REPO)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "| one thread per run | 2 |" in proc.stdout and "| two threads per run | 1 |" in proc.stdout
    data = json.loads(out_json.read_text())
    assert [m["runs"] for m in data["measured"]["one thread"]] == [2]
    assert [m["threads"] for m in data["measured"]["two threads"]] == [2]
    assert all(m["samples_per_wall_s"] > 0 and m["cpu_s"] > 0 for ms in data["measured"].values() for m in ms)
    assert len(data["ratios"]) == 1


@pytest.mark.slow  # ~15 s
def test_trainer_ab_compares_a_checkout_with_itself(tmp_path):
    """Two checkouts of the same code train the same model (the hash check can pass) and the table
    has both sides."""
    out = tmp_path / "ab.json"
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "trainer_ab.py"), "--other", str(REPO),
                           "--samples", "5000", "--rounds", "1", "--json", str(out)],
                          capture_output=True, text=True, timeout=600, check=True)
    report = json.loads(out.read_text())
    assert report["identical_models"] is True
    assert {r["samples"] for side in report["runs"].values() for r in side} == {report["runs"]["this"][0]["samples"]}
    assert "final models identical" in proc.stdout and "| this (" in proc.stdout and "| other (" in proc.stdout


@pytest.mark.slow  # ~15 s
def test_planner_ab_compares_a_checkout_with_itself(tmp_path):
    """Two checkouts of the same code decide the same episodes (the hash check can pass), with the
    same count of planned decisions, and the table has both sides."""
    out = tmp_path / "ab.json"
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "planner_ab.py"), "--other", str(REPO),
                           "--config", "n5_m2_dt120", "--episodes", "1", "--rounds", "1", "--json", str(out)],
                          capture_output=True, text=True, timeout=600, check=True)
    report = json.loads(out.read_text())
    assert report["identical_episodes"] is True
    this, other = report["runs"]["this"][0], report["runs"]["other"][0]
    assert this["planned"] == other["planned"] > 0 and this["decisions"] == other["decisions"] == 600
    assert "episodes (requests and rewards) identical" in proc.stdout and "| other (" in proc.stdout


@pytest.mark.parametrize("labels", ["planner", "response"])
def test_labelling_benchmark_labels_alike_on_both_sides(tmp_path, labels):
    """benchmarks/labelling.py end to end at 4 simulations and 3 steps: both sides plan the same
    decisions and give the same labels (the hash), and the table has a row per plant."""
    out = tmp_path / "labels.json"
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "labelling.py"), "--smoke", "--labels", labels,
                           "--json", str(out)], capture_output=True, text=True, timeout=300, check=True)
    report = json.loads(out.read_text())
    assert set(report["configs"]) == {"n11_m2_dt120", "n16_m2_dt120"}
    for row in report["configs"].values():
        one, batched = row["rounds"][0]
        assert row["identical_labels"] and one["labels_sha256"] == batched["labels_sha256"]
        assert one["planned"] == batched["planned"] == row["planned"] > 0
    assert proc.stdout.count("| identical |") == 2


def test_scaling_smoke_measures_every_path_of_each_plant(tmp_path):
    """benchmarks/scaling.py end to end on two plants (structure, not speed): each plant's row holds
    every rate, container decisions are n × plant steps, and the planner was timed."""
    out_json, out_md = tmp_path / "scaling.json", tmp_path / "scaling.md"
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "scaling.py"), "--smoke", "--json", str(out_json),
                           "--md", str(out_md)], capture_output=True, text=True, timeout=300, check=True, cwd=tmp_path)
    rows = json.loads(out_json.read_text())
    assert [(r["config"], r["n"], r["m"]) for r in rows] == [("n5_m2_dt120", 5, 2), ("n32_m4_dt120", 32, 4)]
    for r in rows:
        for path in ("central_b1", "central_b1024", "agents_local", "agents_portable"):
            assert r[f"{path}_steps"] > 0
            assert r[f"{path}_decisions"] == pytest.approx(r[f"{path}_steps"] * r["n"])
        assert r["agents_sims"] == 1024 // r["n"]
        assert 0 < r["planner"]["median_ms"] <= r["planner"]["p95_ms"]
    assert out_md.read_text().strip() in proc.stdout and "| `n32_m4_dt120` | 32 | 4 |" in proc.stdout
    # the figure, drawn again from the saved measurements alone
    figure = tmp_path / "scaling.png"
    subprocess.run([sys.executable, str(REPO / "benchmarks" / "scaling.py"), "--from-json", str(out_json),
                    "--figure", str(figure)], capture_output=True, text=True, timeout=120, check=True, cwd=tmp_path)
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_decision_time_smoke_compares_the_two_forwards_on_the_same_decisions(tmp_path):
    """benchmarks/decision_time.py at a few steps, with a model that carries the agents' own check:
    both forwards decide the same (the script stops otherwise), and it reports both and the ratios."""
    import torch

    from containergym_marl.policies.actor_critic import ActorCritic

    model = ActorCritic("decentralised", 25, 2, generator=torch.Generator().manual_seed(1),
                        own_check={"risk": 1e-4, "lead_steps": 1})
    model.save(tmp_path / "model.pt")
    out_json = tmp_path / "decision.json"
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "decision_time.py"), "--model",
                           str(tmp_path / "model.pt"), "--steps", "40", "--rounds", "2", "--json", str(out_json)],
                          capture_output=True, text=True, timeout=300, check=True, cwd=tmp_path)
    assert "the same decisions" in proc.stdout
    result = json.loads(out_json.read_text())
    assert len(result["rounds"]) == 2 and result["ratio_wall"] > 0 and result["ratio_cpu"] > 0
    assert all(r[side]["ms_median"] > 0 for r in result["rounds"] for side in ("direct", "modules"))


def test_shared_check_time_smoke_times_the_published_model_with_and_without_the_rule(tmp_path):
    """benchmarks/shared_check_time.py at a few steps: the published best dagger_checked_agents model of
    n11_m2_dt120 (read from the table), both sides timed in every round, the rule the chosen setting."""
    from containergym_marl.policies.shared_check import SHARED_CHECK

    out_json = tmp_path / "shared.json"
    subprocess.run([sys.executable, str(REPO / "benchmarks" / "shared_check_time.py"), "--steps", "40", "--rounds",
                    "2", "--json", str(out_json)], capture_output=True, text=True, timeout=300, check=True, cwd=tmp_path)
    result = json.loads(out_json.read_text())
    assert result["shared_check"] == SHARED_CHECK and "dagger_checked_agents_n11_m2_dt120_s" in result["model"]
    assert len(result["rounds"]) == 2 and result["ratio_wall_median"] > 0 and result["ratio_cpu"] > 0
    assert all(r[side]["ms_median"] > 0 for r in result["rounds"] for side in ("network", "shared_check"))


def test_shared_check_time_times_another_published_method_and_names_one_that_is_not(tmp_path):
    """--method picks that method's published best model (here dagger_messaging_agents, trained with the rule);
    a method with no published row is refused by name before anything is timed."""
    script = str(REPO / "benchmarks" / "shared_check_time.py")
    out_json = tmp_path / "messaging.json"
    subprocess.run([sys.executable, script, "--method", "dagger_messaging_agents", "--steps", "20", "--rounds", "1",
                    "--json", str(out_json)], capture_output=True, text=True, timeout=300, check=True, cwd=tmp_path)
    assert "dagger_messaging_agents_n11_m2_dt120_s" in json.loads(out_json.read_text())["model"]
    proc = subprocess.run([sys.executable, script, "--method", "no_such_method", "--json", str(tmp_path / "x.json")],
                          capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode != 0 and "no_such_method" in proc.stderr and not (tmp_path / "x.json").exists()
