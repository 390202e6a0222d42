"""The comparison table, built from evaluation files: one builder for ``compare`` and for regenerating.

    python -m containergym_marl.evaluation.table results/compare                 # an output folder of compare
    python -m containergym_marl.evaluation.table results/compare --out results/compare   # also rewrite table.*
    python -m containergym_marl.evaluation.table results/n5_m2_dt120/evaluations/n5_m2_dt120   # one config

Input: the evaluation files ``containergym-marl compare`` writes, ``evaluations/<config>/<method>_s<seed>.json``
for each training seed of a learned method and ``evaluations/<config>/<method>.json`` for a policy without
training seeds (the rule-based controllers). The argument is a compare output folder, its ``evaluations/``
folder or one config's folder. Regenerating from committed files needs no training, no models and no
Ray; it takes seconds.

Output, per (config, method), in the paper's Table 1 shape: the best and the median policy over
training seeds, each as mean ± std over the test episodes. They are ranked by mean return on the
validation episodes (``<folder>/validation/<config>/<method>_s<seed>.json``, seeds 20000+) where every
seed has one, else by mean test return, as the paper's Table 1 does (the lower median for an even
count; the table says which). Then the interquartile mean (IQM) of the per-seed mean returns with a 95 %
stratified-bootstrap interval, and where every seed was evaluated on the fresh episodes
(``<folder>/fresh/<config>/<method>_s<seed>.json``, seeds 30000+, used for nothing else) the same IQM
there and the share of all those fresh episodes that overflowed; the best policy's overflow rate, emptyings, share of emptyings with
reward >= 0.75, denied requests and PU utilisation; the training budget per run (in samples, one per
decision of the trained policy: plant steps for centralised methods, agent steps for decentralised
ones such as shared PPO and MAPPO). The paper's own PPO/TRPO/DQN rows follow each config. Below
the table: for each (decentralised, centralised) pair,
the probability that a run of the first beats a run of the second, with its interval (over training
seeds; over test episodes for the rule-based controllers, which have no seeds).

Bootstrap intervals are reproducible and independent of each other: every interval draws from its
own generator seeded with :data:`TABLE_SEED` and the names it is about ((config, method) for an IQM,
(config, decentralised, centralised) for a probability of improvement), so adding, removing or
reordering methods or configs never changes another row's interval.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import re
import sys
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Sequence, TextIO

import numpy as np

from containergym_marl.config.loading import config_sort_key
from containergym_marl.evaluation import metrics
from containergym_marl.evaluation import stats as st
from containergym_marl.evaluation.protocol import DEMONSTRATIONS, FRESH, PAPER, VALIDATION
from containergym_marl.files import atomic_write, atomic_write_text
from containergym_marl.methods import PAIRS

#: The paper's Table 1 (PPO, TRPO, DQN; best and median of 15 seeds; mean ± std over 15 episodes).
PAPER_TABLE_1 = {
    "n5_m2_dt60": {"ppo": ((38.55, 1.87), (29.94, 8.42)), "trpo": ((37.35, 7.13), (4.93, 4.90)), "dqn": ((29.50, 3.43), (1.57, 0.93))},
    "n5_m2_dt120": {"ppo": ((51.43, 3.00), (49.81, 1.56)), "trpo": ((38.33, 8.36), (16.86, 2.78)), "dqn": ((42.96, 2.80), (7.90, 4.72))},
    "n5_m5_dt60": {"ppo": ((37.54, 1.50), (30.64, 2.44)), "trpo": ((33.62, 7.76), (7.36, 4.40)), "dqn": ((23.98, 13.17), (1.96, 1.28))},
    "n5_m5_dt120": {"ppo": ((50.42, 2.57), (47.23, 1.89)), "trpo": ((47.36, 2.07), (5.39, 4.38)), "dqn": ((43.26, 3.73), (8.56, 4.12))},
    "n11_m2_dt60": {"ppo": ((31.01, 8.62), (23.25, 16.79)), "trpo": ((26.62, 18.94), (4.26, 3.81)), "dqn": ((42.63, 21.73), (11.84, 10.33))},
    "n11_m2_dt120": {"ppo": ((54.30, 8.48), (49.58, 13.54)), "trpo": ((45.78, 18.42), (32.08, 18.04)), "dqn": ((72.19, 16.20), (24.07, 13.68))},
    "n11_m11_dt60": {"ppo": ((27.87, 8.89), (17.57, 13.99)), "trpo": ((15.66, 10.65), (4.90, 2.68)), "dqn": ((28.32, 22.42), (8.49, 4.92))},
    "n11_m11_dt120": {"ppo": ((47.75, 10.78), (42.37, 13.25)), "trpo": ((50.55, 11.08), (34.29, 16.00)), "dqn": ((29.06, 13.10), (13.16, 8.32))},
}

#: Root seed of every bootstrap stream of the table (see the module docstring).
TABLE_SEED = 0

#: Columns of table.csv (and keys of the rows in table.json) before and after the best policy's metrics
#: (:func:`containergym_marl.evaluation.metrics.table_columns`); :func:`columns` gives them all, in order.
_LEADING_COLUMNS = ("config", "method", "view", "seeds", "best_mean", "best_std", "median_mean", "median_std",
                    "best_fresh_mean", "best_fresh_std", "median_fresh_mean", "median_fresh_std", "iqm",
                    "iqm_low", "iqm_high", "fresh_iqm", "fresh_iqm_low", "fresh_iqm_high", "fresh_overflow_rate",
                    "fresh_episodes")
_TRAILING_COLUMNS = ("best_seed", "selected_on", "samples")


def columns() -> tuple[str, ...]:
    """Columns of table.csv (and keys of the rows in table.json), in order."""
    return (*_LEADING_COLUMNS, *metrics.table_columns(), *_TRAILING_COLUMNS)


#: Where a published folder keeps the evaluations of its policies on fresh episodes
#: (``<folder>/fresh/<config>/<method>_s<seed>.json``, or ``<method>.json`` for a policy without
#: training seeds; containergym-marl publish writes them).
FRESH_FOLDER = "fresh"
#: Where a published folder keeps the evaluations on validation episodes on which the best and the
#: median seed are picked (``<folder>/validation/<config>/<method>_s<seed>.json``).
VALIDATION_FOLDER = "validation"

_FILE = re.compile(r"^(?P<method>.+?)(?:_s(?P<seed>\d+))?$")


def evaluation_key(method: str, seed: int | None) -> str:
    """The stem of an evaluation file: ``<method>_s<seed>`` for a training seed's policy, ``<method>``
    for a policy without seeds (what :func:`parse_evaluation_key` parses back)."""
    return method if seed is None else f"{method}_s{seed}"


def parse_evaluation_key(stem: str) -> tuple[str, int | None]:
    """The (method, training seed or None) of an evaluation file's stem (:func:`evaluation_key`'s inverse)."""
    m = _FILE.match(stem)
    return m["method"], int(m["seed"]) if m["seed"] is not None else None


@dataclass
class MethodEvaluations:
    """The evaluations of one method on one config: one per training seed, or a single one for a
    policy without training seeds (``seeds == []``). ``evaluations`` are the evaluation files'
    JSON objects (as :meth:`EvaluationResult.to_json` writes them, plus compare's ``"compare"``
    entry with the run's budget)."""

    config: str
    method: str
    seeds: list[int]
    evaluations: list[dict] = field(repr=False)
    #: evaluations on fresh episodes (disjoint from the test seeds) by training seed (None: the
    #: policy without training seeds), where published
    fresh: dict[int | None, dict] = field(default_factory=dict, repr=False)
    #: evaluations on the validation episodes the best and median seeds are picked on, by training seed
    validation: dict[int, dict] = field(default_factory=dict, repr=False)

    def fresh_returns(self, i: int) -> np.ndarray | None:
        """Returns of seed index ``i``'s policy on the fresh episodes, or None when not evaluated there."""
        data = self.fresh.get(self.seeds[i] if self.seeds else None)
        return None if data is None else _episode_returns(data)

    @property
    def fresh_complete(self) -> bool:
        """Every seed's policy (or the seedless policy) was evaluated on fresh episodes."""
        return all(self.fresh_returns(i) is not None for i in range(len(self.evaluations)))

    @property
    def fresh_seed_means(self) -> np.ndarray | None:
        if not self.fresh_complete:
            return None
        return np.array([self.fresh_returns(i).mean() for i in range(len(self.evaluations))])

    def fresh_overflow_rates(self) -> np.ndarray | None:
        """Per seed, the share of its fresh episodes that overflowed (None unless every seed has some)."""
        if not self.fresh_complete:
            return None
        keys = self.seeds or [None]
        return np.array([np.mean([e["overflow"] for e in self.fresh[k]["episodes"]]) for k in keys])

    @property
    def selected_on(self) -> str:
        """"validation" when every seed has a validation evaluation (the best and median are picked
        there), else "test" (picked on the test episodes they are reported on)."""
        return "validation" if self.seeds and all(s in self.validation for s in self.seeds) else "test"

    @property
    def selection_means(self) -> np.ndarray:
        """The per-seed means the best and median seeds are ranked by."""
        if self.selected_on == "validation":
            return np.array([_episode_returns(self.validation[s]).mean() for s in self.seeds])
        return self.seed_means

    @property
    def view(self) -> str:
        return self.evaluations[0].get("view") or "centralised"

    def returns(self, i: int) -> np.ndarray:
        return _episode_returns(self.evaluations[i])

    @property
    def seed_means(self) -> np.ndarray:
        return np.array([self.returns(i).mean() for i in range(len(self.evaluations))])

    def ranked(self) -> list[int]:
        """Indices of the evaluations from the best to the worst mean return on the episodes they are
        picked on (:attr:`selected_on`; stable)."""
        return [int(i) for i in np.argsort(-self.selection_means, kind="stable")]

    @property
    def best(self) -> int:
        return self.ranked()[0]

    @property
    def median(self) -> int:
        order = self.ranked()  # best first: for an even count the lower (worse) of the two middle policies
        return order[len(order) // 2]

    def improvement_scores(self) -> np.ndarray:
        """What a probability of improvement compares: per-seed mean returns, or the per-episode
        returns of a policy without training seeds."""
        return self.seed_means if self.seeds else self.returns(0)

    @property
    def unit(self) -> str:
        """What a probability of improvement is over: training seeds, or the episodes of a policy without them."""
        if self.seeds:
            return "training seeds"
        first = (self.evaluations[0].get("protocol") or {}).get("first_seed") if self.evaluations else None
        return f"{episode_kind(first)} episodes"


def _episode_returns(evaluation: dict) -> np.ndarray:
    return np.array([e["cumulative_reward"] for e in evaluation["episodes"]], dtype=float)


def method_sort_key(group: MethodEvaluations) -> tuple:
    """Policies without training seeds (rule-based) first, then learned methods, each by name."""
    return (bool(group.seeds), group.method)


def sort_groups(groups: Iterable[MethodEvaluations]) -> list[MethodEvaluations]:
    return sorted(groups, key=lambda g: (config_sort_key(g.config), method_sort_key(g)))


# ---- reading evaluation files ---------------------------------------------------------------------
def _evaluation_files(directory: Path) -> list[tuple[Path, dict]]:
    """The evaluation files of a folder (JSON with per-episode results; table.json and the like are not)."""
    found = []
    for file in sorted(directory.glob("*.json")) if directory.is_dir() else []:
        try:
            data = json.loads(file.read_text())
        except ValueError:
            continue
        if isinstance(data, dict) and isinstance(data.get("episodes"), list):
            found.append((file, data))
    return found


def load_evaluations(path: str | Path) -> list[MethodEvaluations]:
    """Every (config, method) found under ``path`` (a compare output folder, its ``evaluations/``
    folder or one config's folder), in table order. The config is the folder's name."""
    path = Path(path)
    if (path / "evaluations").is_dir():
        path = path / "evaluations"
    folders = [(path, files)] if (files := _evaluation_files(path)) else [
        (d, f) for d in (sorted(path.iterdir()) if path.is_dir() else []) if d.is_dir() and (f := _evaluation_files(d))]
    if not folders:
        raise FileNotFoundError(f"{str(path)!r} holds no evaluation files (<method>_s<seed>.json or <method>.json), "
                                f"neither directly nor in evaluations/<config>/")
    root = path.parent if path.name == "evaluations" else None
    groups = []
    for directory, files in folders:
        by_method: dict[str, list[tuple[int | None, dict]]] = {}
        for file, data in files:
            method, seed = parse_evaluation_key(file.stem)
            by_method.setdefault(method, []).append((seed, data))
        for method, found in by_method.items():
            seeded = sorted(((s, d) for s, d in found if s is not None), key=lambda sd: sd[0])
            if seeded and len(seeded) != len(found):
                raise ValueError(f"{directory}: {method} has both per-seed files and a seedless {method}.json")
            if not seeded and len(found) != 1:
                raise ValueError(f"{directory}: more than one evaluation file for {method}")
            fresh = _other_evaluations(root, FRESH_FOLDER, directory.name, method)
            if seeded:
                groups.append(MethodEvaluations(directory.name, method, [s for s, _ in seeded], [d for _, d in seeded],
                              fresh, _other_evaluations(root, VALIDATION_FOLDER, directory.name, method)))
            else:
                groups.append(MethodEvaluations(directory.name, method, [], [found[0][1]], fresh))
    return sort_groups(groups)


def _other_evaluations(root: Path | None, folder: str, config: str, method: str) -> dict[int | None, dict]:
    """A method's evaluations on other episodes (``<root>/<folder>/<config>/``) by training seed (None:
    a policy without seeds); none when the table is read from an evaluations folder alone."""
    found = {}
    for file, data in _evaluation_files(root / folder / config) if root is not None else []:
        found_method, seed = parse_evaluation_key(file.stem)
        if found_method == method:
            found[seed] = data
    return found


# ---- statistics -----------------------------------------------------------------------------------
def bootstrap_rng(*names: str) -> np.random.Generator:
    """The generator of one interval: seeded with :data:`TABLE_SEED` and the names it is about."""
    key = tuple(zlib.crc32(str(n).encode("utf-8")) for n in names)
    return np.random.default_rng(np.random.SeedSequence(TABLE_SEED, spawn_key=key))


def _summary_value(evaluation: dict, key: str) -> float:
    value = evaluation.get("summary", {}).get(key)
    return float("nan") if value is None else float(value)


def _budget(group: MethodEvaluations) -> int | None:
    """Training samples per run, one per decision of the policy (plant steps for a centralised
    method, agent steps for a decentralised one): compare's record, or the training record of a run
    trained by a script (baselines/train_mappo.py: ``training.samples``, its budget in agent steps)."""
    budgets = {e.get("compare", {}).get("timesteps") or e.get("training", {}).get("samples")
               for e in group.evaluations}
    return budgets.pop() if len(budgets) == 1 else None


def table_rows(groups: Sequence[MethodEvaluations], reps: int = 2000) -> list[dict[str, Any]]:
    """One row per (config, method), keys :func:`columns`."""
    rows = []
    for g in groups:
        best, median = g.best, g.median
        b, md = g.returns(best), g.returns(median)
        point, low, high = st.stratified_bootstrap_ci(g.seed_means[:, None], st.iqm, reps=reps,
                                                      rng=bootstrap_rng("iqm", g.config, g.method))
        e = g.evaluations[best]
        fb, fm = g.fresh_returns(best), g.fresh_returns(median)
        fresh_means, fresh_overflows = g.fresh_seed_means, g.fresh_overflow_rates()
        fresh = (None, None, None) if fresh_means is None else (
            st.stratified_bootstrap_ci(fresh_means[:, None], st.iqm, reps=reps,
                                       rng=bootstrap_rng("fresh_iqm", g.config, g.method)) if g.seeds
            else (float(g.fresh_returns(0).mean()),) * 3)
        rows.append({
            "config": g.config, "method": g.method, "view": g.view, "seeds": len(g.seeds),
            "best_mean": float(b.mean()), "best_std": float(b.std()),
            "median_mean": float(md.mean()), "median_std": float(md.std()),
            "best_fresh_mean": None if fb is None else float(fb.mean()),
            "best_fresh_std": None if fb is None else float(fb.std()),
            "median_fresh_mean": None if fm is None else float(fm.mean()),
            "median_fresh_std": None if fm is None else float(fm.std()),
            "iqm": point, "iqm_low": low, "iqm_high": high,
            "fresh_iqm": fresh[0], "fresh_iqm_low": fresh[1], "fresh_iqm_high": fresh[2],
            "fresh_overflow_rate": None if fresh_overflows is None else float(fresh_overflows.mean()),
            "fresh_episodes": None if fb is None else len(fb),
            **{m.column: _summary_value(e, m.summary) for m in metrics.shown_in("table")},
            "best_seed": g.seeds[best] if g.seeds else None,
            "selected_on": g.selected_on if g.seeds else None, "samples": _budget(g),
        })
    return rows


def improvements(groups: Sequence[MethodEvaluations], pairs: Iterable[tuple[str, str]],
                 reps: int = 2000) -> list[dict[str, Any]]:
    """P(decentralised > centralised) with its 95 % bootstrap interval, for each pair present in a config."""
    by_key = {(g.config, g.method): g for g in groups}
    out = []
    for config in dict.fromkeys(g.config for g in groups):
        for dec, cen in pairs:
            if (config, dec) in by_key and (config, cen) in by_key:
                x, y = by_key[(config, dec)], by_key[(config, cen)]
                p, low, high = st.probability_of_improvement_ci(
                    x.improvement_scores()[:, None], y.improvement_scores()[:, None], reps=reps,
                    rng=bootstrap_rng("poi", config, dec, cen))
                out.append({"config": config, "decentralised": dec, "centralised": cen,
                            "probability": p, "low": low, "high": high, "unit": x.unit})
    return out


# ---- formatting -----------------------------------------------------------------------------------
def format_value(x: float | None, fmt: str = ".2f") -> str:
    """A table cell: ``x`` in ``fmt``, "–" where it is missing or undefined (NaN)."""
    return "–" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, fmt)


def _samples(n: int | None) -> str:
    """2000000 -> 2M, 2500000 -> 2.5M, 30000 -> 30k, 2048 -> 2,048."""
    if n is None:
        return "–"
    for unit, size in (("M", 1_000_000), ("k", 1_000)):
        if n >= size and (n * 10) % size == 0:
            return f"{n / size:g}{unit}"
    return f"{n:,}"


def _protocol_text(groups: Sequence[MethodEvaluations]) -> str:
    seen = {(p.get("timestep_s"), p.get("episode_length_steps"), p.get("episodes"), p.get("first_seed"))
            for g in groups for e in g.evaluations if (p := e.get("protocol"))}
    if len(seen) > 1:
        return "protocols differ between rows"
    dt, steps, episodes, first = seen.pop() if seen else (120.0, 600, None, PAPER.first_seed)
    if (dt, steps, first) == (PAPER.timestep_s, PAPER.episode_length_steps, PAPER.first_seed):
        name = "paper protocol"
    else:  # another plant timing, or other episodes than the test seeds (a study on validation or fresh ones)
        name = f"seeds {first}+" if first is not None and first != PAPER.first_seed else "test protocol"
    return f"{name}: δ = {dt:g} s, T = {steps}" + (f", {episodes} episodes" if episodes else "")


def episode_kind(first_seed: int | None) -> str:
    """What the episodes starting at ``first_seed`` are for (:mod:`~containergym_marl.evaluation.protocol`'s
    seed ranges): "test" (the paper's protocol, seeds 10000+, and evaluations that do not say),
    "validation" (20000+), "fresh" (30000+), else "evaluation"."""
    if first_seed is None:
        return "test"
    for kind, start, end in (("test", PAPER.first_seed, VALIDATION.first_seed),
                             ("validation", VALIDATION.first_seed, FRESH.first_seed),
                             ("fresh", FRESH.first_seed, DEMONSTRATIONS.first_seed)):
        if start <= first_seed < end:
            return kind
    return "evaluation"


def _episode_kind(groups: Sequence[MethodEvaluations]) -> str:
    """The kind of the table's main episodes ("test" unless every evaluation says otherwise)."""
    kinds = {episode_kind(p.get("first_seed")) for g in groups for e in g.evaluations if (p := e.get("protocol"))}
    return kinds.pop() if len(kinds) == 1 else "test"


def reward_title(groups: Sequence[MethodEvaluations]) -> str:
    """The table's title: "Test cumulative reward (paper protocol: δ = 120 s, T = 600, 15 episodes)", or
    "Validation …" / "Fresh …" for a comparison on those episodes."""
    return f"{_episode_kind(groups).capitalize()} cumulative reward ({_protocol_text(groups)})"


def _fresh_text(groups: Sequence[MethodEvaluations]) -> str:
    seeds = sorted({e["seed"] for g in groups for data in g.fresh.values() for e in data["episodes"]})
    if not seeds:
        return ""
    return (f" Fresh: the same policies on {len(seeds)} fresh episodes (seeds {seeds[0]}–{seeds[-1]}, used for "
            f"nothing else), where they were picked without seeing them; IQM, fresh: the IQM of the seeds' mean "
            f"fresh returns [95 % CI]; overflow, fresh: the share of all those episodes that overflowed.")


def _selection_text(groups: Sequence[MethodEvaluations]) -> str:
    seeded = [g for g in groups if g.seeds]
    if not seeded:  # rules and planners only: nothing is picked
        return ""
    on = {g.selected_on for g in seeded}
    if on == {"validation"}:
        seeds = sorted({e["seed"] for g in seeded for data in g.validation.values() for e in data["episodes"]})
        return f", picked on {len(seeds)} validation episodes (seeds {seeds[0]}–{seeds[-1]})"
    return ", picked on the test episodes" if on == {"test"} else (
        ", picked on validation episodes where every seed has them, else on the test episodes")


def _fresh_iqm_cell(row: dict) -> str:
    if row["fresh_iqm"] is None:
        return "–"
    return f"{row['fresh_iqm']:.2f} [{row['fresh_iqm_low']:.2f}, {row['fresh_iqm_high']:.2f}]"


def _fresh_cell(mean: float | None, std: float | None) -> str:
    return "–" if mean is None else f"{mean:.2f} ± {std:.2f}"


def _best_policy_columns() -> str:
    """The best policy's metric columns, named for the caption: "overflow rate … PU busy"."""
    shown = metrics.shown_in("table")
    return "" if not shown else shown[0].label.capitalize() if len(shown) == 1 else (
        f"{shown[0].label.capitalize()} … {shown[-1].label}")


def markdown(rows: Sequence[dict], imps: Sequence[dict], groups: Sequence[MethodEvaluations] = ()) -> str:
    """The Markdown table (one block for all configs) and the probabilities of improvement."""
    shown = metrics.shown_in("table")
    headers = ["config", "method", "view", "seeds", "best", "best, fresh", "median", "median, fresh", "IQM [95 % CI]",
               "IQM, fresh [95 % CI]", "overflow, fresh", *(m.label for m in shown), "samples"]
    lines = [
        f"{reward_title(groups)}. A seed's policy: its run's validated model (the checkpoint of highest "
        "validation return) where its curve picked one, else its best model (of highest training return). "
        "Best / median: the best and the median policy "
        f"over training seeds{_selection_text(groups)}, mean ± std over {_episode_kind(groups)} episodes."
        + _fresh_text(groups)
        + " IQM: interquartile mean "
        f"of the per-seed mean returns [95 % stratified-bootstrap CI]. {_best_policy_columns()}: of the best policy. "
        "Samples: training budget per run, one sample per decision of the trained policy (a plant step "
        "for a centralised method, an agent step for a decentralised one: n per plant step).",
        "",
        "| " + " | ".join(headers) + " |",
        "|" + "---|" * len(headers),
    ]
    configs = list(dict.fromkeys(r["config"] for r in rows))
    for config in configs:
        for r in (r for r in rows if r["config"] == config):
            lines.append(
                f"| {r['config']} | {r['method']} | {r['view']} | {r['seeds'] or '–'} | "
                f"{r['best_mean']:.2f} ± {r['best_std']:.2f} | {_fresh_cell(r['best_fresh_mean'], r['best_fresh_std'])} | "
                f"{r['median_mean']:.2f} ± {r['median_std']:.2f} | "
                f"{_fresh_cell(r['median_fresh_mean'], r['median_fresh_std'])} | "
                f"{r['iqm']:.2f} [{r['iqm_low']:.2f}, {r['iqm_high']:.2f}] | {_fresh_iqm_cell(r)} | "
                f"{format_value(r['fresh_overflow_rate'])} | "
                + "".join(f"{format_value(r[m.column], m.fmt)} | " for m in shown) + f"{_samples(r['samples'])} |")
        for algo, (best, median) in PAPER_TABLE_1.get(config, {}).items():
            lines.append(f"| {config} | paper {algo.upper()} (15 seeds) | centralised | 15 | "
                         f"{best[0]:.2f} ± {best[1]:.2f} | – | {median[0]:.2f} ± {median[1]:.2f} | "
                         + "– | " * (len(headers) - 8) + f"{'2M' if config.startswith('n5_') else '5M'} |")
    if imps:
        lines += ["", "Probability of improvement (decentralised over centralised) [95 % bootstrap CI]:", ""]
        for i in imps:
            lines.append(f"- {i['config']}: P({i['decentralised']} > {i['centralised']}) = {i['probability']:.2f} "
                         f"[{i['low']:.2f}, {i['high']:.2f}] (over {i['unit']})")
    return "\n".join(lines) + "\n"


@dataclass
class Table:
    rows: list[dict]
    improvements: list[dict]
    markdown: str
    seed_means: dict[str, list[float]]
    title: str = ""  # e.g. "Test cumulative reward (paper protocol: δ = 120 s, T = 600, 15 episodes)"

    def write(self, out: str | Path, meta: dict | None = None) -> list[Path]:
        """Write ``table.md``, ``table.csv`` and ``table.json`` into ``out``; returns their paths."""
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_text(out / "table.md", self.markdown)

        def write_csv(tmp: Path) -> None:
            with tmp.open("w", newline="") as f:
                w = csv.DictWriter(f, fieldnames=columns())
                w.writeheader()
                w.writerows(self.rows)

        atomic_write(out / "table.csv", write_csv)
        report = {**(meta or {}), "rows": self.rows, "improvements": self.improvements,
                  "seed_means": self.seed_means}
        atomic_write_text(out / "table.json", json.dumps(report, indent=2))
        return [out / "table.md", out / "table.csv", out / "table.json"]


def build_table(groups: Sequence[MethodEvaluations], pairs: Iterable[tuple[str, str]] | None = None,
                reps: int = 2000) -> Table:
    """The table of ``groups`` (sorted into table order). ``pairs``: (decentralised, centralised)
    method names whose probability of improvement is reported (default: the method registry's)."""
    pairs = PAIRS if pairs is None else pairs
    groups = sort_groups(groups)
    rows = table_rows(groups, reps)
    imps = improvements(groups, pairs, reps)
    return Table(rows, imps, markdown(rows, imps, groups),
                 {f"{g.config}/{g.method}": g.seed_means.tolist() for g in groups}, reward_title(groups))


def print_table(table: Table, stream: TextIO | None = None, shipped: bool = False, width: int | None = None) -> None:
    """``table`` in the terminal (rich): one section per config with the paper's PPO below it, then
    the probabilities of improvement. ``shipped``: the caption says how the shipped policies'
    rows were made. A terminal too narrow for every column gets the table without the view and
    median and samples columns; without a terminal: no colours, ``width`` (default 140) columns, no trailing blanks."""
    import io

    from rich.console import Console

    stream = stream or sys.stdout
    tty = bool(getattr(stream, "isatty", lambda: False)())
    console = Console(file=stream if tty else io.StringIO(), width=width or (None if tty else 140), highlight=False,
                      markup=False, emoji=False, force_terminal=None if tty else False)
    out = _rich_table(table, shipped, narrow=False)
    if console.measure(out, options=console.options.update_width(10_000)).maximum > console.width:
        out = _rich_table(table, shipped, narrow=True)
    console.print(out)
    if table.improvements:
        console.print("\nProbability of improvement (decentralised over centralised) [95 % bootstrap CI]:")
        for i in table.improvements:
            console.print(f"  {i['config']}: P({i['decentralised']} > {i['centralised']}) = {i['probability']:.2f} "
                          f"[{i['low']:.2f}, {i['high']:.2f}] (over {i['unit']})")
    if not tty:
        print("\n".join(line.rstrip() for line in console.file.getvalue().splitlines()), file=stream, flush=True)


def _rich_table(table: Table, shipped: bool, narrow: bool):
    """The rich table of :func:`print_table`; ``narrow``: without the view, median and samples columns
    (the IQM over seeds stays: it is the comparison's headline number)."""
    from rich import box
    from rich.table import Table as RichTable

    out = RichTable(title=table.title or "Test cumulative reward (paper protocol)", box=box.SIMPLE_HEAD,
                    title_justify="left", caption_justify="left", pad_edge=False)
    shown = metrics.shown_in("terminal")
    columns = ["config", "method", "view", "seeds", "best", "median", "IQM [95 % CI]", *(m.short for m in shown),
               "samples"]
    if narrow:
        columns = [c for c in columns if c not in ("view", "median", "samples")]
    for name in columns:
        out.add_column(name, justify="left" if name in ("config", "method", "view") else "right", no_wrap=True)

    def add(cells: dict[str, str], **style) -> None:
        out.add_row(*(cells[c] for c in columns), **style)

    configs = list(dict.fromkeys(r["config"] for r in table.rows))
    for i, config in enumerate(configs):
        for j, r in enumerate(r for r in table.rows if r["config"] == config):
            add({"config": config if j == 0 else "", "method": r["method"], "view": r["view"],
                 "seeds": str(r["seeds"] or "–"), "best": f"{r['best_mean']:.2f} ± {r['best_std']:.2f}",
                 "median": f"{r['median_mean']:.2f} ± {r['median_std']:.2f}",
                 "IQM [95 % CI]": f"{r['iqm']:.2f} [{r['iqm_low']:.2f}, {r['iqm_high']:.2f}]" if r["seeds"] else "–",
                 **{m.short: format_value(r[m.column], m.fmt) for m in shown}, "samples": _samples(r["samples"])})
        if "ppo" in PAPER_TABLE_1.get(config, {}):
            best, median = PAPER_TABLE_1[config]["ppo"]
            add({"config": "", "method": "paper PPO", "view": "centralised", "seeds": "15",
                 "best": f"{best[0]:.2f} ± {best[1]:.2f}", "median": f"{median[0]:.2f} ± {median[1]:.2f}",
                 "IQM [95 % CI]": "–", **{m.short: "–" for m in shown},
                 "samples": "2M" if config.startswith("n5_") else "5M"},
                style="dim")
        if i < len(configs) - 1:
            out.add_section()
    out.caption = (
        "best / median: the best and the median policy over training seeds (by mean test return), mean ± std over "
        "the test episodes; IQM: interquartile mean of the per-seed means; "
        + "".join(f"{m.short}: the best policy's {m.label} over the test episodes; " for m in shown)
        + ("" if narrow else "samples: training budget per run (plant steps for centralised methods, agent steps "
                             "for decentralised ones). ")
        + "Paper PPO: Table 1 of the paper ("
        + ("views, medians, budgets, " if narrow else "") + "TRPO, DQN and more columns in table.md)."
        + (" Learned methods: their finished shipped seeds; the best seed's policy (and any seed without a "
           "published evaluation) is evaluated now, the other seeds' numbers are their published evaluations."
           if shipped and any(r["seeds"] for r in table.rows) else ""))
    return out


def markdown_table(results: str | Path, reps: int = 2000) -> str:
    """The Markdown table of the evaluation files under ``results`` (see :func:`load_evaluations`)."""
    return build_table(load_evaluations(results), reps=reps).markdown


@dataclass
class MethodRow:
    """Best and median policy of one method, as ``(mean, std, seed)``; seed -1: no training seeds."""

    method: str
    seeds: list[int]
    best: tuple[float, float, int]
    median: tuple[float, float, int]
    overflow_rate_best: float
    view: str  # "centralised" or "decentralised", as the evaluation files record it


def method_rows(results: str | Path) -> list[MethodRow]:
    """:class:`MethodRow` per (config, method) under ``results``."""
    out = []
    for g in load_evaluations(results):
        seeds = g.seeds or [-1]
        b, md = g.returns(g.best), g.returns(g.median)
        out.append(MethodRow(g.method, seeds, (float(b.mean()), float(b.std()), seeds[g.best]),
                             (float(md.mean()), float(md.std()), seeds[g.median]),
                             _summary_value(g.evaluations[g.best], "overflow_rate"), g.view))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m containergym_marl.evaluation.table",
                                     description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("path", help="a compare output folder, its evaluations/ folder, or one config's folder")
    parser.add_argument("--out", default=None, help="also write table.md, table.csv and table.json here")
    parser.add_argument("--bootstrap-reps", type=int, default=2000)
    ns = parser.parse_args(sys.argv[1:] if argv is None else argv)
    table = build_table(load_evaluations(ns.path), reps=ns.bootstrap_reps)
    print(table.markdown, end="")
    if ns.out:
        paths = table.write(ns.out, {"source": str(ns.path)})
        print(f"written: {', '.join(str(p) for p in paths)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
