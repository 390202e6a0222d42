"""studies/transfer.py: bad settings are refused before anything runs; its smoke run trains a shared
policy on the portable observation, evaluates it on its plant and zero-shot on larger ones beside the
controllers, and a second run reuses every file."""

from __future__ import annotations

import json

import pytest

from tests.helpers import load_script


@pytest.mark.parametrize("change, match", [
    ({"targets": ["n5_m2_dt120"], "sources": ["n5_m2_dt120"]}, "targets: .* source plants too"),
    ({"hyperparams": {"observation": "local"}}, "hyperparams: the observation is 'portable'"),
    ({"seeds": [101, 101]}, "seeds: expected distinct entries"),
    ({"planner_episodes": 300}, "planner_episodes"),
    ({"targets": ["n99_m1_dt120"]}, "n99_m1_dt120"),
    ({"methods": ["ppo"]}, "methods: \\['ppo'\\] are not shared"),  # a centralised method: no agents to transfer
    ({"centralised": ["fast_shared_ppo"]}, "centralised: expected distinct centralised methods"),
    ({"centralised": ["fast_ppo", "fast_ppo"]}, "centralised: expected distinct"),
    ({"timing_steps": 0}, "timing_steps: expected at least 1"),
])
def test_bad_settings_are_refused_before_anything_is_written(tmp_path, change, match):
    study = load_script("studies/transfer.py")
    args = study.Args(out=str(tmp_path / "out"), runs=str(tmp_path / "runs"), **change)
    with pytest.raises(ValueError, match=match):
        study.main(args)
    assert not (tmp_path / "out").exists() and not (tmp_path / "runs").exists()


def test_every_plan_reports_on_fresh_episodes_and_the_methods_train_on_the_portable_observation(tmp_path):
    study = load_script("studies/transfer.py")
    plans = study.Args(out=str(tmp_path / "o"), runs=str(tmp_path / "r")).plans()
    assert set(plans) == {"fast_shared_ppo", "dagger_agents", "centralised", "controllers", "planner",
                          "rules_validation"}
    assert all(p.eval_protocol().first_seed == 30_000 for name, p in plans.items() if name != "rules_validation")
    # the rule on the episodes of the runs' curves: the yardstick of the training cost
    assert plans["rules_validation"].eval_protocol() == plans["fast_shared_ppo"].eval_protocol().__class__(
        episodes=30, first_seed=20_000)
    assert plans["rules_validation"].methods == ["rule_based_agents"]
    assert plans["fast_shared_ppo"].curves and plans["centralised"].curves
    assert plans["fast_shared_ppo"].hyperparams == {"observation": "portable"}
    # trained on the target plants too (in domain); the centralised PPO on every plant, on its own observation
    assert plans["fast_shared_ppo"].configs == plans["centralised"].configs == [*study.SOURCES, *study.TARGETS]
    assert plans["centralised"].methods == ["fast_ppo"] and plans["centralised"].hyperparams == {}
    zero_shot_only = study.Args(out=str(tmp_path / "o"), runs=str(tmp_path / "r"), in_domain=False, centralised=[])
    assert "centralised" not in zero_shot_only.plans()
    assert zero_shot_only.plans()["dagger_agents"].configs == list(study.SOURCES)
    assert plans["planner"].eval_protocol().episodes == 30 and plans["controllers"].eval_protocol().episodes == 200
    assert set(plans["controllers"].configs) == {*study.SOURCES, *study.TARGETS}


