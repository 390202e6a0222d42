"""Figures over seeds and rows, as rliable and marl-eval draw them, from a published folder's files.

==========================================  ======================================================
function                                    figure
==========================================  ======================================================
:func:`plot_sample_efficiency`              one row: each learned method's IQM over seeds of the
                                            validation return against training samples, with its
                                            95 % bootstrap band (the runs' ``curve.json``)
:func:`plot_performance_profiles`           every row: the share of runs whose test return, as a
                                            share of a reference method's on the same row, exceeds
                                            τ, with 95 % bands (each row weighs the same)
:func:`plot_probability_of_improvement`     P(X > Y) with its 95 % interval for pairs of methods
==========================================  ======================================================

Each writes ``<stem>.png`` and ``<stem>.svg`` (as :mod:`containergym_marl.evaluation.plots` does) and
returns the Figure. :func:`draw_aggregate_figures` draws all of them for a published folder.
Bootstrap intervals are seeded by what they are about, so redrawing gives the same files.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from containergym_marl.evaluation.curves import BUDGET_FRACTIONS, iqm_curve, read_curve
from containergym_marl.evaluation.plots import FORMATS, _gid, _save
from containergym_marl.evaluation.stats import performance_profile_ci_per_task, probability_of_improvement_ci_per_task

#: The method every row's returns are divided by in the performance profiles: the rule-based
#: container agents (no training, no seeds, on every row).
PROFILE_REFERENCE = "rule_based_agents"
#: Thresholds τ of the performance profiles (share of the reference's return).
PROFILE_TAUS = np.round(np.linspace(0.0, 1.2, 121), 3)


def _seed(*names: str) -> np.random.Generator:
    from containergym_marl.evaluation.table import bootstrap_rng

    return bootstrap_rng("figure", *names)


def plot_sample_efficiency(curves_by_method: Mapping[str, Sequence[dict]], path: str | Path, *, config: str = "",
                           reps: int = 2000, formats: Sequence[str] = FORMATS) -> Figure:
    """Each method's IQM over its runs' validation returns at each tenth of the budget, against
    training samples, with the 95 % stratified-bootstrap band (gid ``iqm-<method>``,
    ``band-<method>``). ``curves_by_method``: the ``curve.json`` contents of each method's runs."""
    fig = Figure(figsize=(6.4, 4.0), layout="constrained")
    ax = fig.add_subplot()
    for method, curves in curves_by_method.items():
        if not curves:
            continue
        budgets = {c["budget"] for c in curves}
        if len(budgets) != 1:
            raise ValueError(f"{method}: runs with different budgets {sorted(budgets)} cannot share one curve")
        agg = iqm_curve(list(curves), reps=reps, rng=_seed("curve", config, method))
        x = np.array(agg["fractions"]) * budgets.pop()
        line, = ax.plot(x, agg["iqm"], marker="o", ms=3, label=f"{method} ({agg['runs']} runs)",
                        gid=_gid("iqm", method))
        ax.fill_between(x, agg["low"], agg["high"], color=line.get_color(), alpha=0.2, lw=0, gid=_gid("band", method))
    ax.set_xlabel("training samples")
    ax.set_ylabel("validation return (IQM over seeds)")
    ax.set_title(f"Sample efficiency{f' on {config}' if config else ''} (95 % bootstrap bands)", fontsize=10)
    ax.grid(alpha=0.3)
    if ax.lines:
        ax.legend(fontsize=8)
    return _save(fig, path, formats)


def normalised_scores(seed_means: Mapping[str, Mapping[str, Sequence[float]]],
                      reference: Mapping[str, float]) -> dict[str, dict[str, np.ndarray]]:
    """Per method, per row, its runs' mean returns divided by the reference's return on that row;
    only the methods found on every row of the reference (a profile over fewer rows would not
    compare). ``seed_means``: by method, by row, the runs' mean returns."""
    return {method: {r: np.asarray(by_row[r], dtype=float) / reference[r] for r in reference}
            for method, by_row in seed_means.items() if reference and all(r in by_row for r in reference)}


def plot_performance_profiles(scores: Mapping[str, Mapping[str, np.ndarray]], path: str | Path, *,
                              reference: str = PROFILE_REFERENCE, taus: np.ndarray = PROFILE_TAUS, reps: int = 2000,
                              formats: Sequence[str] = FORMATS) -> Figure:
    """For each method, the share of its runs whose score exceeds τ, averaged over rows (each row
    weighs the same, whatever its number of runs), with its 95 % band (gid ``profile-<method>``).
    ``scores``: by method, by row, the runs' scores (:func:`normalised_scores`)."""
    fig = Figure(figsize=(6.4, 4.0), layout="constrained")
    ax = fig.add_subplot()
    for method, by_row in scores.items():
        if not by_row:
            continue
        runs = sorted({len(v) for v in by_row.values()})
        point, low, high = performance_profile_ci_per_task(list(by_row.values()), taus, reps=reps,
                                                           rng=_seed("profile", method))
        count = f"{runs[0]}" if len(runs) == 1 else f"{runs[0]}–{runs[-1]}"
        line, = ax.plot(taus, point, label=f"{method} ({len(by_row)} rows × {count} runs)",
                        gid=_gid("profile", method))
        ax.fill_between(taus, low, high, color=line.get_color(), alpha=0.15, lw=0)
    ax.axvline(1.0, color="0.5", lw=0.8, ls=":")
    ax.set_xlabel(f"test return as a share of {reference}'s on the same row (τ)")
    ax.set_ylabel("share of runs with score > τ")
    ax.set_ylim(0, 1.02)
    ax.set_title("Performance profiles over rows (95 % bootstrap bands)", fontsize=10)
    ax.grid(alpha=0.3)
    if ax.lines:
        ax.legend(fontsize=7, loc="lower left")
    return _save(fig, path, formats)


