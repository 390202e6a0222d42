"""The published comparison (results/paper_rows/) is consistent with itself and with the README: the
committed table is the table of the committed evaluation files, rebuilt from them alone (what a fresh
clone does), and the README's compact table and the results page's generated blocks are what
containergym-marl publish writes from it now."""

from __future__ import annotations

from pathlib import Path

import pytest

from containergym_marl.evaluation import table as tables
from containergym_marl.orchestration import publish as publish_results

ROOT = Path(__file__).resolve().parents[2]
PUBLISHED = ROOT / "results" / "paper_rows"




def test_committed_table_is_the_table_of_the_committed_evaluations(tmp_path):
    rebuilt = tables.build_table(tables.load_evaluations(PUBLISHED / "evaluations"))
    rebuilt.write(tmp_path, {"source": "containergym-marl publish"})
    assert (tmp_path / "table.md").read_text() == (PUBLISHED / "table.md").read_text()
    assert (tmp_path / "table.csv").read_text() == (PUBLISHED / "table.csv").read_text()


def test_readme_shows_the_committed_table():
    """The README's compact table is what the publishing step writes from the committed table now
    (``containergym-marl publish --pages-only --readme README.md --docs docs/results.md``)."""
    readme = (ROOT / "README.md").read_text()
    start = readme.index(publish_results.README_START.format(source="results/paper_rows"))
    end = readme.index(publish_results.README_END)
    shown = readme[start:end].split("\n", 1)[1].strip()
    assert shown == publish_results.readme_block(PUBLISHED).strip()


def test_results_page_shows_the_committed_tables():
    """Every generated block of docs/results.md is what the publishing step writes now, and every
    published row has its block."""
    page = (ROOT / "docs" / "results.md").read_text()
    blocks = publish_results.page_blocks(PUBLISHED)
    assert publish_results.fill_page(page, blocks) == page, (
        "docs/results.md is stale: containergym-marl publish --pages-only --readme README.md "
        "--docs docs/results.md")
    for name in blocks:
        assert publish_results.PAGE_START.format(name=name) in page, f"docs/results.md has no block {name!r}"
    assert (PUBLISHED / "table.md").read_text().strip() in page


def test_compact_table_has_one_row_per_config_and_the_iqm_of_each_method(tmp_path):
    """Hand-made table.json: two configs, a rule-based controller and one learned method on one of them."""
    import json

    to = tmp_path / "paper_rows"
    to.mkdir()
    rows = [{"config": "n5_m2_dt120", "method": "rule_based", "seeds": 0, "iqm": 58.855},
            {"config": "n5_m2_dt120", "method": "ppo", "seeds": 5, "iqm": 50.11},
            {"config": "n11_m2_dt120", "method": "rule_based", "seeds": 0, "iqm": 76.8},
            {"config": "n11_m2_dt120", "method": "planner_agents", "seeds": 0, "iqm": 96.84}]
    (to / "table.json").write_text(json.dumps({"rows": rows}))
    lines = publish_results.compact_table(to).splitlines()
    assert lines[0] == "| row | `rule_based` | `ppo` | `planner_agents` |"  # the planner: the last column
    assert lines[2] == "| `n5_m2_dt120` | 58.9 | 50.1 (5) | – |"
    assert lines[3] == "| `n11_m2_dt120` | 76.8 | – | 96.8 |"
    assert "(5 evaluated policies)" in lines[5] and "rule-based controllers and the rollout planner" in lines[5]


def test_fill_page_replaces_known_blocks_and_refuses_unknown_ones():
    start, end = publish_results.PAGE_START.format(name="a"), publish_results.PAGE_END.format(name="a")
    page = f"intro\n{start}\nold\n{end}\noutro\n"
    assert publish_results.fill_page(page, {"a": "new"}) == f"intro\n{start}\n\nnew\n\n{end}\noutro\n"
    try:
        publish_results.fill_page(page, {"b": "x"})
    except ValueError as exc:
        assert "unknown" in str(exc)
    else:
        raise AssertionError("an unknown block was accepted")


def test_committed_compute_is_the_sum_of_the_committed_runs_times():
    assert (PUBLISHED / "compute.md").read_text() == publish_results.training_compute(PUBLISHED / "runs")


