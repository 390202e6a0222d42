"""The paper's figures (and a PU timeline) from episode records, as PNG and SVG.

Every function takes :class:`~containergym_marl.evaluation.records.EpisodeRecord` objects (or, for
the reward curve, a config and a container) and an output path *stem*, writes ``<stem>.png`` and
``<stem>.svg`` (a ``.png`` or ``.svg`` suffix on ``path`` is dropped; parent folders are made) and
**returns the matplotlib Figure**, so callers and tests can inspect what was drawn.
:func:`figure_paths` gives the written paths.

==================================  ===========================================================
function                            figure
==================================  ===========================================================
:func:`plot_reward_function`        paper Fig. 1: emptying reward of one container over [0, v_max)
:func:`plot_episode`                paper Fig. 2: volumes with v_max and targets, emptyings,
                                    denied requests, and the non-zero rewards of one episode
:func:`plot_emptying_volume_ecdfs`  paper Fig. 3: ECDF of emptying volumes, one panel per
                                    container, one line per method, optima marked
:func:`plot_reward_ecdf`            paper Fig. 4: ECDF of the reward per emptying action,
                                    one line per method
:func:`plot_pu_timeline`            which container each PU served, and the denied requests
==================================  ===========================================================

The figures use the object-oriented API on Agg canvases (``matplotlib.figure.Figure``), never
pyplot, so they work headless and leave no global state behind. Optima, v_max, r_pen and fill
rates come from the plant config: pass ``config=`` (a :class:`~containergym_marl.config.PlantConfig`
or a name/path) or let it be loaded by the records' ``config_name`` (built-in configs).

Artists carry SVG ids (``gid``) naming what they show (``volume-C1-20``, ``emptied-C1-20``,
``ecdf-C1-20-PPO``, ``pu-0``…), so the SVG files can be checked and post-processed by content.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib import rc_context
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from containergym_marl.config import PlantConfig, load_config
from containergym_marl.core.dynamics import emptying_rewards
from containergym_marl.core.params import PlantParams
from containergym_marl.evaluation.records import EpisodeRecord
from containergym_marl.evaluation.metrics import GOOD_REWARD
from containergym_marl.render import container_colors

__all__ = [
    "FORMATS",
    "ecdf_points",
    "figure_paths",
    "plot_emptying_volume_ecdfs",
    "plot_episode",
    "plot_pu_timeline",
    "plot_reward_ecdf",
    "plot_reward_function",
]

#: Formats written by default.
FORMATS = ("png", "svg")
PNG_DPI = 150


# ---- helpers ---------------------------------------------------------------------------------
def figure_paths(path: str | Path, formats: Sequence[str] = FORMATS) -> list[Path]:
    """The files a plot function writes for ``path``: ``<stem>.<format>`` for each format."""
    p = Path(path)
    if p.suffix.lower() in {f".{f}" for f in ("png", "svg", "pdf")}:
        p = p.with_suffix("")
    return [p.with_name(f"{p.name}.{fmt}") for fmt in formats]


def _save(fig: Figure, path: str | Path, formats: Sequence[str]) -> Figure:
    """Write the figure in each format, each file crash-safe (a reader never sees a part)."""
    from containergym_marl.files import atomic_write

    for out in figure_paths(path, formats):
        fmt = out.suffix[1:].lower()
        # No creation date and fixed internal ids in vector files: the same data give
        # byte-identical files (figures can be versioned and diffed).
        meta = {"Date": None} if fmt in ("svg", "pdf") else None
        with rc_context({"svg.hashsalt": "containergym-marl"}):
            atomic_write(out, lambda tmp, fmt=fmt, meta=meta: fig.savefig(tmp, format=fmt, dpi=PNG_DPI, metadata=meta))
    return fig


def _gid(*parts) -> str:
    """An SVG id from names (anything but letters, digits, '_', '.', '-' becomes '_')."""
    return re.sub(r"[^A-Za-z0-9_.-]", "_", "-".join(str(p) for p in parts))


def _resolve_config(config: str | PlantConfig | None, records: Sequence[EpisodeRecord]) -> PlantConfig:
    if isinstance(config, PlantConfig):
        return config
    name = config if config is not None else records[0].config_name
    try:
        return load_config(name)
    except Exception as exc:  # a record of a custom config that is not a built-in name
        raise ValueError(
            f"config: cannot load {name!r} ({exc}); pass the PlantConfig as config="
        ) from exc


def _check_names(cfg: PlantConfig, record: EpisodeRecord) -> None:
    if tuple(record.container_names) != cfg.container_names:
        raise ValueError(
            f"config {cfg.name!r} has containers {list(cfg.container_names)}, but the record "
            f"({record.config_name}, {record.policy}) has {list(record.container_names)}"
        )


def _as_record_lists(records_by_method) -> dict[str, list[EpisodeRecord]]:
    if not isinstance(records_by_method, Mapping) or not records_by_method:
        raise ValueError("records_by_method: expected a non-empty dict {method name: [EpisodeRecord, ...]}")
    out = {}
    for method, recs in records_by_method.items():
        recs = [recs] if isinstance(recs, EpisodeRecord) else list(recs)
        if not recs:
            raise ValueError(f"records_by_method[{method!r}]: no records")
        out[str(method)] = recs
    return out


def ecdf_points(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices of the ECDF step line of ``values`` (drawn with ``drawstyle="steps-post"``).

    For k values: k + 1 points, ``(x_(1), 0)`` then ``(x_(i), i / k)`` for the sorted values; for
    no values, two empty arrays.
    """
    x = np.sort(np.asarray(values, dtype=np.float64).ravel())
    if x.size == 0:
        return x, x.copy()
    return np.concatenate([x[:1], x]), np.arange(x.size + 1) / x.size