def plot_probability_of_improvement(pairs: Sequence[tuple[str, Sequence[np.ndarray], str, Sequence[np.ndarray]]],
                                    path: str | Path, *, reps: int = 2000, formats: Sequence[str] = FORMATS) -> Figure:
    """P(X > Y) over rows with its 95 % interval, one line per ``(x_name, x_rows, y_name, y_rows)``
    (one array of run scores per row, the same rows for x and y), as rliable draws it (gid ``poi-<x>-<y>``)."""
    fig = Figure(figsize=(6.4, 0.9 + 0.4 * max(len(pairs), 1)), layout="constrained")
    ax = fig.add_subplot()
    labels = []
    for k, (x_name, x, y_name, y) in enumerate(pairs):
        p, low, high = probability_of_improvement_ci_per_task(x, y, reps=reps, rng=_seed("poi", x_name, y_name))
        ax.errorbar([p], [k], xerr=[[p - low], [high - p]], fmt="o", capsize=3, gid=_gid("poi", x_name, y_name))
        labels.append(f"P({x_name} > {y_name}), {len(x)} rows")
    ax.set_yticks(range(len(labels)), labels, fontsize=8)
    ax.axvline(0.5, color="0.5", lw=0.8, ls=":")
    ax.set_xlim(0, 1)
    ax.set_xlabel("P(X > Y) [95 % bootstrap CI]")
    ax.invert_yaxis()
    ax.grid(alpha=0.3, axis="x")
    return _save(fig, path, formats)


def _curves(folder: Path, groups) -> dict[str, dict[str, list[dict]]]:
    """The published runs' curves (``runs/<run>/curve.json``), by row, by method: a method's runs on a
    row only where every one of them has its curve."""
    from containergym_marl.rundir import run_name

    out: dict[str, dict[str, list[dict]]] = {}
    for g in groups:
        curves = [read_curve(folder / "runs" / run_name(g.method, g.config, seed)) for seed in g.seeds]
        if curves and all(c is not None for c in curves):
            out.setdefault(g.config, {})[g.method] = curves
    return out


def draw_aggregate_figures(folder: str | Path, out: str | Path | None = None, *, reps: int = 2000,
                           pairs: Sequence[tuple[str, str]] = (), formats: Sequence[str] = FORMATS) -> list[Path]:
    """Every aggregate figure of a published folder into ``out`` (default ``<folder>/figures``):
    ``sample_efficiency_<row>`` for each row with curves, ``performance_profiles`` and, for
    ``pairs`` of methods found on the same rows, ``probability_of_improvement``. Returns the files."""
    from containergym_marl.evaluation.plots import figure_paths
    from containergym_marl.evaluation.table import load_evaluations

    folder = Path(folder)
    out = Path(out) if out is not None else folder / "figures"
    written: list[Path] = []
    groups = load_evaluations(folder)
    for config, by_method in sorted(_curves(folder, groups).items()):
        stem = out / f"sample_efficiency_{config}"
        plot_sample_efficiency(by_method, stem, config=config, reps=reps, formats=formats)
        written += figure_paths(stem, formats)
    reference = {g.config: float(g.seed_means.mean()) for g in groups if g.method == PROFILE_REFERENCE}
    seed_means: dict[str, dict[str, list[float]]] = {}
    for g in groups:
        if g.seeds:
            seed_means.setdefault(g.method, {})[g.config] = g.seed_means.tolist()
    scores = normalised_scores(seed_means, reference)
    if scores:
        stem = out / "performance_profiles"
        plot_performance_profiles(scores, stem, reps=reps, formats=formats)
        written += figure_paths(stem, formats)
    shared = []
    for x, y in pairs:
        rows = [r for r in seed_means.get(x, {}) if r in seed_means.get(y, {})]
        if rows:
            shared.append((x, [seed_means[x][r] for r in rows], y, [seed_means[y][r] for r in rows]))
    if shared:
        stem = out / "probability_of_improvement"
        plot_probability_of_improvement(shared, stem, reps=reps, formats=formats)
        written += figure_paths(stem, formats)
    return written


__all__ = ["BUDGET_FRACTIONS", "PROFILE_REFERENCE", "draw_aggregate_figures", "normalised_scores",
           "plot_performance_profiles", "plot_probability_of_improvement", "plot_sample_efficiency"]
