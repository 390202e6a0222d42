"""benchmarks/throughput.py runs at tiny sizes and prints the documented tables (structure, not speed)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from containergym_marl.core import compiled

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "throughput.py"


def _table(lines: list[str], heading: str) -> tuple[list[str], list[list[str]]]:
    start = lines.index(heading)
    rows = []
    for line in lines[start + 1:]:
        if line.startswith("## "):
            break
        if line.startswith("|") and not line.startswith("|---"):
            rows.append([c.strip() for c in line.strip("|").split("|")])
    return rows[0], rows[1:]


def test_smoke_run_prints_every_table(tmp_path):
    out_json = tmp_path / "throughput.json"
    proc = subprocess.run([sys.executable, str(SCRIPT), "--smoke", "--quiet", "--json", str(out_json)],
                          capture_output=True, text=True, timeout=300, check=True)
    lines = proc.stdout.splitlines()
    assert lines[0] == "# Throughput (smoke run)"

    header, rows = _table(lines, "## Environment steps per second")
    assert header == ["path", "backend", "B", "n=5 env steps/s", "n=5 agent steps/s", "n=5 × ref (global)",
                      "n=5 × ref (Generator)", "n=11 env steps/s", "n=11 agent steps/s",
                      "n=11 × ref (global)", "n=11 × ref (Generator)"]
    backends = ["numpy", "numba"] if compiled.numba_available() else ["numpy"]
    paths = {(r[0], r[1], r[2]) for r in rows}
    for ref in ("earlier implementation, cost model (global np.random)",
                "earlier implementation, cost model (np.random.Generator)"):
        assert (ref, "–", "1") in paths
    for backend in backends:  # every package path is measured with every available backend
        for single in ("centralised Gymnasium env (ContainerGymEnv)",
                       "PettingZoo parallel env (container_agents_v0)"):
            assert (single, backend, "1") in paths
        assert any(p.startswith("SuperSuit stack") and be == backend for p, be, _ in paths)
        for native in ("native SB3 ContainerGymVecEnv", "native Gymnasium ContainerGymVectorEnv",
                       "native SB3 ContainerAgentsVecEnv (B·n agent slots)"):
            assert {(native, backend, b) for b in ("1", "4")} <= paths  # the smoke batch sizes
    for r in rows:
        assert len(r) == len(header)
        assert float(r[3].replace(",", "")) > 0 and float(r[7].replace(",", "")) > 0
        assert r[5].endswith("×") and r[10].endswith("×")
    ref = next(r for r in rows if r[0].endswith("(global np.random)"))
    assert ref[5] == "1.00×" and ref[9] == "1.00×"

    header, rows = _table(lines, "## Where the time goes")
    assert header[0] == "configuration" and len(rows) == 3 * len(backends)
    assert all(len(r) == len(header) and r[2].endswith("%") for r in rows)
    assert {r[0].rsplit("[", 1)[1].rstrip("]") for r in rows} == set(backends)

    header, rows = _table(lines, "## SB3 PPO training throughput (n5_m2_dt120, MlpPolicy, torch threads = 1)")
    assert header == ["training", "env slots", "samples/s", "env share of wall time", "projected 2M-step run (min)"]
    assert [r[0].split(",")[0] for r in rows] == ["shared PPO", "shared PPO", "centralised PPO", "centralised PPO"]
    assert "default Adam" in rows[3][0]
    assert "SuperSuit" in rows[0][0] and "native" in rows[1][0]
    assert all(r[3].endswith("%") for r in rows)

    data = json.loads(out_json.read_text())
    assert set(data) >= {"meta", "env", "profile", "ppo", "reference_sampling_share"}
    assert data["meta"]["smoke"] is True and len(data["env"]) == len(paths)