def _step_axis(ax, timestep_s: float, top_ax=None) -> None:
    """x in steps on ``ax``; the elapsed time in hours on a secondary axis at the top of
    ``top_ax`` (default ``ax``)."""
    ax.set_xlabel(f"step (δ = {timestep_s:g} s)")
    hours = 3600.0 / timestep_s
    sec = (top_ax or ax).secondary_xaxis("top", functions=(lambda s: s / hours, lambda h: h * hours))
    sec.set_xlabel("time (h)")


# ---- Fig. 1: reward function -----------------------------------------------------------------
def plot_reward_function(config: str | PlantConfig, container: str | int, path: str | Path, *,
                         num_points: int = 2000, formats: Sequence[str] = FORMATS) -> Figure:
    """The emptying reward of one container over volumes in [0, v_max) (paper Fig. 1).

    ``container`` is a name or an index into ``config.containers``. The curve is the core's
    reward ``r_pen + Σ_k (h_k − r_pen)·exp(−(v − v*_k)² / (2 w_k²))`` (``r_pen`` at v = 0), on
    ``num_points`` evenly spaced volumes plus 101 points around every peak (narrow peaks stay
    resolved). A dashed black line marks the global optimum (gid ``optimum-<k>``), dotted grey
    lines the local optima (``local-optimum-<k>``), each labelled with v* and h; a red line r_pen.
    One axis; the curve has gid ``reward``.
    """
    cfg = config if isinstance(config, PlantConfig) else load_config(config)
    if isinstance(container, str):
        if container not in cfg.container_names:
            raise ValueError(f"container: {container!r} not in {list(cfg.container_names)}")
        i = cfg.container_names.index(container)
    else:
        i = int(container)
        if not 0 <= i < cfg.n_containers:
            raise ValueError(f"container: index {i} out of range [0, {cfg.n_containers - 1}]")
    spec = cfg.containers[i]
    vmax = spec.max_volume
    pieces = [np.linspace(0.0, vmax, int(num_points), endpoint=False)]
    pieces += [np.linspace(p - 5 * w, p + 5 * w, 101) for p, w in zip(spec.reward_peaks, spec.reward_widths)]
    x = np.unique(np.concatenate(pieces))
    x = x[(x >= 0.0) & (x < vmax)]
    vols = np.zeros((x.size, cfg.n_containers))
    vols[:, i] = x
    y = emptying_rewards(vols, PlantParams.from_config(cfg))[:, i]

    fig = Figure(figsize=(6.4, 3.8), layout="constrained")
    ax = fig.add_subplot()
    ax.plot(x, y, color="tab:blue", lw=1.8, label="emptying reward", gid="reward")
    order = sorted(range(len(spec.reward_peaks)), key=lambda k: -spec.reward_heights[k])
    for rank, k in enumerate(order):
        peak, h = spec.reward_peaks[k], spec.reward_heights[k]
        is_global = peak == spec.target_volume
        ax.axvline(peak, color="black" if is_global else "0.5", ls="--" if is_global else ":", lw=1,
                   label=("global optimum" if is_global else ("local optima" if rank == 1 else None)),
                   gid=_gid("optimum" if is_global else "local-optimum", k))
        ax.annotate(f"v* = {peak:g}, h = {h:g}", (peak, h), xytext=(0, 4), textcoords="offset points",
                    fontsize=7, va="bottom", ha="center",
                    bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.85})
    ax.axhline(cfg.penalty_reward, color="tab:red", lw=0.8, alpha=0.7,
               label=f"r_pen = {cfg.penalty_reward:g}", gid="r_pen")
    ax.set_xlim(0, vmax)
    ax.set_ylim(min(cfg.penalty_reward, 0.0) - 0.05, 1.12)
    ax.set_xlabel("volume at emptying (volume units)")
    ax.set_ylabel("reward")
    ax.set_title(f"Emptying reward of {spec.name} ({cfg.name}), v ∈ [0, {vmax:g})")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    return _save(fig, path, formats)


