"""Aggregate statistics across training seeds, in the style of rliable.

Agarwal et al. (2021), "Deep Reinforcement Learning at the Edge of the Statistical Precipice",
recommend reporting, beside the usual mean ± std, the **interquartile mean** (IQM) with
**stratified bootstrap confidence intervals**, and the **probability of improvement** of one
method over another. This module computes those for the ``compare`` command.

Data model
----------
The scores of one method are a 2-D array ``scores[run, task]``: runs are training seeds, tasks
are plant configurations, and a score is the run's mean test return over its evaluation
episodes. A 1-D array is taken as the runs of a single task. Every function rejects, with a
``ValueError``, empty arrays and arrays holding NaN or ±inf.

Why numpy and not the ``rliable`` package
-----------------------------------------
``pip install --dry-run rliable`` would pull in eleven packages (rliable, arch, statsmodels,
scipy, pandas, seaborn, patsy, formulaic, narwhals, wrapt, interface_meta) for what amounts to a
trimmed mean, a percentile bootstrap and a Mann-Whitney count; and the set it resolved to here
(rliable 1.2.0, arch 7.2.0, pandas 3.1.1) did not even import (arch fails against pandas 3 with a
``TypeError`` in ``deprecate_kwarg``) until pandas was pinned below 3. The formulas below are short,
numpy-only (a core dependency already), and draw randomness only from an explicit
``np.random.Generator``, as everything in this package does. Point estimates agree with rliable's
``aggregate_iqm``, ``aggregate_mean`` and ``probability_of_improvement`` to floating-point
rounding (checked against rliable 1.2.0 in a scratch environment with ``pandas<3``). Bootstrap
intervals follow the same method (stratified resampling of runs within each task, percentile
interval) but not the same random stream (rliable goes through arch and a legacy
``RandomState``), so they agree in distribution, not digit for digit.

One deliberate difference: :func:`median` is the median of all run × task scores pooled, like
:func:`iqm`. rliable's ``aggregate_median`` is the median over tasks of the per-task mean scores,
an Atari-suite convention that, with one or two plant configurations, is just a mean.

Functions
---------
- :func:`iqm`, :func:`mean`, :func:`median`: aggregates, ``scores -> float``.
- :func:`stratified_bootstrap_samples`: the bootstrap replicates themselves (for inspection).
- :func:`stratified_bootstrap_ci`: ``(point, low, high)`` for any aggregate.
- :func:`probability_of_improvement` and :func:`probability_of_improvement_ci`.
- :func:`performance_profile` and :func:`performance_profile_ci`: rliable's run-score distribution.
- :func:`performance_profile_ci_per_task` and :func:`probability_of_improvement_ci_per_task`: the
  same for tasks with different numbers of runs (one array per task).
- :func:`summarise` and :func:`format_ci` for tables.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Iterator, Mapping
from numbers import Integral
from typing import Any, NamedTuple

import numpy as np

__all__ = [
    "Interval",
    "format_ci",
    "iqm",
    "mean",
    "median",
    "performance_profile",
    "performance_profile_ci",
    "performance_profile_ci_per_task",
    "probability_of_improvement",
    "probability_of_improvement_ci",
    "probability_of_improvement_ci_per_task",
    "stratified_bootstrap_ci",
    "stratified_bootstrap_samples",
    "summarise",
]

#: An aggregate maps a ``[run, task]`` score array to one number.
Aggregate = Callable[[np.ndarray], float]
#: Where bootstrap randomness comes from: a generator (advanced in place) or an integer seed.
RngLike = np.random.Generator | int

#: Bootstrap replicates are drawn in chunks of at most this many scores (about 32 MB of float64).
_MAX_CHUNK_ELEMENTS = 1 << 22


class Interval(NamedTuple):
    """A point estimate and its confidence interval; unpacks as ``point, low, high``."""

    point: float
    low: float
    high: float


# --------------------------------------------------------------------------- validation


def _as_scores(scores: Any, name: str = "scores") -> np.ndarray:
    """``scores`` as a finite, non-empty float64 ``[run, task]`` array (1-D = one task)."""
    try:
        arr = np.asarray(scores, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric [run, task] array: {exc}") from exc
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a 1-D (runs of one task) or 2-D [run, task] array, got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError(f"{name} is empty (shape {arr.shape}): need at least one run and one task")
    if np.isnan(arr).any():
        run, task = np.argwhere(np.isnan(arr))[0]
        raise ValueError(f"{name} contains NaN (first at run {run}, task {task})")
    if not np.isfinite(arr).all():
        run, task = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{name} contains an infinite value (first at run {run}, task {task})")
    return arr


def _as_generator(rng: RngLike) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, Integral) and not isinstance(rng, bool):
        return np.random.default_rng(int(rng))
    raise TypeError(f"rng must be a numpy Generator or an integer seed, got {type(rng).__name__}")


def _check_reps(reps: int) -> None:
    if not isinstance(reps, Integral) or isinstance(reps, bool) or reps < 1:
        raise ValueError(f"reps must be a positive integer, got {reps!r}")


def _check_bootstrap_args(reps: int, confidence: float) -> None:
    _check_reps(reps)
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie strictly between 0 and 1, got {confidence!r}")


# --------------------------------------------------------------------------- aggregates
# Each aggregate has a batched form over replicates, shape [replicate, run, task] -> [replicate].


def _iqm_batch(batch: np.ndarray) -> np.ndarray:
    flat = np.sort(batch.reshape(batch.shape[0], -1), axis=1)
    n = flat.shape[1]
    cut = n // 4  # == int(0.25 * n), scipy.stats.trim_mean's cut, for every n >= 0
    return flat[:, cut : n - cut].mean(axis=1)


def _mean_batch(batch: np.ndarray) -> np.ndarray:
    return batch.reshape(batch.shape[0], -1).mean(axis=1)


def _median_batch(batch: np.ndarray) -> np.ndarray:
    return np.median(batch.reshape(batch.shape[0], -1), axis=1)


def iqm(scores: Any) -> float:
    """Interquartile mean of all run × task scores pooled: the mean of the middle 50 %.

    Matches ``scipy.stats.trim_mean(scores, 0.25, axis=None)`` (rliable's ``aggregate_iqm``):
    of the ``n`` pooled scores, sorted, ``int(0.25 * n)`` = ``n // 4`` are cut from *each* end and
    the rest averaged. Nothing is interpolated when ``n`` is not a multiple of 4, so slightly more
    than half the scores are kept: n = 8 keeps the middle 4, n = 10 cuts 2 per end and keeps 6,
    n = 5 keeps 3, and n <= 3 cuts nothing (the plain mean).
    """
    return float(_iqm_batch(_as_scores(scores)[None])[0])


def mean(scores: Any) -> float:
    """Mean of all run × task scores (= the mean of the per-task means: runs per task are equal)."""
    return float(_mean_batch(_as_scores(scores)[None])[0])


def median(scores: Any) -> float:
    """Median of all run × task scores pooled (not rliable's median of per-task means)."""
    return float(_median_batch(_as_scores(scores)[None])[0])


_BATCHED: dict[Callable[..., float], Callable[[np.ndarray], np.ndarray]] = {
    iqm: _iqm_batch,
    mean: _mean_batch,
    median: _median_batch,
}


def _apply_batch(aggregate: Aggregate, batch: np.ndarray) -> np.ndarray:
    batched = _BATCHED.get(aggregate)
    if batched is not None:
        return batched(batch)
    return np.array([float(aggregate(replicate)) for replicate in batch], dtype=np.float64)


# --------------------------------------------------------------------------- bootstrap


def _chunk_sizes(reps: int, elements_per_rep: int) -> Iterator[int]:
    per_chunk = max(1, _MAX_CHUNK_ELEMENTS // max(1, elements_per_rep))
    for start in range(0, reps, per_chunk):
        yield min(per_chunk, reps - start)


def _resample(scores: np.ndarray, size: int, rng: np.random.Generator) -> np.ndarray:
    """``size`` stratified replicates of a validated ``[run, task]`` array.

    Replicate ``b`` holds, in column ``t``, ``n_runs`` runs of task ``t`` drawn with replacement,
    independently of the other tasks: ``out[b, r, t] = scores[idx[b, r, t], t]``.
    """
    n_runs, n_tasks = scores.shape
    idx = rng.integers(0, n_runs, size=(size, n_runs, n_tasks))
    return scores[idx, np.arange(n_tasks)]


def stratified_bootstrap_samples(scores: Any, reps: int, rng: RngLike = 0) -> np.ndarray:
    """The bootstrap replicates used by :func:`stratified_bootstrap_ci`, shape ``[reps, run, task]``.

    Runs are resampled with replacement within each task (stratified by task) and independently
    across tasks; a replicate never moves a score to another task. With the same ``rng`` this
    returns exactly the replicates :func:`stratified_bootstrap_ci` aggregates.
    """
    arr = _as_scores(scores)
    _check_reps(reps)
    gen = _as_generator(rng)
    return np.concatenate([_resample(arr, size, gen) for size in _chunk_sizes(reps, arr.size)])


def _percentile_interval(point: float, replicates: np.ndarray, confidence: float) -> Interval:
    alpha = 1.0 - confidence
    low, high = np.percentile(replicates, [100.0 * alpha / 2.0, 100.0 * (1.0 - alpha / 2.0)])
    return Interval(float(point), float(low), float(high))


def stratified_bootstrap_ci(
    scores: Any,
    aggregate: Aggregate = iqm,
    reps: int = 2000,
    confidence: float = 0.95,
    rng: RngLike = 0,
) -> Interval:
    """``(point, low, high)``: ``aggregate(scores)`` and its stratified percentile bootstrap CI.

    ``reps`` replicates are drawn as in :func:`stratified_bootstrap_samples`, the aggregate is
    applied to each, and ``low``/``high`` are the ``(1 - confidence) / 2`` and
    ``(1 + confidence) / 2`` percentiles of those values (linear interpolation, as
    ``np.percentile``). ``aggregate`` is any ``[run, task] -> float`` function; :func:`iqm`,
    :func:`mean` and :func:`median` run vectorised over replicates.

    ``rng`` is a generator (advanced in place) or an integer seed; the default seed 0 makes the same
    scores always print the same interval. A percentile interval need not contain the point
    estimate (it can miss it for tiny or very skewed samples); with a few runs per task it is also
    too narrow, since a bootstrap cannot see values the runs never produced.
    """
    arr = _as_scores(scores)
    _check_bootstrap_args(reps, confidence)
    gen = _as_generator(rng)
    point = float(aggregate(arr))
    values = np.concatenate(
        [_apply_batch(aggregate, _resample(arr, size, gen)) for size in _chunk_sizes(reps, arr.size)]
    )
    return _percentile_interval(point, values, confidence)


# --------------------------------------------------------------------------- probability of improvement


def _pair(x: Any, y: Any) -> tuple[np.ndarray, np.ndarray]:
    xa, ya = _as_scores(x, "x"), _as_scores(y, "y")
    if xa.shape[1] != ya.shape[1]:
        raise ValueError(
            f"x and y must be scored on the same tasks: x has {xa.shape[1]} task(s), y has {ya.shape[1]}"
        )
    return xa, ya


def _poi_batch(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """P(X > Y) for batches ``x[b, n, task]``, ``y[b, m, task]``, averaged over tasks -> ``[b]``."""
    xs, ys = x[:, :, None, :], y[:, None, :, :]
    per_task = (xs > ys).mean(axis=(1, 2)) + 0.5 * (xs == ys).mean(axis=(1, 2))
    return per_task.mean(axis=1)


def probability_of_improvement(x: Any, y: Any) -> float:
    """P(X > Y): the probability that a run of method X beats a run of method Y on a random task.

    For each task, with runs ``x_1..x_N`` and ``y_1..y_M`` (``N`` and ``M`` may differ), this is
    the normalised Mann-Whitney U statistic ``(1 / (N M)) sum_i sum_j S(x_i, y_j)`` with
    ``S = 1`` if ``x_i > y_j``, ``0.5`` on a tie and ``0`` otherwise; the result is the mean over
    tasks. 0.5 means neither is better; ``P(X > Y) + P(Y > X) = 1``. x and y need the same number
    of tasks (in the same order).
    """
    xa, ya = _pair(x, y)
    return float(_poi_batch(xa[None], ya[None])[0])


def probability_of_improvement_ci(
    x: Any,
    y: Any,
    reps: int = 2000,
    confidence: float = 0.95,
    rng: RngLike = 0,
) -> Interval:
    """``(point, low, high)`` for :func:`probability_of_improvement`.

    Each replicate resamples the runs of x and, independently, the runs of y, both stratified by
    task (rliable's ``StratifiedIndependentBootstrap``), and the interval is the percentile
    interval of P(X > Y) over replicates.
    """
    xa, ya = _pair(x, y)
    _check_bootstrap_args(reps, confidence)
    gen = _as_generator(rng)
    point = float(_poi_batch(xa[None], ya[None])[0])
    per_rep = xa.shape[0] * ya.shape[0] * xa.shape[1] + xa.size + ya.size
    values = np.concatenate(
        [_poi_batch(_resample(xa, size, gen), _resample(ya, size, gen)) for size in _chunk_sizes(reps, per_rep)]
    )
    return _percentile_interval(point, values, confidence)


# --------------------------------------------------------------------------- performance profiles


def _profile_batch(batch: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """The share of runs above each τ, averaged over tasks, for replicates ``[b, run, task]`` -> ``[b, τ]``."""
    return (batch[:, :, :, None] > taus).mean(axis=1).mean(axis=1)


def performance_profile(scores: Any, taus: Any) -> np.ndarray:
    """rliable's performance profile (run-score distribution): for each threshold τ, the share of
    runs whose score exceeds τ, on each task, averaged over tasks (every task weighs the same,
    whatever its number of runs)."""
    arr, grid = _as_scores(scores), np.asarray(taus, dtype=np.float64).reshape(-1)
    return _profile_batch(arr[None], grid)[0]


def performance_profile_ci(scores: Any, taus: Any, reps: int = 2000, confidence: float = 0.95,
                           rng: RngLike = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(point, low, high)`` arrays over ``taus`` for :func:`performance_profile`, from stratified
    bootstrap replicates (runs resampled within each task) and percentile intervals."""
    arr, grid = _as_scores(scores), np.asarray(taus, dtype=np.float64).reshape(-1)
    _check_bootstrap_args(reps, confidence)
    gen = _as_generator(rng)
    values = np.concatenate([_profile_batch(_resample(arr, size, gen), grid)
                             for size in _chunk_sizes(reps, arr.size * grid.size)])
    alpha = 1.0 - confidence
    low, high = np.percentile(values, [100.0 * alpha / 2.0, 100.0 * (1.0 - alpha / 2.0)], axis=0)
    return _profile_batch(arr[None], grid)[0], low, high


# --------------------------------------------------------------------------- tasks with different run counts


def _tasks(tasks: Any, name: str) -> list[np.ndarray]:
    arrays = [_as_scores(t, f"{name}[{k}]") for k, t in enumerate(tasks)]
    if not arrays:
        raise ValueError(f"{name} holds no task")
    if any(a.shape[1] != 1 for a in arrays):
        raise ValueError(f"{name}: each task is a 1-D array of its runs' scores")
    return arrays


def _per_task_interval(points: list[np.ndarray], replicates: list[np.ndarray], confidence: float):
    values = np.mean(replicates, axis=0)
    alpha = 1.0 - confidence
    low, high = np.percentile(values, [100.0 * alpha / 2.0, 100.0 * (1.0 - alpha / 2.0)], axis=0)
    return np.mean(points, axis=0), low, high


def performance_profile_ci_per_task(tasks: Any, taus: Any, reps: int = 2000, confidence: float = 0.95,
                                    rng: RngLike = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`performance_profile_ci` for tasks with different numbers of runs: ``tasks`` is one 1-D
    array of run scores per task. Each replicate resamples every task's runs (stratified, as there)
    and averages the tasks' profiles; with equal run counts the point is :func:`performance_profile`'s."""
    arrays, grid = _tasks(tasks, "tasks"), np.asarray(taus, dtype=np.float64).reshape(-1)
    _check_bootstrap_args(reps, confidence)
    gen = _as_generator(rng)
    points = [_profile_batch(a[None], grid)[0] for a in arrays]
    replicates = [np.concatenate([_profile_batch(_resample(a, size, gen), grid)
                                  for size in _chunk_sizes(reps, a.size * grid.size)]) for a in arrays]
    return _per_task_interval(points, replicates, confidence)


def probability_of_improvement_ci_per_task(x_tasks: Any, y_tasks: Any, reps: int = 2000, confidence: float = 0.95,
                                           rng: RngLike = 0) -> Interval:
    """:func:`probability_of_improvement_ci` for tasks with different numbers of runs (per task and
    per method): ``x_tasks`` and ``y_tasks`` hold one 1-D array of run scores per task, the same
    tasks in the same order."""
    xs, ys = _tasks(x_tasks, "x_tasks"), _tasks(y_tasks, "y_tasks")
    if len(xs) != len(ys):
        raise ValueError(f"x and y must be scored on the same tasks: x has {len(xs)} task(s), y has {len(ys)}")
    _check_bootstrap_args(reps, confidence)
    gen = _as_generator(rng)
    points = [_poi_batch(x[None], y[None])[0] for x, y in zip(xs, ys)]
    replicates = []
    for x, y in zip(xs, ys):
        per_rep = x.shape[0] * y.shape[0] + x.size + y.size
        replicates.append(np.concatenate([_poi_batch(_resample(x, size, gen), _resample(y, size, gen))
                                          for size in _chunk_sizes(reps, per_rep)]))
    point, low, high = _per_task_interval(points, replicates, confidence)
    return Interval(float(point), float(low), float(high))


# --------------------------------------------------------------------------- tables


def summarise(
    scores_by_method: Mapping[str, Any],
    reps: int = 2000,
    rng: RngLike = 0,
    confidence: float = 0.95,
) -> dict[str, dict[str, Any]]:
    """Per method: ``n_runs``, ``n_tasks``, ``iqm`` and ``mean`` as :class:`Interval`, ``median``.

    Each method's intervals come from its own random stream, derived from ``rng`` and the method
    name, so a method's interval does not change when other methods are added or reordered; its
    IQM and mean intervals are computed on the same replicates.
    """
    if not scores_by_method:
        raise ValueError("scores_by_method is empty: nothing to summarise")
    _check_bootstrap_args(reps, confidence)
    gen = _as_generator(rng)
    base = int(gen.integers(0, 2**63)) if isinstance(rng, np.random.Generator) else int(rng)
    out: dict[str, dict[str, Any]] = {}
    for method, scores in scores_by_method.items():
        arr = _as_scores(scores, f"scores of {method!r}")
        stream = np.random.SeedSequence(base, spawn_key=(zlib.crc32(str(method).encode("utf-8")),))
        out[method] = {
            "n_runs": int(arr.shape[0]),
            "n_tasks": int(arr.shape[1]),
            "iqm": stratified_bootstrap_ci(arr, iqm, reps, confidence, np.random.default_rng(stream)),
            "mean": stratified_bootstrap_ci(arr, mean, reps, confidence, np.random.default_rng(stream)),
            "median": median(arr),
        }
    return out


def format_ci(interval: tuple[float, float, float], digits: int = 1) -> str:
    """``"12.3 [10.1, 14.0]"`` for ``(point, low, high)``."""
    point, low, high = interval
    return f"{point:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]"