@pytest.mark.slow  # trains six tiny runs (with their curves), runs 23 short evaluations and 17 timings: seconds to a minute
def test_smoke_run_evaluates_zero_shot_and_a_rerun_reuses_everything(tmp_path, capsys):
    study = load_script("studies/transfer.py")
    args = study.Args(out=str(tmp_path / "out"), runs=str(tmp_path / "runs"), smoke=True)
    report = study.main(args)
    entries = {e["plant"]: e["cells"] for e in report["entries"]}
    assert set(entries["n32_m4_dt120"]) == {"rule_based", "rule_based_agents", "planner_agents",
                                            "fast_shared_ppo from n5_m2_dt120", "fast_shared_ppo (trained here)",
                                            "fast_ppo (trained here)"}
    assert {"fast_shared_ppo (trained here)", "fast_ppo (trained here)"} <= set(entries["n5_m2_dt120"])
    # every cell's decision time measured, on its own plant: the centralised PPO's network grows with n
    timing = json.loads((tmp_path / "out" / "decision_time.json").read_text())
    assert all(c["decision_ms_median"] > 0 for cells in entries.values() for c in cells.values())
    assert timing["fast_ppo (trained here)/n32_m4_dt120"]["steps"] == 5
    # every run trained on a plant has its curve kept in the results and a training cost against the rule
    for label in ("fast_ppo (trained here)", "fast_shared_ppo (trained here)"):
        cost = entries["n32_m4_dt120"][label]["cost_to_rule"]
        assert cost["runs"] == 1 and cost["rule_validation_return"] > 0
    assert "fast_shared_ppo from n5_m2_dt120" in entries["n32_m4_dt120"]
    assert "cost_to_rule" not in entries["n32_m4_dt120"]["fast_shared_ppo from n5_m2_dt120"]
    kept = json.loads((tmp_path / "out" / "curves" / "fast_ppo_n32_m4_dt120_s101.json").read_text())
    assert kept["timesteps"] == kept["curve"]["points"][-1]["samples"] >= 2_000  # whole rollouts: a few more
    assert (timing["fast_shared_ppo from n5_m2_dt120/n32_m4_dt120"]["model_sha256"]
            == timing["fast_shared_ppo (trained here)/n5_m2_dt120"]["model_sha256"]
            != timing["fast_shared_ppo (trained here)/n32_m4_dt120"]["model_sha256"])
    zero_shot = json.loads(study.zero_shot_path(args.for_smoke(), "fast_shared_ppo", "n5_m2_dt120", "n32_m4_dt120",
                                                101).read_text())
    assert zero_shot["config"] == "n32_m4_dt120" and zero_shot["source"]["config"] == "n5_m2_dt120"
    assert [e["seed"] for e in zero_shot["episodes"]] == [30_000, 30_001]
    capsys.readouterr()
    study.main(args)
    out = capsys.readouterr().out
    assert "0 run(s) to train" in out and "0 evaluation(s) to run" in out and "0 decision time(s) to measure" in out


def test_training_cost_is_counted_to_the_first_curve_point_at_the_rules_share(tmp_path):
    """The cost of a run: the samples of its curve's first point at or above 90 % of the rule's validation
    return (later dips do not matter), and its training time in that proportion; a seed that never
    reaches it counts apart and stays out of the medians."""
    study = load_script("studies/transfer.py")
    args = study.Args(out=str(tmp_path / "out"), runs=str(tmp_path / "runs"), seeds=[101, 102, 103])
    plans = args.plans()
    rule = tmp_path / "out" / "rules_validation" / "evaluations" / "n32_m4_dt120" / "rule_based_agents.json"
    rule.parent.mkdir(parents=True)
    rule.write_text(json.dumps({"summary": {"return_mean": 200.0}}))
    curves = {101: [(500_000, 150.0), (1_000_000, 181.0), (1_500_000, 170.0), (5_000_000, 190.0)],
              102: [(500_000, 179.9), (2_500_000, 180.0), (5_000_000, 185.0)],
              103: [(500_000, 10.0), (5_000_000, 179.0)]}
    for seed, points in curves.items():
        path = tmp_path / "out" / "curves" / f"fast_ppo_n32_m4_dt120_s{seed}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"timesteps": 5_000_000, "wall_time_s": 1000.0, "curve": {"points": [
            {"samples": s, "return_mean": r} for s, r in reversed(points)]}}))
    cost = study.cost_to_rule(args, plans, "n32_m4_dt120", "fast_ppo")
    assert cost["seeds"] == {"101": {"samples": 1_000_000, "cpu_s": 200.0},
                             "102": {"samples": 2_500_000, "cpu_s": 500.0}, "103": None}
    assert (cost["reached"], cost["runs"], cost["rule_validation_return"]) == (2, 3, 200.0)
    assert cost["samples_median"] == 1_750_000 and cost["cpu_s_median"] == 350.0
    assert study.cost_to_rule(args, plans, "n64_m8_dt120", "fast_ppo") is None  # no rule evaluation there


