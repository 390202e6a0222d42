"""benchmarks/clients_throughput.py runs at tiny sizes and prints its table (structure, not speed).

Needs torchrl (skipped without it; the ``clients`` extra installs it).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("torchrl")

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "clients_throughput.py"


def test_smoke_run_prints_the_table(tmp_path):
    out_json = tmp_path / "clients.json"
    proc = subprocess.run([sys.executable, str(SCRIPT), "--smoke", "--quiet", "--json", str(out_json)],
                          capture_output=True, text=True, timeout=300, check=True)
    lines = proc.stdout.splitlines()
    assert lines[0] == "# Agent steps per second through the MARL libraries' APIs (smoke run)"
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in lines
            if line.startswith("|") and not line.startswith("|---")]
    assert rows[0] == ["path", "B", "n=5 agent steps/s", "n=5 × wrapper", "n=11 agent steps/s", "n=11 × wrapper"]
    assert [(r[0], r[1]) for r in rows[1:]] == [
        ("TorchRL PettingZooWrapper(parallel_env)", "1"),
        ("PettingZoo parallel_env, no TorchRL (for scale)", "1"),
        ("ContainerAgentsTorchRLEnv (batched)", "1"),
        ("ContainerAgentsTorchRLEnv (batched)", "4"),
    ]
    assert rows[1][3] == rows[1][5] == "1.0"  # the wrapper is the reference
    data = json.loads(out_json.read_text())
    assert data["smoke"] and len(data["rows"]) == 4
    assert all(r["n5"] > 0 and r["n11"] > 0 for r in data["rows"])