# ---- Fig. 2: one episode ---------------------------------------------------------------------
def plot_episode(record: EpisodeRecord, path: str | Path, *, config: str | PlantConfig | None = None,
                 formats: Sequence[str] = FORMATS) -> Figure:
    """Volumes, emptying actions, denied requests and rewards of one episode (paper Fig. 2).

    Two axes sharing the step axis. Top: one volume line per container (``record.volumes[:, i]``
    over steps 0..T, gid ``volume-<name>``), its global optimum as a dashed line of the same
    colour (``target-<name>``), v_max, a filled circle at (t, v_i(t)) for every emptying
    (``emptied-<name>``, one marker per granted request), a cross for every denied request
    (``denied-<name>``: another container took the last free PU in the decentralised view, no
    free PU for the centralised controller) and a star at an overflow. Bottom: the non-zero
    rewards: of every emptying (``reward-<name>``, circles), of every denied request (r_pen,
    ``reward-denied-<name>``, crosses) and the overflow reward r_min (``reward-overflow``, star,
    which replaced the plant reward of the last step).
    """
    cfg = _resolve_config(config, [record])
    _check_names(cfg, record)
    n, T = cfg.n_containers, record.steps
    colors = container_colors(n)
    steps = np.arange(T + 1)

    fig = Figure(figsize=(11, 6.8), layout="constrained")
    ax, rax = fig.subplots(2, 1, sharex=True, height_ratios=(3.0, 1.3))
    vmaxes = [c.max_volume for c in cfg.containers]
    for i, spec in enumerate(cfg.containers):
        c = colors[i]
        ax.plot(steps, record.volumes[:, i], color=c, lw=1.1, label=spec.name, gid=_gid("volume", spec.name))
        ax.axhline(spec.target_volume, color=c, ls="--", lw=0.8, alpha=0.8, gid=_gid("target", spec.name))
        t_e = np.flatnonzero(record.granted[:, i])
        ax.plot(t_e, record.volumes[t_e, i], ls="", marker="o", ms=5, mfc=c, mec="black", mew=0.6,
                gid=_gid("emptied", spec.name))
        t_d = np.flatnonzero(record.denied[:, i])
        ax.plot(t_d, record.volumes[t_d, i], ls="", marker="x", ms=6, mew=1.5, color=c,
                gid=_gid("denied", spec.name))
        if len(set(vmaxes)) > 1:
            ax.axhline(spec.max_volume, color=c, ls=":", lw=1.0, gid=_gid("vmax", spec.name))
    if len(set(vmaxes)) == 1:
        ax.axhline(vmaxes[0], color="black", lw=1.2, gid="vmax")
    over = np.flatnonzero(record.volumes[-1] >= np.array(vmaxes)) if record.terminated else np.zeros(0, int)
    ax.plot(np.full(over.size, T), record.volumes[-1, over], ls="", marker="*", ms=14, color="tab:red",
            mec="black", gid="overflow")
    ax.set_ylabel("volume (volume units)")
    ax.set_ylim(0, max(max(vmaxes), float(record.volumes.max(initial=0.0))) * 1.05)
    ax.grid(alpha=0.25)

    for i, spec in enumerate(cfg.containers):
        t_e = np.flatnonzero(record.granted[:, i])
        rax.plot(t_e, record.container_reward[t_e, i], ls="", marker="o", ms=4, color=colors[i],
                 gid=_gid("reward", spec.name))
        t_d = np.flatnonzero(record.denied[:, i])
        rax.plot(t_d, record.container_reward[t_d, i], ls="", marker="x", ms=6, mew=1.5, color=colors[i],
                 gid=_gid("reward-denied", spec.name))
    if record.terminated and T > 0:
        rax.plot([T - 1], [record.plant_reward[-1]], ls="", marker="*", ms=12, color="tab:red", mec="black",
                 gid="reward-overflow")
    rax.axhline(0.0, color="0.4", lw=0.8)
    rax.set_ylabel("reward")
    rax.set_ylim(min(cfg.overflow_reward, cfg.penalty_reward) - 0.15, 1.15)
    rax.grid(alpha=0.25)
    _step_axis(rax, record.timestep_s, top_ax=ax)
    rax.set_xlim(0, max(T, 1))

    ending = "overflow" if record.terminated else ("time limit" if record.truncated else "unfinished")
    ax.set_title(f"{record.policy} ({record.view} view) on {record.config_name}, seed {record.seed}: "
                 f"return {record.cumulative_reward:.2f} over {T} steps ({ending})", fontsize=11)
    markers = [
        Line2D([], [], color="black", lw=1.2 if len(set(vmaxes)) == 1 else 1.0,
               ls="-" if len(set(vmaxes)) == 1 else ":", label="v_max"),
        Line2D([], [], color="0.3", ls="--", lw=0.8, label="global optimum\n(container colour)"),
        Line2D([], [], ls="", marker="o", mfc="0.6", mec="black", label=f"emptied ({int(record.granted.sum())})"),
    ]
    if record.denied.any():
        markers.append(Line2D([], [], ls="", marker="x", mew=1.5, color="0.3",
                              label=f"denied request ({int(record.denied.sum())})"))
    if record.terminated:
        markers.append(Line2D([], [], ls="", marker="*", ms=12, color="tab:red", mec="black",
                              label="overflow (r_min)"))
    handles = ax.get_legend_handles_labels()[0] + markers
    fig.legend(handles=handles, loc="outside right upper", fontsize=8)
    return _save(fig, path, formats)


