"""Every per-episode metric, declared once: how a step counts towards it, how episodes aggregate, the
names the files hold it under, its unit and format, and which renderers show it.

One :class:`Metric` feeds everything downstream of an evaluation:

- each episode's value (:class:`~containergym_marl.evaluation.protocol.EpisodeMetrics`, the
  ``episodes`` of an evaluation file), counted by the same function from an episode's record
  (:func:`episode_values`) and from the batched evaluation's simulations (:class:`BatchTotals`);
- the summary over episodes (an evaluation file's ``summary``: the mean over the episodes where the
  value is defined);
- the comparison table's column of the best policy (table.md, table.csv, table.json) where it has
  one, and the terminal table, the results page's row block and the ``evaluate`` command's print,
  as :attr:`Metric.shows` says.

Adding a metric is one entry in :data:`METRICS`. The three names of a metric (per episode, summary,
table column) are those of the published files, kept so that those files stay readable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Literal

import numpy as np

#: The paper's "close to optimal" band of emptying rewards is [GOOD_REWARD, 1].
GOOD_REWARD = 0.75

#: Where a metric can be shown: the comparison table (markdown, CSV, JSON: the best policy's value),
#: the terminal's table (``compare``/``table``), a results page's row block, and ``evaluate``'s print
#: (one column per episode and the summary line).
RENDERERS = frozenset({"table", "terminal", "row", "cli"})


@dataclass(frozen=True)
class Steps:
    """What one or more steps did. The last axis is the containers (``requested``, ``granted``,
    ``denied``, ``container_reward``) or the PUs (``pu_busy``: the PU is busy after the step); the
    leading axes are the steps of one episode (a record) or the simulations of one batched step.
    ``terminated``: the step ended the episode with an overflow; ``overflow_probability``: the
    probability that it would, given the state before the step and its emptyings (leading axes only)."""

    requested: np.ndarray
    granted: np.ndarray
    denied: np.ndarray
    container_reward: np.ndarray
    pu_busy: np.ndarray
    terminated: np.ndarray
    overflow_probability: np.ndarray


@dataclass(frozen=True)
class Metric:
    """One per-episode metric and the columns it feeds.

    ``count(steps)`` is what each step adds (reduced over containers or PUs, one value per leading
    index of :class:`Steps`). The episode's value is the sum over its steps (``per=None``), that sum
    per step (``per="steps"``) or a share of another metric's sum (``per=<its name>``; undefined, NaN,
    where that sum is 0). ``kind`` is the per-episode value's type in the files."""

    name: str  # per episode: the evaluation files' key and EpisodeMetrics' attribute
    count: Callable[[Steps], np.ndarray]
    kind: Literal["int", "float", "bool"]
    summary: str  # the mean over episodes: the evaluation files' summary key
    label: str  # column header in the tables and the summary line
    short: str  # header of evaluate's per-episode column
    unit: str
    doc: str
    per: str | None = None
    column: str | None = None  # the comparison table's key (table.csv, table.json) for the best policy
    fmt: str = ".2f"  # format of a mean over episodes
    shows: frozenset[str] = frozenset({"cli"})

    def __post_init__(self) -> None:
        unknown = set(self.shows) - RENDERERS
        if unknown:
            raise ValueError(f"metric {self.name!r}: unknown renderer(s) {sorted(unknown)}; known: {sorted(RENDERERS)}")
        if self.shows - {"cli"} and self.column is None:
            raise ValueError(f"metric {self.name!r} is shown in {sorted(self.shows - {'cli'})} but has no column")

    def episode_text(self, value) -> str:
        """One episode's value as ``evaluate`` prints it ("–" where undefined)."""
        if self.kind == "bool":
            return str(bool(value))
        if self.kind == "int":
            return str(int(value))
        return "–" if math.isnan(value) else format(value, self.fmt)


def _requests_with(condition: Callable[[np.ndarray], np.ndarray]) -> Callable[[Steps], np.ndarray]:
    return lambda s: (s.requested & condition(s.container_reward)).sum(-1)


