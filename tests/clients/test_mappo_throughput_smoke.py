"""benchmarks/mappo_throughput.py runs at tiny sizes and prints its table (structure, not speed).

Needs benchmarl (the ``clients`` extra).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("benchmarl")

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "mappo_throughput.py"


def test_smoke_run_prints_the_table(tmp_path):
    out_json = tmp_path / "mappo.json"
    proc = subprocess.run([sys.executable, str(SCRIPT), "--smoke", "--iterations", "2", "--json", str(out_json)],
                          capture_output=True, text=True, timeout=300, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in proc.stdout.splitlines()
            if line.startswith("|") and not line.startswith("|---")]
    assert rows[0][:4] == ["config", "iterations timed", "plant steps/s", "agent steps/s"]
    assert [r[0] for r in rows[1:]] == ["n5_m2_dt120", "n11_m2_dt120"]
    assert [r[7] for r in rows[1:]] == ["2M / 10M", "5M / 55M"]  # the paper's budgets, plant / agent steps
    data = json.loads(out_json.read_text())
    assert data["smoke"] and [r["iterations_timed"] for r in data["results"]] == [1, 1]
    for r in data["results"]:
        assert r["agent_steps_per_s"] == pytest.approx(r["plant_steps_per_s"] * r["n"])
        assert r["projected_hours_per_seed"] > 0