def test_a_call_for_one_method_keeps_the_other_methods_cells_in_the_table(tmp_path):
    """The table is everything ``--out`` holds: a call with ``--methods dagger_agents`` (or ``--report``)
    reads fast_shared_ppo's evaluations too, instead of writing a table of the one method."""
    study = load_script("studies/transfer.py")
    from containergym_marl.evaluation.table import evaluation_key

    out = tmp_path / "out"

    def evaluation(path, returns, overflows):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"episodes": [{"cumulative_reward": r, "overflow": o}
                                                 for r, o in zip(returns, overflows)]}))

    # fast_shared_ppo trained on a source plant (seed 101), by an earlier call; the imitation zero-shot, by this one
    evaluation(out / "fast_shared_ppo" / "evaluations" / "n11_m2_dt120" / f"{evaluation_key('fast_shared_ppo', 101)}.json",
               [110.0, 88.0], [False, True])
    args = study.Args(out=str(out), runs=str(tmp_path / "runs"), methods=["dagger_agents"], centralised=[],
                      seeds=[101], in_domain=False, report=True)
    evaluation(study.zero_shot_path(args, "dagger_agents", "n11_m2_dt120", "n32_m4_dt120", 101), [64.0, 96.0],
               [False, False])
    report = study.main(args)
    cells = {e["plant"]: e["cells"] for e in report["entries"]}
    mine = cells["n11_m2_dt120"]["fast_shared_ppo (trained here)"]
    assert mine["return_per_container"] == pytest.approx(99.0 / 11) and mine["overflow_share"] == 0.5
    assert cells["n32_m4_dt120"]["dagger_agents from n11_m2_dt120"]["return_per_container"] == pytest.approx(80.0 / 32)
    assert report["shown"] == {"methods": ["fast_shared_ppo", "dagger_agents"], "in_domain": [], "centralised": []}
    table = (out / "table.md").read_text()
    assert "(`fast_shared_ppo`, `dagger_agents`)" in table and "| n11_m2_dt120 | 11 | fast_shared_ppo (trained here) |" in table


def test_the_cost_figure_joins_plants_of_one_share_of_pus_only(tmp_path):
    """The two plants of each size (PUs in proportion, and scarce) are separate lines of the figure, each
    ordered by n, and the figure is written where it is asked to be."""
    study = load_script("studies/transfer.py")

    def cell(samples):
        return {"cost_to_rule": {"samples_median": samples}}

    report = {"entries": [
        {"plant": "n32_m3_dt120", "n": 32, "cells": {"dagger_agents (trained here)": cell(3.0)}},
        {"plant": "n64_m8_dt120", "n": 64, "cells": {"dagger_agents (trained here)": cell(2.0)}},
        {"plant": "n32_m4_dt120", "n": 32, "cells": {"dagger_agents (trained here)": cell(1.0),
                                                     "dagger_agents from n16_m2_dt120": {}}},
        {"plant": "n64_m6_dt120", "n": 64, "cells": {"dagger_agents (trained here)": cell(None)}},
        {"plant": "n11_m2_dt120", "n": 11, "cells": {"dagger_agents (trained here)": cell(4.0)}},
    ]}
    assert study.cost_lines(report) == {("dagger_agents", "m < n/8"): [(32, 3.0)],
                                        ("dagger_agents", "m = n/8"): [(32, 1.0), (64, 2.0)],
                                        ("dagger_agents", "m > n/8"): [(11, 4.0)]}
    path = tmp_path / "figure" / "cost.png"
    assert study.draw_costs(report, path) == path and path.stat().st_size > 0
