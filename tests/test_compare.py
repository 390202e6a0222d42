"""`containergym-marl compare` end to end on a tiny budget; reruns reuse finished runs."""

from __future__ import annotations

import csv
import json
import xml.etree.ElementTree as ET

import pytest

from containergym_marl.compare import CompareArgs, compare

TINY = dict(configs=["n5_m2_dt120"], methods=["rule_based", "rule_based_agents", "ppo", "shared_ppo"],
            seeds=[1, 2], timesteps=256, episodes=2, n_envs=1, bootstrap_reps=100,
            hyperparams={"n_steps": 128, "batch_size": 64})


def test_compare_end_to_end_then_reuse(tmp_path, capsys):
    out = tmp_path / "cmp"
    report = compare(CompareArgs(out=str(out), **TINY))
    methods = [r["method"] for r in report["rows"]]
    assert methods == TINY["methods"]
    for row in report["rows"]:
        assert row["best_mean"] >= row["median_mean"]
        assert row["iqm_low"] <= row["iqm_high"]
        assert row["seeds"] == (2 if row["method"] in ("ppo", "shared_ppo") else 0)
    pairs = {(i["decentralised"], i["centralised"]) for i in report["improvements"]}
    assert pairs == {("shared_ppo", "ppo"), ("rule_based_agents", "rule_based")}
    assert all(0.0 <= i["low"] <= i["high"] <= 1.0 for i in report["improvements"])

    table = (out / "table.md").read_text()
    for m in TINY["methods"]:
        assert f"| n5_m2_dt120 | {m} |" in table
    assert "paper PPO" in table and "P(shared_ppo > ppo)" in table
    with (out / "table.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [r["method"] for r in rows] == TINY["methods"]
    evaluations = sorted(p.name for p in (out / "evaluations" / "n5_m2_dt120").iterdir())
    assert evaluations == ["ppo_s1.json", "ppo_s2.json", "rule_based.json", "rule_based_agents.json",
                           "shared_ppo_s1.json", "shared_ppo_s2.json"]
    saved = json.loads((out / "table.json").read_text())
    assert len(saved["seed_means"]["n5_m2_dt120/ppo"]) == 2
    figures = sorted(p.name for p in (out / "figures").iterdir())
    assert "n5_m2_dt120_emptying_volume_ecdfs.png" in figures and "n5_m2_dt120_reward_ecdf.svg" in figures
    assert sum(name.startswith("n5_m2_dt120_episode_") for name in figures) == 2 * len(TINY["methods"])
    ET.parse(out / "figures" / "n5_m2_dt120_reward_ecdf.svg")

    # A rerun reuses the finished runs: no training, same numbers.
    stamps = {p: p.stat().st_mtime_ns for p in (out / "runs").glob("*/final_model.zip")}
    assert len(stamps) == 4
    capsys.readouterr()
    again = compare(CompareArgs(out=str(out), **{**TINY, "methods": ["ppo", "shared_ppo"]}))
    assert "train " not in capsys.readouterr().out
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps
    assert again["rows"][0]["best_mean"] == report["rows"][2]["best_mean"]


def test_compare_refuses_a_finished_run_with_another_budget(tmp_path):
    args = dict(TINY, methods=["ppo"], seeds=[1], figures=False)
    compare(CompareArgs(out=str(tmp_path), **args))
    with pytest.raises(ValueError, match="budget of 256 samples, not 512"):
        compare(CompareArgs(out=str(tmp_path), **{**args, "timesteps": 512}))


def test_compare_rejects_unknown_methods_and_configs(tmp_path):
    from containergym_marl import ConfigError

    with pytest.raises(ValueError, match="unknown method"):
        compare(CompareArgs(out=str(tmp_path), methods=["a2c"]))
    with pytest.raises(ConfigError):
        compare(CompareArgs(out=str(tmp_path), configs=["n9"]))
