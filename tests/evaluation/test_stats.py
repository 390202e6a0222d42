"""Aggregate statistics across seeds (IQM, stratified bootstrap CIs, probability of improvement).

Values are checked against hand computations on small inputs; scipy, when installed, is a
cross-check only (the module itself is numpy-only).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from containergym_marl.evaluation import stats
from containergym_marl.evaluation.stats import (
    Interval,
    format_ci,
    iqm,
    mean,
    median,
    performance_profile,
    performance_profile_ci_per_task,
    probability_of_improvement,
    probability_of_improvement_ci,
    probability_of_improvement_ci_per_task,
    stratified_bootstrap_ci,
    stratified_bootstrap_samples,
    summarise,
)

# --------------------------------------------------------------------------- IQM, mean, median


def test_iqm_of_one_to_eight_is_the_mean_of_the_middle_four():
    assert iqm(np.arange(1, 9)) == pytest.approx(4.5)  # mean of [3, 4, 5, 6]
    assert iqm([8, 1, 7, 2, 6, 3, 5, 4]) == pytest.approx(4.5)  # order does not matter


def test_iqm_of_ten_values_cuts_two_from_each_end():
    # int(0.25 * 10) = 2 per end, the middle six kept: (4 + 8 + 16 + 32 + 64 + 128) / 6 = 42.
    values = [512, 1, 64, 2, 256, 4, 128, 8, 32, 16]
    assert iqm(values) == pytest.approx(42.0)


@pytest.mark.parametrize(
    ("values", "expected"),
    [
        ([7.0], 7.0),  # n = 1: nothing cut
        ([1, 2, 9], 4.0),  # n = 3: int(0.75) = 0, the plain mean
        ([100, 1, 2, 3, 4], 3.0),  # n = 5: one cut per end, mean of [2, 3, 4]
        ([0, 1, 2, 3, 4, 5, 100], 3.0),  # n = 7: one cut per end, mean of [1..5]
        ([-100, 1, 2, 3, 4, 5, 6, 7, 200], 4.0),  # n = 9: two cut per end, mean of [2..6]
    ],
)
def test_iqm_trims_int_of_a_quarter_from_each_end(values, expected):
    assert iqm(values) == pytest.approx(expected)


def test_iqm_pools_runs_and_tasks():
    scores = np.array([[1, 8], [5, 2], [7, 3], [4, 6]])  # [run, task], values 1..8
    assert iqm(scores) == pytest.approx(4.5)
    assert iqm(scores[:, 0]) == iqm(scores[:, :1])  # 1-D = the runs of one task


def test_iqm_matches_scipy_trim_mean():
    scipy_stats = pytest.importorskip("scipy.stats")
    rng = np.random.default_rng(0)
    for shape in [(1, 1), (2, 1), (3, 2), (5, 1), (7, 3), (10, 1), (13, 2), (15, 8)]:
        for _ in range(5):
            scores = rng.standard_t(df=2, size=shape) * 10
            assert iqm(scores) == pytest.approx(scipy_stats.trim_mean(scores, 0.25, axis=None), rel=1e-12, abs=1e-12)


def test_mean_and_median_pool_all_scores():
    scores = np.array([[1.0, 10.0], [2.0, 20.0], [3.0, 30.0]])
    assert mean(scores) == pytest.approx(11.0)
    # Pooled median of [1, 2, 3, 10, 20, 30]; rliable's median of task means would give 11.
    assert median(scores) == pytest.approx(6.5)
    assert median([4, 1, 3]) == 3.0


# --------------------------------------------------------------------------- validation


@pytest.mark.parametrize("bad", [[], np.empty((0, 3)), np.empty((3, 0))])
@pytest.mark.parametrize("func", [iqm, mean, median, stratified_bootstrap_ci])
def test_empty_scores_are_rejected(func, bad):
    with pytest.raises(ValueError, match="empty"):
        func(bad)


@pytest.mark.parametrize("func", [iqm, mean, median, stratified_bootstrap_ci, stratified_bootstrap_samples])
def test_nan_scores_are_rejected(func):
    scores = np.ones((3, 2))
    scores[2, 1] = np.nan
    args = (scores, 10) if func is stratified_bootstrap_samples else (scores,)
    with pytest.raises(ValueError, match=r"NaN \(first at run 2, task 1\)"):
        func(*args)


def test_infinite_and_misshapen_scores_are_rejected():
    with pytest.raises(ValueError, match="infinite"):
        iqm([1.0, np.inf])
    with pytest.raises(ValueError, match="2-D"):
        iqm(np.ones((2, 2, 2)))
    with pytest.raises(ValueError, match="2-D"):
        iqm(3.0)
    with pytest.raises(ValueError, match="numeric"):
        iqm([[1, 2], [3]])
    with pytest.raises(ValueError, match="numeric"):
        iqm(["a", "b"])


def test_probability_of_improvement_rejects_mismatched_tasks_and_bad_inputs():
    with pytest.raises(ValueError, match="x has 3 task\\(s\\), y has 2"):
        probability_of_improvement(np.ones((4, 3)), np.ones((4, 2)))
    with pytest.raises(ValueError, match="same tasks"):
        probability_of_improvement_ci(np.ones((4, 1)), np.ones((4, 2)), reps=10)
    with pytest.raises(ValueError, match="y is empty"):
        probability_of_improvement([1.0], [])
    with pytest.raises(ValueError, match="x contains NaN"):
        probability_of_improvement([np.nan], [1.0])


def test_bootstrap_arguments_are_checked():
    scores = np.arange(6.0)
    for reps in (0, -5, 2.5, True):
        with pytest.raises(ValueError, match="reps"):
            stratified_bootstrap_ci(scores, reps=reps)
    for confidence in (0.0, 1.0, 95, float("nan")):
        with pytest.raises(ValueError, match="confidence"):
            stratified_bootstrap_ci(scores, confidence=confidence)
    for rng in (None, 1.5, True, np.random.RandomState(0)):
        with pytest.raises(TypeError, match="rng"):
            stratified_bootstrap_ci(scores, reps=10, rng=rng)


# --------------------------------------------------------------------------- stratified bootstrap


@pytest.mark.parametrize("aggregate", [iqm, mean, median])
def test_ci_of_constant_scores_is_degenerate_at_the_constant(aggregate):
    point, low, high = stratified_bootstrap_ci(np.full((5, 3), 7.25), aggregate, reps=200, rng=0)
    assert point == low == high == pytest.approx(7.25)


@pytest.mark.parametrize("aggregate", [iqm, mean, median])
def test_ci_contains_the_point_estimate(aggregate):
    scores = np.random.default_rng(1).normal(50.0, 5.0, size=(10, 4))
    ci = stratified_bootstrap_ci(scores, aggregate, reps=1000, rng=2)
    assert isinstance(ci, Interval)
    assert ci.point == pytest.approx(aggregate(scores))
    assert ci.low < ci.point < ci.high


def test_ci_narrows_with_more_runs_on_average():
    data_rng = np.random.default_rng(3)

    def mean_width(n_runs: int) -> float:
        widths = []
        for seed in range(15):
            scores = data_rng.normal(0.0, 1.0, size=(n_runs, 2))
            _, low, high = stratified_bootstrap_ci(scores, iqm, reps=400, rng=seed)
            widths.append(high - low)
        return float(np.mean(widths))

    assert mean_width(40) < 0.6 * mean_width(5)  # about 1/sqrt(8) ~ 0.35 expected


def test_a_higher_confidence_gives_a_nested_wider_interval():
    scores = np.random.default_rng(4).gamma(2.0, 3.0, size=(8, 3))
    narrow = stratified_bootstrap_ci(scores, iqm, reps=500, confidence=0.5, rng=7)
    wide = stratified_bootstrap_ci(scores, iqm, reps=500, confidence=0.95, rng=7)  # same replicates
    assert wide.low < narrow.low < narrow.high < wide.high


def _tasks_with_disjoint_ranges(n_runs: int = 6, n_tasks: int = 3) -> np.ndarray:
    # Task t scores lie in [100 t, 100 t + 1), all distinct.
    return np.random.default_rng(5).random((n_runs, n_tasks)) + 100.0 * np.arange(n_tasks)


def test_resampling_is_stratified_by_task():
    scores = _tasks_with_disjoint_ranges()
    n_runs, n_tasks = scores.shape
    samples = stratified_bootstrap_samples(scores, reps=300, rng=3)
    assert samples.shape == (300, n_runs, n_tasks)
    run_of = np.empty_like(samples, dtype=np.int64)  # which original run each resampled score is
    for t in range(n_tasks):
        column = samples[:, :, t]
        assert ((column >= 100.0 * t) & (column < 100.0 * t + 1.0)).all()  # never from another task
        assert np.isin(column, scores[:, t]).all()  # and always one of this task's runs
        run_of[:, :, t] = np.argsort(scores[:, t])[np.searchsorted(np.sort(scores[:, t]), column)]
        assert set(np.unique(run_of[:, :, t])) == set(range(n_runs))  # every run gets drawn
    # With replacement: some replicate repeats a run; independently per task: patterns differ.
    assert any(len(set(run_of[b, :, 0])) < n_runs for b in range(300))
    assert (run_of[:, :, 0] != run_of[:, :, 1]).any()


def test_chunked_resampling_keeps_shape_and_strata(monkeypatch):
    monkeypatch.setattr(stats, "_MAX_CHUNK_ELEMENTS", 7)  # 18 scores per replicate: one per chunk
    scores = _tasks_with_disjoint_ranges()
    samples = stratified_bootstrap_samples(scores, reps=11, rng=0)
    assert samples.shape == (11, *scores.shape)
    for t in range(scores.shape[1]):
        assert np.isin(samples[:, :, t], scores[:, t]).all()
    _, low, high = stratified_bootstrap_ci(scores, iqm, reps=11, rng=0)
    assert low <= high


def test_ci_is_the_percentile_interval_of_the_exposed_replicates():
    scores = np.random.default_rng(6).normal(size=(7, 3))
    samples = stratified_bootstrap_samples(scores, reps=400, rng=11)
    values = [iqm(replicate) for replicate in samples]
    point, low, high = stratified_bootstrap_ci(scores, iqm, reps=400, confidence=0.9, rng=11)
    assert point == iqm(scores)
    assert (low, high) == pytest.approx(tuple(np.percentile(values, [5.0, 95.0])), rel=1e-12)


def test_a_custom_aggregate_matches_the_vectorised_builtin():
    scores = np.random.default_rng(8).normal(size=(6, 2))
    custom = stratified_bootstrap_ci(scores, lambda a: float(np.mean(a)), reps=300, rng=9)
    builtin = stratified_bootstrap_ci(scores, mean, reps=300, rng=9)
    assert custom == pytest.approx(builtin, rel=1e-12)


def test_bootstrap_is_deterministic_for_a_fixed_seed():
    scores = np.random.default_rng(10).normal(size=(5, 3))
    assert stratified_bootstrap_ci(scores, reps=300, rng=42) == stratified_bootstrap_ci(scores, reps=300, rng=42)
    from_generator = stratified_bootstrap_ci(scores, reps=300, rng=np.random.default_rng(42))
    assert from_generator == stratified_bootstrap_ci(scores, reps=300, rng=42)
    assert stratified_bootstrap_ci(scores, reps=300, rng=43) != stratified_bootstrap_ci(scores, reps=300, rng=42)
    generator = np.random.default_rng(1)  # a generator is advanced: consecutive calls differ
    assert stratified_bootstrap_ci(scores, reps=300, rng=generator) != stratified_bootstrap_ci(
        scores, reps=300, rng=generator
    )
    np.testing.assert_array_equal(
        stratified_bootstrap_samples(scores, 50, rng=3), stratified_bootstrap_samples(scores, 50, rng=3)
    )


# --------------------------------------------------------------------------- probability of improvement


@pytest.mark.parametrize(
    ("x", "y", "expected"),
    [
        ([3, 4], [1, 2], 1.0),
        ([1, 2], [3, 4], 0.0),
        ([1, 2], [1, 2], 0.5),  # ties count half: (0.5 + 0 + 1 + 0.5) / 4
        ([1, 3], [2], 0.5),
        ([2, 2], [1, 2, 3], 0.5),  # (1 + 0.5 + 0) * 2 / 6
        ([2, 3], [1, 2, 4], 7 / 12),  # x=2: 1 + 0.5 + 0; x=3: 1 + 1 + 0
    ],
)
def test_probability_of_improvement_hand_values(x, y, expected):
    assert probability_of_improvement(x, y) == pytest.approx(expected)


def test_probability_of_improvement_averages_over_tasks():
    x = np.array([[3, 1], [4, 2]])  # task 0 beats y, task 1 loses
    y = np.array([[1, 3], [2, 4]])
    assert probability_of_improvement(x, y) == pytest.approx(0.5)
    # Different run counts per method; per task 1, 0.5 and 7/12.
    x = np.array([[3, 1, 2], [4, 3, 3]])
    y = np.array([[1, 2, 1], [2, 2, 2], [0, 2, 4]])
    assert probability_of_improvement(x, y) == pytest.approx((1 + 0.5 + 7 / 12) / 3)


def test_probability_of_improvement_is_complementary():
    rng = np.random.default_rng(12)
    x, y = np.round(rng.normal(size=(6, 3))), np.round(rng.normal(size=(9, 3)))  # with ties
    assert probability_of_improvement(x, y) + probability_of_improvement(y, x) == pytest.approx(1.0)


def test_probability_of_improvement_matches_scipy_mann_whitney():
    scipy_stats = pytest.importorskip("scipy.stats")
    rng = np.random.default_rng(13)
    x, y = np.round(rng.normal(size=(7, 4)) * 2), np.round(rng.normal(size=(5, 4)) * 2)
    per_task = [scipy_stats.mannwhitneyu(x[:, t], y[:, t]).statistic / (7 * 5) for t in range(4)]
    assert probability_of_improvement(x, y) == pytest.approx(np.mean(per_task), rel=1e-12)


def test_probability_of_improvement_ci():
    assert probability_of_improvement_ci([[5, 6], [7, 8]], [[1, 2], [3, 4]], reps=200, rng=0) == (1.0, 1.0, 1.0)
    rng = np.random.default_rng(14)
    x, y = rng.normal(1.0, 1.0, size=(10, 3)), rng.normal(0.0, 1.0, size=(10, 3))
    ci = probability_of_improvement_ci(x, y, reps=1000, rng=1)
    assert ci.point == pytest.approx(probability_of_improvement(x, y))
    assert 0.0 <= ci.low < ci.point < ci.high <= 1.0
    assert ci == probability_of_improvement_ci(x, y, reps=1000, rng=1)


def test_probability_of_improvement_ci_resamples_both_methods():
    # One run on one side, two far-apart runs on the other: only resampling the latter moves P.
    assert probability_of_improvement_ci([5.0], [1.0, 9.0], reps=500, rng=0) == (0.5, 0.0, 1.0)
    assert probability_of_improvement_ci([1.0, 9.0], [5.0], reps=500, rng=0) == (0.5, 0.0, 1.0)


# --------------------------------------------------------------------------- summary and formatting


def test_summarise_reports_each_method():
    rng = np.random.default_rng(15)
    scores = {"centralised": rng.normal(40.0, 5.0, size=(5, 2)), "decentralised": rng.normal(45.0, 5.0, size=(8, 2))}
    summary = summarise(scores, reps=300, rng=0)
    assert list(summary) == ["centralised", "decentralised"]
    for method, s in scores.items():
        row = summary[method]
        assert (row["n_runs"], row["n_tasks"]) == s.shape
        assert row["iqm"].point == pytest.approx(iqm(s))
        assert row["mean"].point == pytest.approx(mean(s))
        assert row["median"] == pytest.approx(median(s))
        for key in ("iqm", "mean"):
            assert row[key].low <= row[key].point <= row[key].high
    json.dumps(summary)  # plain numbers and tuples only


def test_summarise_streams_do_not_depend_on_other_methods():
    rng = np.random.default_rng(16)
    a, b = rng.normal(size=(5, 2)), rng.normal(size=(6, 2))
    alone = summarise({"a": a}, reps=200, rng=3)["a"]
    assert summarise({"b": b, "a": a}, reps=200, rng=3)["a"] == alone
    assert summarise({"a": a}, reps=200, rng=4)["a"] != alone
    generator_based = summarise({"a": a}, reps=200, rng=np.random.default_rng(3))
    assert generator_based == summarise({"a": a}, reps=200, rng=np.random.default_rng(3))


def test_summarise_rejects_empty_input_and_names_the_bad_method():
    with pytest.raises(ValueError, match="empty"):
        summarise({})
    with pytest.raises(ValueError, match="'decentralised'.*NaN"):
        summarise({"centralised": [1.0, 2.0], "decentralised": [1.0, np.nan]}, reps=10)


def test_format_ci():
    assert format_ci((12.345, 10.06, 14.0)) == "12.3 [10.1, 14.0]"
    assert format_ci(Interval(0.5, 0.254, 0.876), digits=2) == "0.50 [0.25, 0.88]"
    assert format_ci(Interval(-1.0, -2.4, 0.0), digits=0) == "-1 [-2, 0]"


# --------------------------------------------------------------------------- performance profiles


def test_performance_profile_by_hand():
    """Task 0 runs [1, 2, 3, 4], task 1 runs [10, 20, 30, 40]: above τ = 2.5, half of task 0's runs
    and all of task 1's, so 0.75; above 25, none of task 0's and half of task 1's: 0.25."""
    from containergym_marl.evaluation.stats import performance_profile

    scores = np.array([[1, 10], [2, 20], [3, 30], [4, 40]], dtype=float)
    assert performance_profile(scores, [0.0, 2.5, 25.0, 100.0]).tolist() == [1.0, 0.75, 0.25, 0.0]
    # a task weighs the same whatever its spread: one task's profile is its runs' survival function
    assert performance_profile([3.0, 1.0, 2.0], [1.5]).tolist() == [pytest.approx(2 / 3)]


