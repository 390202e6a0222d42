"""The main job (README's first command) runs end to end and its statistics are consistent."""

from __future__ import annotations

import subprocess
import sys

from containergym_marl.rollout import run_centralised, run_decentralised


def test_rollout_statistics_match_an_episode():
    cen = run_centralised("n5_m2_dt120", seed=1000)
    dec = run_decentralised("n5_m2_dt120", seed=1000)
    for s in (cen, dec):
        assert 1 <= s.steps <= 600  # the paper's test protocol
        assert s.end in ("overflow", "time limit")
        assert (s.end == "time limit") == (s.steps == 600)
        # each emptying earns at most 1, each denied request r_pen = -0.1, an overflow r_min = -1
        assert s.cumulative_reward <= s.emptyings * 1.0 + 1e-9
    # the rule keeps this plant alive: dozens of emptyings, nearly all with positive reward
    assert cen.emptyings > 20 and cen.positive_emptying_share > 0.9


def test_main_job_command_prints_per_episode_table():
    out = subprocess.run([sys.executable, "-m", "containergym_marl.rollout", "--episodes", "2"],
                         capture_output=True, text=True, check=True).stdout
    rows = [line for line in out.splitlines() if line.startswith(("centralised ", "decentralised "))]
    assert len(rows) == 4
    assert "cumulative reward" in out
