"""studies/dagger_rows.py at its smoke size: trains both imitations through compare (Ray, one CPU),
evaluates them beside planner_agents and reports each one's share, training cost and the decision time."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow  # a study's end-to-end smoke run, ~1 min
def test_smoke_run_reports_share_cost_and_decision_time(tmp_path):
    subprocess.run([sys.executable, str(REPO / "studies" / "dagger_rows.py"), "--smoke", "--num-cpus", "1",
                    "--out", str(tmp_path / "out"), "--runs", str(tmp_path / "runs")],
                   # a guard against a hang, not a speed check: Ray's workers run at nice 15 and take
                   # several times their idle time beside other jobs on a 2-core machine
                   capture_output=True, text=True, timeout=1800, check=True)
    report = json.loads((tmp_path / "out" / "rows.json").read_text())
    assert [(e["row"], e["method"]) for e in report["entries"]] == [
        ("n5_m2_dt120", "dagger_agents"), ("n5_m2_dt120", "dagger_ppo_agents")]
    for e in report["entries"]:
        cost = e["training_cost_per_seed"]
        assert e["seeds"] == 1 and e["samples"] == 20_000 and e["reference_return"] > 50
        assert e["share_of_reference"] == e["iqm"] / e["reference_return"]
        assert cost["seeds"] == 1 and 0 < cost["label_cpu_s"] < cost["wall_s"] and cost["samples"] >= 20_000
    timing = report["decision_time"]
    assert timing["steps"] == 600 and 0 < timing["ms_per_step_median"] <= timing["ms_per_step_p99"]
    assert "| n5_m2_dt120 | dagger_ppo_agents | 1 |" in (tmp_path / "out" / "rows.md").read_text()