def test_performance_profile_interval_brackets_the_point_and_narrows_with_more_runs():
    from containergym_marl.evaluation.stats import performance_profile_ci

    rng = np.random.default_rng(3)
    taus = np.linspace(0, 1, 11)
    few = rng.uniform(size=(5, 2))
    point, low, high = performance_profile_ci(few, taus, reps=500, rng=0)
    assert np.all(low <= point + 1e-12) and np.all(point <= high + 1e-12)
    assert point[0] == low[0] == high[0] == 1.0 and point[-1] == low[-1] == high[-1] == 0.0
    many = rng.uniform(size=(200, 2))
    _, low_many, high_many = performance_profile_ci(many, taus, reps=500, rng=0)
    assert (high_many - low_many)[3:8].mean() < (high - low)[3:8].mean()


# ---- tasks with different numbers of runs -----------------------------------------------------------
def test_per_task_profile_and_improvement_with_equal_runs_match_the_array_forms():
    rng = np.random.default_rng(5)
    scores = rng.normal(size=(6, 3))
    other = rng.normal(0.3, 1.0, size=(4, 3))
    taus = np.linspace(-2, 2, 9)
    point, low, high = performance_profile_ci_per_task([scores[:, t] for t in range(3)], taus, reps=300)
    np.testing.assert_allclose(point, performance_profile(scores, taus))
    assert np.all(low <= point + 1e-12) and np.all(point <= high + 1e-12)
    p, lo, hi = probability_of_improvement_ci_per_task([other[:, t] for t in range(3)],
                                                       [scores[:, t] for t in range(3)], reps=300)
    assert p == pytest.approx(probability_of_improvement(other, scores), rel=1e-12)
    assert lo <= p <= hi


def test_per_task_forms_weigh_every_task_the_same_whatever_its_runs():
    # task 0: 2 runs, both above 1; task 1: 5 runs, one above 1 -> share above 1 = (1 + 1/5) / 2
    tasks = [np.array([2.0, 3.0]), np.array([0.0, 0.5, 0.2, 0.1, 4.0])]
    point, _, _ = performance_profile_ci_per_task(tasks, [1.0], reps=50)
    assert point[0] == pytest.approx(0.6)
    # P(X > Y) on task 0 is 1 (every x beats every y), on task 1 it is 0.5 (ties only) -> 0.75
    p, low, high = probability_of_improvement_ci_per_task([np.array([5.0, 6.0, 7.0]), np.array([1.0])],
                                                          [np.array([0.0]), np.array([1.0, 1.0])], reps=200)
    assert (p, low, high) == pytest.approx((0.75, 0.75, 0.75))  # no resample can change a sure win or a tie
    with pytest.raises(ValueError, match="same tasks"):
        probability_of_improvement_ci_per_task([np.ones(2)], [np.ones(2), np.ones(3)])
    with pytest.raises(ValueError, match="1-D"):
        performance_profile_ci_per_task([np.ones((2, 2))], [0.5])
