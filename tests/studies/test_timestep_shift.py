"""studies/timestep_shift.py: the δ = 60 s rows' published models at the test protocol's δ = 120 s and at
their own δ = 60 s, on the same validation episodes, against the rule-based agents."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers import load_script

REPO = Path(__file__).resolve().parents[2]
SCRIPT = str(REPO / "studies" / "timestep_shift.py")


def _entry(method, seed, ret120, over120, ret60, over60, episodes=100):
    return {"row": "n5_m2_dt60", "method": method, "seed": seed, "episodes": episodes, "first_seed": 20_000,
            "test_dt120": {"return_mean": ret120, "overflowing_episodes": over120},
            "own_dt60": {"return_mean": ret60, "overflowing_episodes": over60}}


def test_report_by_hand():
    study = load_script("studies/timestep_shift.py")
    entries = [_entry("rule_based_agents", 0, 59.0, 1, 60.0, 0),
               _entry("learner", 1, 50.0, 2, 56.0, 0),   # above the rule's 1 % at 120 s only
               _entry("learner", 2, 54.0, 0, 58.0, 1),   # above the rule's 0 % at 60 s only
               _entry("learner", 3, 52.0, 1, 57.0, 0)]   # equal to the rule at 120 s: not above
    (cell,) = study.report(entries)["cells"]
    assert (cell["row"], cell["method"], cell["seeds"]) == ("n5_m2_dt60", "learner", 3)
    assert cell["test_dt120"]["return_mean"] == pytest.approx(52.0)
    assert cell["own_dt60"]["return_mean"] == pytest.approx(57.0)
    assert cell["test_dt120"]["overflowing_per_100"] == pytest.approx(1.0)       # 3 of 300
    assert cell["own_dt60"]["overflowing_per_100"] == pytest.approx(100 / 300)   # 1 of 300
    assert (cell["test_dt120"]["seeds_above_rule"], cell["own_dt60"]["seeds_above_rule"]) == (1, 1)
    assert (cell["test_dt120"]["rule_overflowing_per_100"], cell["own_dt60"]["rule_overflowing_per_100"]) == (1.0, 0.0)
    table = study.markdown(study.report(entries), 100)
    assert "| n5_m2_dt60 | `learner` | 3 | 52.00 | 57.00 | 1.0 | 0.3 | 1 of 3 | 1 of 3 |" in table


def test_smoke_run_evaluates_the_published_models_at_both_timesteps(tmp_path):
    from containergym_marl.evaluation.batched import evaluate_batched
    from containergym_marl.evaluation.protocol import EvalProtocol
    from containergym_marl.evaluation.run_policies import evaluated_which, policy_from_run

    subprocess.run([sys.executable, SCRIPT, "--smoke", "--workers", "1", "--out", str(tmp_path)],
                   capture_output=True, text=True, timeout=300, check=True)
    entries = json.loads((tmp_path / "shift.json").read_text())["entries"]
    assert [(e["method"], e["seed"]) for e in entries] == [("rule_based_agents", 0), ("fast_shared_ppo", 1),
                                                           ("fast_shared_ppo", 2)]
    assert all(e["episodes"] == 4 and e["first_seed"] == 20_000 for e in entries)
    # at 120 s the entry is the paper's plant on the validation seeds, as any evaluation of the model gives it
    run = REPO / "results" / "paper_rows" / "runs" / "fast_shared_ppo_n5_m2_dt60_s1"
    at120 = evaluate_batched(policy_from_run(run, evaluated_which(run)), "n5_m2_dt60",
                             EvalProtocol(episodes=4, first_seed=20_000))
    assert entries[1]["test_dt120"]["return_mean"] == pytest.approx(float(at120.returns.mean()))
    assert entries[1]["model"] == evaluated_which(run)
    # at the row's own 60 s over the same plant time, another plant: other returns
    assert entries[1]["own_dt60"]["return_mean"] != pytest.approx(entries[1]["test_dt120"]["return_mean"])
    assert "| n5_m2_dt60 | `fast_shared_ppo` | 2 |" in (tmp_path / "shift.md").read_text()


@pytest.mark.parametrize("argv,named", [(["--rows", "n5_m2_dt120"], "n5_m2_dt120"),
                                         (["--seeds", "99", "--rows", "n5_m2_dt60"], "fast_ppo_n5_m2_dt60_s99")])
def test_bad_rows_and_missing_runs_are_refused_before_anything_is_written(tmp_path, argv, named):
    proc = subprocess.run([sys.executable, SCRIPT, *argv, "--out", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0 and named in proc.stderr
    assert not (tmp_path / "out").exists()


def test_the_committed_table_is_what_its_entries_give():
    study = load_script("studies/timestep_shift.py")
    saved = json.loads((REPO / "results" / "timestep_shift" / "shift.json").read_text())["entries"]
    episodes = {e["episodes"] for e in saved}
    assert len(episodes) == 1
    assert study.markdown(study.report(saved), episodes.pop()) == \
        (REPO / "results" / "timestep_shift" / "shift.md").read_text()