#: Every per-episode metric, in the order the files and tables hold them.
METRICS: tuple[Metric, ...] = (
    Metric("steps", lambda s: np.ones(s.terminated.shape), "int", "steps_mean", "steps", "steps", "steps",
           "steps until the episode ended (T, or the overflow's step)", fmt=".1f"),
    Metric("overflow", lambda s: s.terminated, "bool", "overflow_rate", "overflow rate", "overflow", "episodes",
           "the episode ended with an overflow", column="overflow_rate",
           shows=frozenset({"table", "terminal", "row", "cli"})),
    # Σ_t P(overflow at step t | the state before it, its emptyings) over the steps of the episode: an
    # overflow ends it, so the mean over episodes is an unbiased estimate of the overflow rate, as the
    # share of overflowing episodes is. Where a policy keeps every step's risk small, it measures rates
    # (1e-4 an episode) that no affordable number of episodes can count.
    Metric("overflow_risk", lambda s: s.overflow_probability, "float", "overflow_risk", "overflow risk", "risk",
           "expected overflows", "the episode's summed step probabilities of an overflow (given the state "
           "before each step and its emptyings): its mean over episodes estimates the overflow rate",
           fmt=".2g"),
    Metric("emptyings", lambda s: s.granted.sum(-1), "int", "emptyings_mean", "emptyings", "emptyings",
           "containers", "containers emptied (granted requests)", column="emptyings", fmt=".1f",
           shows=frozenset({"table", "row", "cli"})),
    Metric("emptying_actions", lambda s: s.requested.sum(-1), "int", "emptying_actions_mean", "emptying actions",
           "requests", "requests", "requests to empty, granted or denied for lack of a free PU", fmt=".1f",
           shows=frozenset()),
    Metric("good_emptying_share", _requests_with(lambda r: r >= GOOD_REWARD), "float", "good_emptying_share",
           f"r ≥ {GOOD_REWARD:g}", f"r>={GOOD_REWARD:g}", "share of requests",
           f"share of the emptying actions with reward ≥ {GOOD_REWARD:g} (the paper's close-to-optimal band)",
           per="emptying_actions", column="good_share", shows=frozenset({"table", "row", "cli"})),
    Metric("negative_emptying_share", _requests_with(lambda r: r < 0), "float", "negative_emptying_share", "r < 0",
           "r<0", "share of requests", "share of the emptying actions with a negative reward (the paper's Figure 4)",
           per="emptying_actions"),
    Metric("denied_requests", lambda s: s.denied.sum(-1), "int", "denied_requests_mean", "denied req.", "denied",
           "requests", "requests denied because no PU was free", column="denied", fmt=".1f",
           shows=frozenset({"table", "row", "cli"})),
    Metric("pu_utilisation", lambda s: s.pu_busy.mean(-1), "float", "pu_utilisation", "PU busy", "PU busy",
           "share of (step, PU) pairs", "share of (step, PU) pairs with the PU busy after the step", per="steps",
           column="pu_utilisation", shows=frozenset({"table", "cli"})),
)


def shown_in(renderer: str) -> list[Metric]:
    """The metrics a renderer shows, in order."""
    if renderer not in RENDERERS:
        raise ValueError(f"unknown renderer {renderer!r}; known: {sorted(RENDERERS)}")
    return [m for m in METRICS if renderer in m.shows]


def finish(totals: dict[str, float]) -> dict[str, float | int | bool]:
    """Each metric's episode value from its summed counts (``totals``: by name, with ``"steps"``)."""
    values: dict[str, float | int | bool] = {}
    for m in METRICS:
        total = totals[m.name]
        if m.per is not None:
            base = totals[m.per]
            total = total / base if base else float("nan")
        values[m.name] = bool(total) if m.kind == "bool" else int(round(total)) if m.kind == "int" else float(total)
    return values


def episode_values(steps: Steps) -> dict[str, float | int | bool]:
    """Every metric of one episode whose steps are the leading axis of ``steps``."""
    return finish({m.name: float(np.sum(m.count(steps))) for m in METRICS})


class BatchTotals:
    """Every metric's sum over the steps of B simulations' episodes, one batched step at a time."""

    def __init__(self, sims: int):
        self.totals = {m.name: np.zeros(sims) for m in METRICS}

    def add(self, steps: Steps, active: np.ndarray) -> None:
        """Add one step of every simulation whose episode is still running (``active``)."""
        weight = active.astype(float)
        for m in METRICS:
            self.totals[m.name] += weight * m.count(steps)

    def values(self, sim: int) -> dict[str, float | int | bool]:
        return finish({name: float(total[sim]) for name, total in self.totals.items()})


def summary(episodes: list[dict]) -> dict[str, float]:
    """Each metric's mean over the episodes where it is defined, by summary key (NaN where none is)."""
    out = {}
    for m in METRICS:
        vals = np.array([e[m.name] for e in episodes], dtype=float)
        vals = vals[~np.isnan(vals)]
        out[m.summary] = float(vals.mean()) if vals.size else float("nan")
    return out


def table_columns() -> list[str]:
    """The comparison table's keys of the metrics it shows (table.csv's columns, in order)."""
    return [m.column for m in shown_in("table")]
