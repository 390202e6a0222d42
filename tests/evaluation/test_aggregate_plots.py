"""The figures over seeds and rows: sample-efficiency curves from runs' curve files, performance
profiles and probabilities of improvement from evaluation files, drawn with the numbers the
statistics module gives (read back from the SVGs' paths) and reproducible byte for byte."""

from __future__ import annotations

import json

import numpy as np
import pytest

from containergym_marl.evaluation.aggregate_plots import (
    draw_aggregate_figures,
    normalised_scores,
    plot_performance_profiles,
    plot_sample_efficiency,
)
from containergym_marl.evaluation.curves import iqm_curve


def _curve(returns, budget=1000):
    return {"budget": budget, "points": [{"samples": int(budget * (k + 1) / len(returns)), "return_mean": r,
                                          "overflow_rate": 0.0} for k, r in enumerate(returns)]}


def test_the_sample_efficiency_curve_is_the_iqm_over_runs(tmp_path):
    curves = [_curve(np.linspace(0, 10, 10) + s) for s in range(4)]
    fig = plot_sample_efficiency({"m": curves}, tmp_path / "se", config="row", reps=100)
    line = next(a for a in fig.axes[0].lines if a.get_gid() == "iqm-m")
    expected = iqm_curve(curves, reps=100)["iqm"]
    np.testing.assert_allclose(line.get_ydata(), expected)
    np.testing.assert_allclose(line.get_xdata(), np.arange(1, 11) * 100)  # tenths of the 1000-sample budget
    assert (tmp_path / "se.png").is_file() and (tmp_path / "se.svg").is_file()
    with pytest.raises(ValueError, match="different budgets"):
        plot_sample_efficiency({"m": [_curve([1.0]), _curve([1.0], budget=2000)]}, tmp_path / "x")


def test_scores_are_shares_of_the_reference_and_methods_missing_a_row_are_left_out():
    scores = normalised_scores({"a": {"r1": [10.0, 20.0], "r2": [5.0]}, "b": {"r1": [10.0]}},
                               {"r1": 20.0, "r2": 10.0})
    assert set(scores) == {"a"}
    np.testing.assert_allclose(scores["a"]["r1"], [0.5, 1.0])
    np.testing.assert_allclose(scores["a"]["r2"], [0.5])


def _evaluation(returns, view="decentralised"):
    return {"view": view, "episodes": [{"seed": 10_000 + k, "cumulative_reward": r, "overflow": False}
                                       for k, r in enumerate(returns)]}


def test_a_published_folder_gets_its_figures_reproducibly(tmp_path):
    root = tmp_path / "published"
    for row, base in (("n5_m2_dt120", 60.0), ("n11_m2_dt120", 100.0)):
        folder = root / "evaluations" / row
        folder.mkdir(parents=True)
        (folder / "rule_based_agents.json").write_text(json.dumps(_evaluation([base, base])))
        for seed, share in ((1, 0.5), (2, 0.9), (3, 1.1)):
            (folder / f"good_s{seed}.json").write_text(json.dumps(_evaluation([share * base] * 2)))
        for seed, share in ((1, 0.4), (2, 0.6)):  # fewer runs than "good", on the same rows
            (folder / f"weak_s{seed}.json").write_text(json.dumps(_evaluation([share * base] * 2)))
    written = draw_aggregate_figures(root, pairs=[("good", "weak"), ("good", "absent")], reps=200)
    assert sorted(p.name for p in written) == [
        "performance_profiles.png", "performance_profiles.svg", "probability_of_improvement.png",
        "probability_of_improvement.svg"]  # no run has a curve file: no sample-efficiency figure
    svg = (root / "figures" / "performance_profiles.svg").read_text()
    assert 'id="profile-good"' in svg and 'id="profile-weak"' in svg and "rule_based_agents" in svg
    poi = (root / "figures" / "probability_of_improvement.svg").read_text()
    assert 'id="poi-good-weak"' in poi and "absent" not in poi
    first = {p.name: p.read_bytes() for p in written if p.suffix == ".svg"}
    draw_aggregate_figures(root, pairs=[("good", "weak"), ("good", "absent")], reps=200)
    assert {p.name: p.read_bytes() for p in written if p.suffix == ".svg"} == first


def test_the_profile_is_the_share_of_runs_above_each_threshold(tmp_path):
    scores = {"good": {"r1": np.array([0.5, 0.9, 1.1]), "r2": np.array([0.5, 0.9, 1.1])},
              "weak": {"r1": np.array([0.4, 0.6]), "r2": np.array([0.4, 0.6])}}
    fig = plot_performance_profiles(scores, tmp_path / "p", taus=np.array([0.45, 1.0]), reps=50)
    lines = {line.get_gid(): line.get_ydata() for line in fig.axes[0].lines if line.get_gid()}
    np.testing.assert_allclose(lines["profile-good"], [1.0, 1 / 3])
    np.testing.assert_allclose(lines["profile-weak"], [0.5, 0.0])
