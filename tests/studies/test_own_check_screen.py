"""studies/own_check_screen.py: the published policies with and without the agents' own check on validation
episodes, each number what the package's single-environment evaluation gives for that policy; bad checks
refused before anything is written."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")

from containergym_marl.evaluation import EvalProtocol, evaluate  # noqa: E402
from containergym_marl.evaluation.run_policies import evaluated_which, policy_from_run  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
SCRIPT = str(REPO / "studies" / "own_check_screen.py")
RUN = REPO / "results" / "paper_rows" / "runs" / "dagger_agents_n11_m2_dt120_s1"


def test_the_smoke_screen_is_the_single_environment_evaluation_with_and_without_the_check(tmp_path):
    subprocess.run([sys.executable, SCRIPT, "--smoke", "--out", str(tmp_path / "out")], check=True,
                   capture_output=True, text=True, timeout=600)
    data = json.loads((tmp_path / "out" / "screen.json").read_text())
    got = data["results"]["dagger_agents"]["n11_m2_dt120"]["s1"]
    protocol = EvalProtocol(episodes=2, first_seed=20_000)
    for label, check in (("none", None), ("1e-4:1", {"risk": 1e-4, "lead_steps": 1})):
        policy = policy_from_run(RUN, evaluated_which(RUN))
        policy.model.own_check = check
        result = evaluate(policy, "n11_m2_dt120", protocol)  # one environment, episode by episode
        assert got[label]["return_mean"] == pytest.approx(float(np.mean(result.returns)), abs=1e-9)
        assert got[label]["overflowing_episodes"] == int(sum(bool(m.values["overflow"]) for m in result.episodes))
    assert "| `dagger_agents` | n11_m2_dt120 | 1e-4:1 | 1 |" in (tmp_path / "out" / "screen.md").read_text()


@pytest.mark.parametrize("checks, match", [(["1e-4"], "ε:L"), (["2:1"], "risk"), (["1e-4:-1"], "lead_steps")])
def test_a_bad_check_is_refused_before_anything_is_written(tmp_path, checks, match):
    done = subprocess.run([sys.executable, SCRIPT, "--checks", *checks, "--out", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 2 and match in done.stderr and not (tmp_path / "out").exists()


def test_the_committed_table_is_what_the_script_writes_from_its_json():
    sys.path.insert(0, str(REPO / "studies"))
    try:
        from own_check_screen import table
    finally:
        sys.path.remove(str(REPO / "studies"))
    out = REPO / "results" / "own_check"
    assert (out / "screen.md").read_text() == table(json.loads((out / "screen.json").read_text()))
