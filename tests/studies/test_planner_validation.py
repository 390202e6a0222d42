"""studies/planner_validation.py at its smoke size: every part runs, blocks of episodes add up to
what one evaluation of the same episodes gives, and a rerun reuses what is there."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from containergym_marl.evaluation import EvalProtocol, evaluate
from containergym_marl.evaluation.protocol import FRESH
from containergym_marl.policies import PlannerAgents
from tests.helpers import load_script

REPO = Path(__file__).resolve().parents[2]
SCRIPT = str(REPO / "studies" / "planner_validation.py")


@pytest.mark.slow  # a study's end-to-end smoke run, ~20 s
def test_smoke_run_covers_every_part_and_matches_a_plain_evaluation(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    # a block of fresh episodes from another seed range (an earlier version's) is dropped, not mixed in
    stale = {"key": "stale", "part": "fresh", "plant": "n5_m2_dt120", "view": "planner_agents", "settings": {},
             "first_seed": 50_000, "episodes": 2, "returns": [0.0, 0.0], "overflows": [1, 1], "cpu_s": 0.0, "steps": 2}
    (out / "validation.json").write_text(json.dumps({"blocks": [stale]}))
    first = subprocess.run([sys.executable, SCRIPT, "--smoke", "--workers", "2", "--out", str(out)],
                           capture_output=True, text=True, timeout=300, check=True)
    assert "1 fresh block(s) outside seeds 30000+ dropped" in first.stdout
    assert "18 block(s) to run, 0 reused" in first.stdout
    blocks = json.loads((out / "validation.json").read_text())["blocks"]
    assert {b["part"] for b in blocks} == {"settings", "horizons", "wide", "fresh", "safety", "risk"}
    fresh = [b for b in blocks if b["part"] == "fresh" and b["view"] == "planner_agents"]
    assert [b["first_seed"] for b in fresh] == [FRESH.first_seed]  # the one fresh range, 30000+
    plain = evaluate(PlannerAgents(), "n5_m2_dt120", EvalProtocol(episodes=2, first_seed=FRESH.first_seed),
                     keep_records=False)
    np.testing.assert_allclose(fresh[0]["returns"], plain.returns)
    np.testing.assert_allclose(fresh[0]["risks"], [e.overflow_risk for e in plain.episodes])
    text = (out / "validation.md").read_text()
    assert "| n5_m2 | max_futures = 32 | 2 |" in text  # the widened look-ahead's part
    assert "| n5_m2 | margin = 2 | 2 |" in text and "## The defaults on fresh episodes (seeds 30000+)" in text
    # the deadline check's part: its setting next to the defaults, on the fresh seeds by default
    assert "| n5_m2 | 30000+ (fresh) | planner_agents | safety_risk = 1e-06, safety_horizon_steps = 24 | 2 |" in text
    assert "| n5_m2 | 30000+ (fresh) | planner_agents | defaults | 2 |" in text
    # the risk part: the check at another ε on validation episodes
    assert "| n5_m2 | 20000+ (validation) | planner | safety_risk = 1e-05, safety_horizon_steps = 24 | 2 |" in text
    again = subprocess.run([sys.executable, SCRIPT, "--smoke", "--workers", "1", "--out", str(out)],
                           capture_output=True, text=True, timeout=300, check=True)
    assert "0 block(s) to run, 18 reused" in again.stdout


def test_each_overflowing_fresh_episode_is_replayed_with_another_seed_and_more_futures():
    script = load_script("studies/planner_validation.py")
    rows = [{"part": "fresh", "plant": "n16_m2_dt120", "view": "planner_agents", "overflowing_seeds": [30_007, 30_042]},
            {"part": "fresh", "plant": "n5_m2_dt120", "view": "planner", "overflowing_seeds": []},
            {"part": "settings", "plant": "n16_m2_dt120", "view": "planner", "overflowing_seeds": [20_003]}]
    jobs = script.replay_jobs(rows)
    assert [(j[1], j[2], j[4], j[5]) for j in jobs] == [("n16_m2_dt120", "planner_agents", s, 1)
                                                      for s in (30_007, 30_042) for _ in range(3)]
    assert [{k: v for k, v in j[3].items() if script.DEFAULTS.get(k) != v} for j in jobs[:3]] == [
        {"seed": 1}, {"seed": 2}, {"futures": 64}]


def test_a_setting_with_one_view_so_far_keeps_its_whole_row():
    """A setting whose container-agent blocks have not run yet: its row shows the planner and dashes
    (the line used to be replaced by its last cell alone)."""
    script = load_script("studies/planner_validation.py")
    row = {"part": "wide", "plant": "n16_m2_dt120", "view": "planner", "settings": dict(script.DEFAULTS),
           "episodes": 10, "return_mean": 111.25, "return_sem": 0.5, "overflowing_episodes": 0,
           "ms_cpu_per_step": 2.0}
    lines = script.report([row]).splitlines()
    assert "| n16_m2 | defaults | 10 | 111.25 ± 0.50 | 0 | – | – | – |" in lines
    assert " | – |" not in lines


def test_the_safety_part_runs_its_setting_next_to_the_defaults_from_the_seed_asked():
    script = load_script("studies/planner_validation.py")
    jobs = script.jobs_for(["safety"], {"safety": 25}, 20_000)
    assert {(j[1], j[2]) for j in jobs} == {(p, v) for p in script.CONTENDED for v in script.VIEWS}
    assert sorted({json.dumps(j[3], sort_keys=True) for j in jobs}) == sorted(
        json.dumps(s, sort_keys=True) for s in (script.DEFAULTS, {**script.DEFAULTS, **script.SAFETY}))
    assert sorted({(j[4], j[5]) for j in jobs}) == [(20_000, 10), (20_010, 10), (20_020, 5)]
    assert {j[4] for j in script.jobs_for(["safety"], {"safety": 10})} == {FRESH.first_seed}  # fresh by default
    # validation and fresh blocks of one setting are rows apart, each with its seed range
    block = {"part": "safety", "plant": "n16_m2_dt120", "view": "planner", "settings": {**script.DEFAULTS,
             **script.SAFETY}, "episodes": 2, "returns": [110.0, 112.0], "overflows": [0, 1], "cpu_s": 2.0,
             "steps": 1000}
    rows = script.summarise([dict(block, first_seed=20_000), dict(block, first_seed=30_000, overflows=[0, 0])])
    assert sorted((r["first_seed"], r["overflowing_episodes"]) for r in rows) == [(20_000, 1), (30_000, 0)]
    text = script.report(rows)
    assert "| n16_m2 | 20000+ (validation) | planner | safety_risk = 1e-06, safety_horizon_steps = 24 | 2 | " \
           "111.00 ± 1.00 | 1 | – | 2.00 |" in text  # blocks without risks: unknown, not 0
    assert "| n16_m2 | 30000+ (fresh) | planner |" in text


def test_the_risk_part_compares_each_epsilon_and_the_defaults_by_their_overflow_risk():
    script = load_script("studies/planner_validation.py")
    jobs = script.jobs_for(["risk"], {"risk": 20})
    assert {j[4] for j in jobs} == {20_000, 20_010}  # validation episodes: where ε is chosen
    assert sorted({j[3].get("safety_risk", 0.0) for j in jobs}) == [0.0, *sorted(script.RISKS)]
    assert {j[3].get("safety_horizon_steps") for j in jobs if "safety_risk" in j[3]} == {
        script.SAFETY["safety_horizon_steps"]}
    block = {"part": "risk", "plant": "n11_m2_dt120", "view": "planner_agents", "settings": {**script.DEFAULTS,
             **script.SAFETY, "safety_risk": 1e-5}, "episodes": 2, "returns": [95.0, 96.0], "overflows": [0, 0],
             "cpu_s": 2.0, "steps": 1000}
    rows = script.summarise([dict(block, first_seed=20_000, risks=[1e-5, 3e-5]),
                             dict(block, first_seed=20_002, risks=[2e-5, 2e-5])])
    assert len(rows) == 1 and rows[0]["risk_mean"] == pytest.approx(2e-5)
    assert rows[0]["risk_sem"] == pytest.approx(np.std([1e-5, 3e-5, 2e-5, 2e-5], ddof=1) / 2)
    text = script.report(rows)
    assert "| n11_m2 | 20000+ (validation) | planner_agents | safety_risk = 1e-05, safety_horizon_steps = 24 | 4 | " \
           "95.50 ± 0.29 | 0 | 0.02 ± 0.0041 | 2.00 |" in text


def test_shielded_blocks_from_before_their_view_s_decisions_changed_are_run_again():
    script = load_script("studies/planner_validation.py")
    shielded = {**script.DEFAULTS, **script.SAFETY}
    blocks = [{"view": "planner", "settings": shielded, "check": 2},  # the centralised shield's decisions stand
              {"view": "planner", "settings": shielded, "check": 1},
              {"view": "planner_agents", "settings": shielded, "check": 2},  # the agents' changed at 3
              {"view": "planner_agents", "settings": shielded, "check": 3},
              {"view": "planner_agents", "settings": dict(script.DEFAULTS)}]  # no shield: any version
    assert script.current_blocks(blocks) == [blocks[0], blocks[3], blocks[4]]


def test_the_safety_part_refuses_a_bad_episode_count(capsys):
    script = load_script("studies/planner_validation.py")
    with pytest.raises(SystemExit):
        script.main(["--parts", "safety", "--safety-episodes", "0", "--out", "/nonexistent/never"])
    assert "--safety-episodes: expected an integer >= 1, got 0" in capsys.readouterr().err