# ---- Fig. 3: ECDFs of emptying volumes -------------------------------------------------------
def plot_emptying_volume_ecdfs(records_by_method: Mapping[str, Sequence[EpisodeRecord]], path: str | Path, *,
                               containers: Sequence[str | int] | None = None,
                               config: str | PlantConfig | None = None, ncols: int | None = None,
                               formats: Sequence[str] = FORMATS) -> Figure:
    """ECDFs of the volumes at which each container was emptied (paper Fig. 3).

    One panel per container (``containers``: names or config indices; default all), one ECDF step
    line per method over all its records' emptyings of that container (gid
    ``ecdf-<container>-<method>``, k + 1 points for k emptyings, see :func:`ecdf_points`; the
    panel names k per method), a solid black line at the global optimum
    (``optimum-<container>``) and dotted grey lines at the local optima
    (``local-optimum-<container>-<k>``). One legend for the figure. Records are matched to
    containers by name. ``ncols`` panels per row (default: at most 4, rows evenly filled).
    """
    methods = _as_record_lists(records_by_method)
    first = next(iter(methods.values()))
    cfg = _resolve_config(config, first)
    if containers is None:
        chosen = list(range(cfg.n_containers))
    else:
        chosen = []
        for c in containers:
            if isinstance(c, str):
                if c not in cfg.container_names:
                    raise ValueError(f"containers: {c!r} not in {list(cfg.container_names)}")
                chosen.append(cfg.container_names.index(c))
            else:
                chosen.append(int(c))
    if not chosen:
        raise ValueError("containers: nothing to plot")
    k = len(chosen)
    if ncols is None:  # at most 4 per row, rows as evenly filled as possible
        ncols = math.ceil(k / math.ceil(k / 4))
    ncols = max(1, min(int(ncols), k))
    nrows = math.ceil(k / ncols)
    fig = Figure(figsize=(3.4 * ncols, 2.9 * nrows + 0.5), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    for extra in axes[k:]:
        fig.delaxes(extra)
    method_colors = {m: f"C{j % 10}" for j, m in enumerate(methods)}

    for ax, ci in zip(axes, chosen):
        spec = cfg.containers[ci]
        counts = []  # emptyings per method, written in the panel
        for method, recs in methods.items():
            vols = []
            for rec in recs:
                if spec.name not in rec.container_names:
                    raise ValueError(f"records_by_method[{method!r}]: a {rec.config_name} record has no "
                                     f"container {spec.name!r}")
                vols.append(rec.emptying_volumes(rec.container_names.index(spec.name)))
            x, y = ecdf_points(np.concatenate(vols))
            ax.plot(x, y, drawstyle="steps-post", color=method_colors[method], lw=1.5,
                    label=method, gid=_gid("ecdf", spec.name, method))
            counts.append((f"n = {max(x.size - 1, 0)}", method_colors[method]))
        ax.axvline(spec.target_volume, color="black", lw=1.0, label="global optimum",
                   gid=_gid("optimum", spec.name))
        local = [p for p in spec.reward_peaks if p != spec.target_volume]
        for j, p in enumerate(local):
            ax.axvline(p, color="0.5", ls=":", lw=1.0, label="local optima" if j == 0 else None,
                       gid=_gid("local-optimum", spec.name, j))
        ax.set_xlim(0, spec.max_volume)
        ax.set_ylim(0, 1.02)
        ax.set_title(f"{spec.name}  (fill rate {spec.fill_rate_per_s:.4f} vu/s)", fontsize=9)
        ax.set_xlabel("emptying volume (volume units)", fontsize=8)
        ax.set_ylabel("ECDF", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.25)
        for row, (text, color) in enumerate(counts):
            ax.text(0.02, 0.97 - 0.075 * row, text, color=color, fontsize=7, va="top",
                    transform=ax.transAxes)
    handles, labels = axes[0].get_legend_handles_labels()
    has_local = any(len(cfg.containers[ci].reward_peaks) > 1 for ci in chosen)
    if has_local and "local optima" not in labels:
        handles.append(Line2D([], [], color="0.5", ls=":", lw=1.0, label="local optima"))
    fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 6), fontsize=8)
    episodes = {len(r) for r in methods.values()}
    per_method = (f"{episodes.pop()} episodes per method" if len(episodes) == 1 else
                  ", ".join(f"{m}: {len(r)} episodes" for m, r in methods.items()))
    fig.suptitle(f"ECDFs of emptying volumes on {cfg.name} ({per_method})")
    return _save(fig, path, formats)


