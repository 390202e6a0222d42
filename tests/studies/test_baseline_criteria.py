"""studies/baseline_criteria.py on a hand-made published folder: each pair is judged on both episode
sets as the numbers say, the seeds counted above the rule's overflow rate are those whose fresh files
overflow more often, and another method's files (fast_shared_ppo_team beside fast_shared_ppo) are not
read as its seeds. On the committed results: every row's three pairs and three seed counts."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
SCRIPT = str(REPO / "studies" / "baseline_criteria.py")


def _row(method: str, iqm: float, fresh_iqm: float, seeds: int = 15) -> dict:
    return {"config": "n5_m2_dt60", "method": method, "seeds": seeds, "iqm": iqm, "fresh_iqm": fresh_iqm}


def _fresh(path: Path, overflows: int, episodes: int = 20, policy: str = "") -> None:
    path.write_text(json.dumps({"policy": policy,
                                "episodes": [{"seed": 30000 + k, "overflow": k < overflows} for k in range(episodes)]}))


def test_pairs_and_overflowing_seeds_are_counted_from_the_files(tmp_path):
    results = tmp_path / "published"
    fresh = results / "fresh" / "n5_m2_dt60"
    fresh.mkdir(parents=True)
    rows = [_row("fast_ppo", 50.0, 49.0), _row("ppo", 40.0, 49.5, 5),  # test yes, fresh no
            _row("fast_shared_ppo", 30.0, 30.0), _row("shared_ppo", 30.0, 29.0, 5),  # equal counts as at least
            _row("fast_shared_ppo_team", 20.0, 20.0), _row("shared_ppo_team", 25.0, 26.0, 5),
            _row("rule_based_agents", 59.0, 59.0, 0)]
    (results / "table.json").write_text(json.dumps({"rows": rows}))
    _fresh(fresh / "rule_based_agents.json", 1)  # 1 of 20: 0.05
    for seed, overflows in ((1, 0), (2, 1), (3, 2), (4, 5)):  # s3 and s4 above 0.05
        _fresh(fresh / f"fast_shared_ppo_s{seed}.json", overflows, policy=f"fast_shared_ppo[s{seed},validated]")
    _fresh(fresh / "fast_shared_ppo_team_s1.json", 20, policy="fast_shared_ppo_team[s1,best]")  # another method's
    _fresh(fresh / "fast_ppo_s1.json", 0, policy="fast_ppo[s1,best]")
    _fresh(fresh / "fast_ppo_s2.json", 0, policy="fast_ppo[s2,validated]")
    done = subprocess.run([sys.executable, SCRIPT, "--results", str(results), "--out", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    found = json.loads((tmp_path / "out" / "criteria.json").read_text())
    judged = {p["method"]: (p["at_least_test"], p["at_least_fresh"]) for p in found["pairs"]}
    assert judged == {"fast_ppo": (True, False), "fast_shared_ppo": (True, True), "fast_shared_ppo_team": (False, False)}
    counted = {o["method"]: (o["seeds"], o["above"]) for o in found["overflows"]}
    assert counted == {"fast_ppo": (2, []), "fast_shared_ppo": (4, [3, 4]), "fast_shared_ppo_team": (1, [1])}
    models = {p["method"]: (p["model"], p["twin_model"]) for p in found["pairs"]}
    assert models == {"fast_ppo": ("best+validated", "–"), "fast_shared_ppo": ("validated", "–"),
                      "fast_shared_ppo_team": ("best", "–")}
    text = (tmp_path / "out" / "criteria.md").read_text()
    assert "**1 of 3 pairs hold on both episode sets** (2 on the test episodes, 1 on the fresh ones)" in text
    assert "| n5_m2_dt60 | fast_shared_ppo | 0.050 | 2 of 4: s3, s4 |" in text
    assert "**0 of 3 (row, method) have more than 2**" in text


def test_the_committed_results_have_every_pair_on_every_row(tmp_path):
    done = subprocess.run([sys.executable, SCRIPT, "--out", str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    found = json.loads((tmp_path / "criteria.json").read_text())
    assert len(found["pairs"]) == 27 and len(found["overflows"]) == 27
    assert all(o["seeds"] == 15 for o in found["overflows"])


def test_a_folder_without_a_table_is_refused(tmp_path):
    done = subprocess.run([sys.executable, SCRIPT, "--results", str(tmp_path), "--out", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode != 0 and "holds no table.json" in done.stderr and not (tmp_path / "out").exists()


def test_best_models_of_validated_seeds_are_evaluated_on_the_fresh_episodes_once(tmp_path):
    """--best-models: where the published fresh files are of validated models, each seed's best model is
    evaluated on the same fresh episodes (the IQM of one seed is its mean), cached by the model's hash."""
    sys.path.insert(0, str(REPO / "studies"))
    try:
        import baseline_criteria
    finally:
        sys.path.remove(str(REPO / "studies"))
    from containergym_marl.evaluation.batched import evaluate_batched
    from containergym_marl.evaluation.protocol import FRESH
    from containergym_marl.evaluation.run_policies import policy_from_run
    from containergym_marl.training import TrainArgs, train

    results = tmp_path / "published"
    train(TrainArgs(algo="fast_shared_ppo", out=str(results / "runs" / "fast_shared_ppo_n5_m2_dt60_s1"),
                    config="n5_m2_dt60", timesteps=1000, n_envs=2, seed=1, progress_bar=False,
                    hyperparams={"n_steps": 16, "minibatch_size": 80}, overrides={"episode_length_steps": 20}))
    (results / "fresh" / "n5_m2_dt60").mkdir(parents=True)
    _fresh(results / "fresh" / "n5_m2_dt60" / "fast_shared_ppo_s1.json", 0, policy="fast_shared_ppo[s1,validated]")
    cache = tmp_path / "cache"
    got = baseline_criteria.best_model_iqm(results, "n5_m2_dt60", "fast_shared_ppo", cache)
    run = results / "runs" / "fast_shared_ppo_n5_m2_dt60_s1"
    assert got == float(evaluate_batched(policy_from_run(run, "best"), "n5_m2_dt60", FRESH).returns.mean())
    stored = cache / "n5_m2_dt60" / "fast_shared_ppo_s1.json"
    before = stored.stat().st_mtime_ns
    assert baseline_criteria.best_model_iqm(results, "n5_m2_dt60", "fast_shared_ppo", cache) == got
    assert stored.stat().st_mtime_ns == before  # reused, not evaluated again
    _fresh(results / "fresh" / "n5_m2_dt60" / "fast_shared_ppo_s1.json", 0, policy="fast_shared_ppo[s1,best]")
    assert baseline_criteria.best_model_iqm(results, "n5_m2_dt60", "fast_shared_ppo", cache) is None


