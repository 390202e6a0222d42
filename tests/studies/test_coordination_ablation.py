"""studies/coordination_ablation.py: its settings are refused before anything runs when they are bad,
and its smoke run trains a student of every observation, evaluates each beside planner_agents on the
same validation episodes and writes the table."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tests.helpers import ROOT, load_script

SCRIPT = str(ROOT / "studies" / "coordination_ablation.py")
STUDENTS = ["local", "global", "history4", "broadcast"]


@pytest.mark.parametrize("change, match", [
    ({"observations": ["oracle"]}, "observations: unknown"),
    ({"hyperparams": {"observation": "global"}}, "hyperparams: observation is what the study varies"),
    ({"seeds": [101, 101]}, "seeds: an entry is given more than once"),
    ({"rows": ["n99_m1_dt120"]}, "n99_m1_dt120"),
    ({"hyperparams": {"n_steps": 0}}, "hp: n_steps"),
    ({"episodes": 0}, "episodes"),
])
def test_bad_settings_are_refused_before_anything_is_written(tmp_path, change, match):
    study = load_script("studies/coordination_ablation.py")
    args = study.Args(out=str(tmp_path / "out"), runs=str(tmp_path / "runs"), **change)
    with pytest.raises(ValueError, match=match):  # a ConfigError for the unknown row
        study.main(args)
    assert not (tmp_path / "out").exists() and not (tmp_path / "runs").exists()


def test_the_study_states_its_rows_seeds_and_observations():
    """The contended rows of the issue, seeds no published run uses, the four students' observations."""
    study = load_script("studies/coordination_ablation.py")
    args = study.Args()
    assert args.rows == ["n11_m2_dt60", "n11_m2_dt120", "n16_m2_dt120"] and args.seeds == [101, 102, 103, 104, 105]
    assert args.observations == STUDENTS  # what each sees besides the default; not portable (less, for transfer)
    plans = args.plans()
    assert {c.protocol for c in plans.values()} == {"validation"} and plans["reference"].methods == ["planner_agents"]
    assert [plans[o].hyperparams for o in args.observations] == [{"observation": o} for o in args.observations]
    assert all(c.out.startswith("results/coordination_ablation/") for c in plans.values())


@pytest.mark.slow  # about 1-2 minutes: 4 tiny DAgger runs, 5 evaluations and the decision timings, in processes
def test_smoke_run_writes_the_table(tmp_path):
    out, runs = tmp_path / "out", tmp_path / "runs"
    subprocess.run([sys.executable, SCRIPT, "--smoke", "--out", str(out), "--runs", str(runs)],
                   capture_output=True, text=True, timeout=900, check=True)
    report = json.loads((out / "table.json").read_text())
    assert [(e["observation"], e["row"], e["seeds"]) for e in report["entries"]] == [
        (o, "n5_m2_dt120", 1) for o in STUDENTS]
    (reference,) = report["references"]
    assert reference["episodes"] == 2 and reference["return"] > 50 and reference["decision_time"]["steps"] == 600
    for e in report["entries"]:
        (run,) = e["runs"]
        assert run["share"] == pytest.approx(run["return"] / reference["return"]) and run["episodes"] == 2
        assert run["samples"] >= 2000 and e["decision_time"]["ms_median"] > 0
        saved = json.loads((runs / e["observation"] / "dagger_agents_n5_m2_dt120_s101" / "args.json").read_text())
        assert saved["hyperparams"]["observation"] == e["observation"]
        evaluation = json.loads((out / e["observation"] / "evaluations" / "n5_m2_dt120" /
                                 "dagger_agents_s101.json").read_text())
        assert evaluation["protocol"]["first_seed"] == 20_000 and evaluation["protocol"]["episodes"] == 2
    table = (out / "table.md").read_text()
    assert all(f"| {o} | n5_m2_dt120 | 1 |" in table for o in STUDENTS)
    again = subprocess.run([sys.executable, SCRIPT, "--smoke", "--out", str(out), "--runs", str(runs)],
                           capture_output=True, text=True, timeout=900, check=True)
    assert "4 run(s), 0 to train; 0 evaluation(s) to run" in again.stdout  # everything reused