def test_training_compute_sums_finished_runs_per_row(tmp_path):
    """Hand-computed: two finished runs on one row (1800 s + 5400 s = 2 h), one on another (3600 s), an
    interrupted run left out."""
    import json


    def run(name, config, wall_s, finished=True, algo="ppo", reward_mode=None, cpu_s=None):
        d = tmp_path / name
        d.mkdir()
        (d / "args.json").write_text(json.dumps({"algo": algo, "config": config, "seed": 1, "reward_mode": reward_mode}))
        if finished:
            (d / "run.json").write_text(json.dumps({"status": "finished", "wall_time_s": wall_s, "cpu_time_s": cpu_s}))
            (d / ("final_model.zip" if algo == "ppo" else "final_model.pt")).write_bytes(b"model")

    run("ppo_n5_m2_dt120_s1", "n5_m2_dt120", 1800.0)
    run("ppo_n5_m2_dt120_s2", "n5_m2_dt120", 5400.0)
    run("ppo_n11_m2_dt120_s1", "n11_m2_dt120", 3600.0)
    run("ppo_n11_m2_dt120_s2", "n11_m2_dt120", 0.0, finished=False)
    run("fast_shared_ppo_team_n11_m2_dt120_s1", "n11_m2_dt120", 900.0, algo="fast_shared_ppo", reward_mode="team")
    text = publish_results.training_compute(tmp_path)
    assert text.startswith("Training compute of the 4 finished runs published here: 3.2 core-hours, the wall time")
    assert "Per row: n5_m2_dt120: 2 runs, 2.0 h · n11_m2_dt120: 2 runs, 1.2 h.\n" in text
    # per method, in the registry's order: the team reward's runs are their own method
    assert text.endswith("Per method: ppo: 3 runs, 3.0 h · fast_shared_ppo_team: 1 run, 0.2 h.\n")
    # a run that recorded its CPU time counts by it (360 s of a 900 s wall time), the others by their wall time
    (tmp_path / "fast_shared_ppo_team_n11_m2_dt120_s1" / "run.json").write_text(
        json.dumps({"status": "finished", "wall_time_s": 900.0, "cpu_time_s": 360.0}))
    text = publish_results.training_compute(tmp_path)
    assert "3.1 core-hours, the CPU time of each run's training process (run.json's cpu_time_s), or its wall " \
           "time for the 3 that predate it" in text and "fast_shared_ppo_team: 1 run, 0.1 h" in text
    assert "n11_m2_dt120: 2 runs, 1.1 h" in text


def test_readme_block_is_replaced_in_place_and_a_missing_marker_is_named(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text("# title\n\nbefore\n<!-- results table: old -->\nold table\n<!-- end of results table -->\nafter\n")
    publish_results.show_table_in_readme(readme, "| a |\n|---|\n| 1 |\n", Path("results/x"))
    assert readme.read_text() == (
        "# title\n\nbefore\n"
        "<!-- results table: written by containergym-marl publish from results/x; do not edit -->\n\n"
        "| a |\n|---|\n| 1 |\n\n<!-- end of results table -->\nafter\n")
    readme.write_text("no markers\n")
    try:
        publish_results.show_table_in_readme(readme, "| a |\n", Path("results/x"))
    except ValueError as exc:
        assert "results-table block" in str(exc) and "found 0 start and 0 end" in str(exc)
    else:
        raise AssertionError("a README without markers was accepted")
    assert readme.read_text() == "no markers\n"  # untouched


def test_the_published_planner_is_the_planner_study_s_default_setting():
    """The rollout planner's rows of the table at its default (cheap) setting (evaluated like the rules
    by compare) are the numbers studies/planner_rows.py found for it on the same test episodes; the
    reference, the shielded planners, has a row on every plant, none of whose test or 200 fresh
    episodes overflows."""
    import json

    study = {(e["row"], e["method"]): e["return_mean"]
             for e in json.loads((ROOT / "results" / "planner" / "rows.json").read_text())["evaluations"]
             if e["setting"] == "default"}
    rows = [r for r in json.loads((PUBLISHED / "table.json").read_text())["rows"] if r["method"].startswith("planner")]
    plain = [r for r in rows if not r["method"].endswith("_shielded")]
    assert {(r["config"], r["method"]) for r in plain} == set(study)
    for r in plain:
        assert r["best_mean"] == pytest.approx(study[(r["config"], r["method"])], rel=1e-12), r["config"]
        assert r["fresh_episodes"] == 200 and r["seeds"] == 0
    shielded = {(r["config"], r["method"]): r for r in rows if r["method"].endswith("_shielded")}
    assert set(shielded) == {(row, f"{m}_shielded") for row, m in study}
    for r in shielded.values():
        assert (r["fresh_episodes"], r["seeds"], r["overflow_rate"], r["fresh_overflow_rate"]) == (200, 0, 0.0, 0.0)


def test_every_shipped_model_has_a_card_of_its_fresh_numbers_and_native_ones_their_safetensors():
    """Each model in models/<row>/ has its card, whose metric and overflow share are recomputed here
    from the seed's fresh evaluation file, and each native actor-critic its safetensors copy with the
    same weights; all are in the manifest."""
    import json

    import numpy as np
    import torch

    from containergym_marl.manifest import read_manifest
    from containergym_marl.policies.actor_critic import ActorCritic

    listed = read_manifest(PUBLISHED)
    metas = sorted((PUBLISHED / "models").glob("*/*.json"))
    assert metas
    natives = 0
    for path in metas:
        meta = json.loads(path.read_text())
        for which in ("best", "median"):
            seed = meta[f"{which}_seed"]
            fresh = json.loads((PUBLISHED / "fresh" / meta["config"] / f"{meta['method']}_s{seed}.json").read_text())
            returns = np.array([e["cumulative_reward"] for e in fresh["episodes"]])
            card = (path.parent / meta["cards"][which]).read_text()
            assert f"value: {returns.mean():.2f} +/- {returns.std():.2f}\n" in card, (path, which)
            overflow = np.mean([e["overflow"] for e in fresh["episodes"]])
            assert f"overflows in {overflow:.1%} of the fresh episodes" in card
            assert f"models/{meta['config']}/{meta['cards'][which]}" in listed
            model = path.parent / meta["files"][which]
            if model.suffix == ".pt" and meta["method"] != "mappo":
                natives += 1
                weights = path.parent / meta["safetensors"][which]
                assert f"models/{meta['config']}/{weights.name}" in listed
                a, b = ActorCritic.load(model).net.state_dict(), ActorCritic.load(weights).net.state_dict()
                assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    assert natives > 0