# ---- Fig. 4: ECDF of rewards per emptying action ---------------------------------------------
def emptying_action_rewards(record: EpisodeRecord, include_denied: bool = True) -> np.ndarray:
    """Rewards of the episode's emptying actions: granted requests (their emptying reward) and,
    with ``include_denied``, denied requests (r_pen). Overflow replacement is not applied."""
    mask = record.requested if include_denied else record.granted
    return record.container_reward[mask]


def plot_reward_ecdf(records_by_method: Mapping[str, Sequence[EpisodeRecord]], path: str | Path, *,
                     include_denied: bool = True, config: str | PlantConfig | None = None,
                     formats: Sequence[str] = FORMATS) -> Figure:
    """ECDF of the reward of every emptying action, one line per method (paper Fig. 4).

    An emptying action is a request: granted (its emptying reward) or, with ``include_denied``
    (default, as in the paper, whose negative rewards "stem from emptying actions taken when no PU
    is available"), denied (r_pen). One axis, one step line per method over all its records (gid
    ``reward-ecdf-<method>``, k + 1 points for k actions), a line at r_pen and the paper's
    "close to optimal" band [0.75, 1] shaded. Methods may come from different plants.
    """
    methods = _as_record_lists(records_by_method)
    cfg = _resolve_config(config, next(iter(methods.values())))
    fig = Figure(figsize=(6.8, 3.8), layout="constrained")
    ax = fig.add_subplot()
    lo = cfg.penalty_reward
    for j, (method, recs) in enumerate(methods.items()):
        rewards = np.concatenate([emptying_action_rewards(r, include_denied) for r in recs])
        x, y = ecdf_points(rewards)
        if x.size:
            lo = min(lo, float(x[0]))
        ax.plot(x, y, drawstyle="steps-post", color=f"C{j % 10}", lw=1.6,
                label=f"{method} (n={max(x.size - 1, 0)}, {len(recs)} ep.)", gid=_gid("reward-ecdf", method))
    ax.axvline(cfg.penalty_reward, color="tab:red", ls=":", lw=1,
               label=f"r_pen = {cfg.penalty_reward:g} (denied / empty)", gid="r_pen")
    ax.axvspan(GOOD_REWARD, 1.0, color="tab:green", alpha=0.08, lw=0, label="close to optimal [0.75, 1]")
    ax.set_xlim(lo - 0.05, 1.05)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("reward per emptying action")
    ax.set_ylabel("ECDF")
    what = "granted and denied requests" if include_denied else "granted requests"
    ax.set_title(f"ECDF of the reward per emptying action ({what})")
    ax.grid(alpha=0.25)
    ax.legend(fontsize=8, loc="upper left")
    return _save(fig, path, formats)