def test_a_table_naming_a_row_outside_the_built_in_plants_is_refused_before_anything_is_written(tmp_path):
    """A crafted table.json whose row names a path (its fresh files are read, and --best-models writes
    under that name) is refused, naming the value, and nothing is written."""
    results = tmp_path / "published"
    results.mkdir()
    (results / "table.json").write_text(json.dumps({"rows": [{**_row("fast_ppo", 1.0, 1.0), "config": "../../x"}]}))
    done = subprocess.run([sys.executable, SCRIPT, "--results", str(results), "--out", str(tmp_path / "out"),
                           "--best-models"], capture_output=True, text=True, timeout=120)
    assert done.returncode != 0 and "row config '../../x' is not a built-in plant" in done.stderr
    assert not (tmp_path / "out").exists() and not (tmp_path / "x").exists()


def test_the_moonshot_sets_every_method_without_a_teacher_against_the_rule_row_by_row(tmp_path):
    """Two rows: fast_shared_ppo above the rule's fresh mean on both (its interval too on one), ppo on
    one only, dagger_agents above on both but taught by the planner (left out), the checked method marked
    with its rule; a method on one row only cannot hold on every row."""
    def row(config, method, fresh_iqm, low=None, seeds=5):
        return {"config": config, "method": method, "seeds": seeds, "iqm": fresh_iqm, "fresh_iqm": fresh_iqm,
                "fresh_iqm_low": fresh_iqm - 1.0 if low is None else low, "fresh_overflow_rate": 0.0}

    rows = [row("n5_m2_dt60", "rule_based_agents", 50.0, seeds=0), row("n11_m2_dt120", "rule_based_agents", 90.0, seeds=0),
            row("n5_m2_dt60", "fast_shared_ppo", 50.5, low=49.0), row("n11_m2_dt120", "fast_shared_ppo", 92.0, low=91.0),
            row("n5_m2_dt60", "ppo", 51.0), row("n11_m2_dt120", "ppo", 90.0),  # equal is not above
            row("n5_m2_dt60", "dagger_agents", 59.0), row("n11_m2_dt120", "dagger_agents", 99.0),
            row("n11_m2_dt120", "fast_shared_ppo_checked", 95.0)]
    results = tmp_path / "published"
    results.mkdir()
    (results / "table.json").write_text(json.dumps({"rows": rows}))
    done = subprocess.run([sys.executable, SCRIPT, "--results", str(results), "--out", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    shots = {m["method"]: m for m in json.loads((tmp_path / "out" / "criteria.json").read_text())["moonshot"]}
    assert set(shots) == {"fast_shared_ppo", "ppo", "fast_shared_ppo_checked"}
    assert [(e["above"], e["interval_above"]) for e in shots["fast_shared_ppo"]["rows"]] == [(True, False), (True, True)]
    assert {m: s["every_row"] for m, s in shots.items()} == {"fast_shared_ppo": True, "ppo": False,
                                                            "fast_shared_ppo_checked": False}
    text = (tmp_path / "out" / "criteria.md").read_text()
    assert "**1 of 3 methods are above it on every row** (`fast_shared_ppo`)" in text
    assert "| `fast_shared_ppo` | 2 of 2 | > 50.50 (49.00) | >> 92.00 (91.00) |" in text
    assert "| `fast_shared_ppo_checked` (with the agents' own check) | 1 of 1 | – | >> 95.00 (94.00) |" in text