# ---- PU timeline -----------------------------------------------------------------------------
def pu_jobs(record: EpisodeRecord) -> list[tuple[int, int, int, int]]:
    """Every emptying as ``(pu, container, start_step, end_step)``.

    The PU is taken from the step of the emptying (``start``) until the first later state in
    which its timer is 0 again (``end``, exclusive: the first step it can serve again), or the
    episode's last state if it was still busy then.
    """
    jobs = []
    timers = record.pu_timers_s
    for t, i in zip(*np.nonzero(record.granted)):
        j = int(record.pu_index[t, i])
        free = np.flatnonzero(timers[t + 1:, j] == 0)
        end = t + 1 + int(free[0]) if free.size else record.steps
        jobs.append((j, int(i), int(t), int(end)))
    return jobs


def plot_pu_timeline(record: EpisodeRecord, path: str | Path, *, config: str | PlantConfig | None = None,
                     formats: Sequence[str] = FORMATS) -> Figure:
    """PU occupancy over one episode: one row per PU, one bar per emptying.

    Each PU's row is a ``broken_barh`` collection (gid ``pu-<j>``) with one bar per job of
    :func:`pu_jobs`, coloured by container and labelled with its name where wide enough. A last
    row holds the denied requests (gid ``denied-requests``: one cross per denied request, at its
    step, one lane per container).
    """
    cfg = _resolve_config(config, [record])
    _check_names(cfg, record)
    n, m, T = cfg.n_containers, cfg.num_processing_units, record.steps
    if record.pu_timers_s.shape[1] != m:
        raise ValueError(f"config {cfg.name!r} has {m} PUs, the record {record.pu_timers_s.shape[1]}")
    colors = container_colors(n)
    names = cfg.container_names
    jobs = pu_jobs(record)

    fig = Figure(figsize=(11, 1.2 + 0.55 * (m + 1)), layout="constrained")
    ax = fig.add_subplot()
    for j in range(m):
        mine = [job for job in jobs if job[0] == j]
        ax.broken_barh([(s, e - s) for _, _, s, e in mine], (j - 0.38, 0.76),
                       facecolors=[colors[i] for _, i, _, _ in mine], edgecolor="white", linewidth=0.5,
                       gid=_gid("pu", j))
        for _, i, s, e in mine:
            if e - s >= 0.025 * max(T, 1) * len(names[i]) / 4:
                ax.text((s + e) / 2, j, names[i], ha="center", va="center", fontsize=6.5, clip_on=True)
    t_d, i_d = np.nonzero(record.denied)
    lane = m - 0.35 + 0.7 * (i_d / max(n - 1, 1))
    ax.scatter(t_d, lane, marker="x", s=22, c=[colors[i] for i in i_d] if i_d.size else "tab:red",
               linewidths=1.2, gid="denied-requests")
    ax.set_yticks(np.arange(m + 1), [f"PU{j}" for j in range(m)] + [f"denied\n({t_d.size})"])
    ax.set_ylim(m + 0.5, -0.5)
    ax.set_xlim(0, max(T, 1))
    _step_axis(ax, record.timestep_s)
    ax.grid(axis="x", alpha=0.25)
    busy = float((record.pu_timers_s[1:] > 0).mean()) if T else 0.0
    ax.set_title(f"PU occupancy: {record.policy} ({record.view} view) on {record.config_name}, seed "
                 f"{record.seed}; {len(jobs)} emptyings, PUs busy {100 * busy:.0f}% of steps", fontsize=10)
    used = sorted({i for _, i, _, _ in jobs} | set(i_d.tolist()))
    handles = [Line2D([], [], color=colors[i], lw=6, label=names[i]) for i in used]
    if handles:
        fig.legend(handles=handles, loc="outside right upper", fontsize=7, title="container",
                   title_fontsize=8)
    return _save(fig, path, formats)
