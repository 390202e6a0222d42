"""The per-episode metrics: each counted as the paper defines it (hand-computed episodes), and declared
once: a metric added to :data:`~containergym_marl.evaluation.metrics.METRICS` alone appears in every
evaluation path (one environment and batched), in the evaluation files, and in every renderer (the
markdown, CSV and JSON table, the terminal table, a results page's row block, ``evaluate``'s print)."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from containergym_marl.evaluation import EvalProtocol, evaluate
from containergym_marl.evaluation import metrics as metric_module
from containergym_marl.evaluation import table as tables
from containergym_marl.evaluation.batched import evaluate_batched
from containergym_marl.evaluation.metrics import Metric, Steps, episode_values
from containergym_marl.evaluation.run_policies import policy_from_run

REPO = Path(__file__).resolve().parents[2]
RUN = REPO / "results" / "paper_rows" / "runs" / "fast_shared_ppo_n11_m2_dt120_s3"
SHORT = EvalProtocol(episodes=3, first_seed=30_000, episode_length_steps=60)


def _steps(requested, granted, reward, busy, terminated, risk=None) -> Steps:
    requested, granted = np.array(requested, bool), np.array(granted, bool)
    terminated = np.array(terminated, bool)
    return Steps(requested=requested, granted=granted, denied=requested & ~granted,
                 container_reward=np.array(reward, float), pu_busy=np.array(busy, bool), terminated=terminated,
                 overflow_probability=np.zeros(terminated.shape) if risk is None else np.array(risk, float))


def test_an_episode_s_metrics_by_hand():
    # 3 steps, 2 containers, 2 PUs. Step 0: container 0 emptied at reward 0.9, container 1 denied
    # (r_pen -0.1); step 1: nothing; step 2: container 1 emptied at 0.5 and the episode overflows.
    steps = _steps(requested=[[1, 1], [0, 0], [0, 1]], granted=[[1, 0], [0, 0], [0, 1]],
                   reward=[[0.9, -0.1], [0, 0], [0, 0.5]], busy=[[1, 0], [1, 0], [1, 1]],
                   terminated=[0, 0, 1], risk=[0.0, 0.25, 0.5])
    assert episode_values(steps) == {
        "steps": 3, "overflow": True, "overflow_risk": 0.75, "emptyings": 2, "emptying_actions": 3,
        "good_emptying_share": pytest.approx(1 / 3), "negative_emptying_share": pytest.approx(1 / 3),
        "denied_requests": 1, "pu_utilisation": pytest.approx(4 / 6)}


def test_a_share_of_no_emptying_action_is_undefined_not_zero():
    steps = _steps(requested=[[0, 0]] * 2, granted=[[0, 0]] * 2, reward=[[0, 0]] * 2, busy=[[0]] * 2,
                   terminated=[0, 0])
    values = episode_values(steps)
    assert math.isnan(values["good_emptying_share"]) and math.isnan(values["negative_emptying_share"])
    assert values["emptying_actions"] == 0 and values["overflow"] is False and values["pu_utilisation"] == 0.0


def test_a_metric_shown_somewhere_needs_a_column_and_a_known_renderer():
    with pytest.raises(ValueError, match="'x'.*no column"):
        Metric("x", lambda s: s.granted.sum(-1), "int", "x_mean", "x", "x", "", "", shows=frozenset({"row"}))
    with pytest.raises(ValueError, match="unknown renderer"):
        Metric("x", lambda s: s.granted.sum(-1), "int", "x_mean", "x", "x", "", "", column="x",
               shows=frozenset({"plot"}))


#: a metric that no shipped code knows: the share of requests that were granted
GRANTED = Metric("granted_request_share", lambda s: s.granted.sum(-1), "float", "granted_request_share",
                 "granted share", "granted", "share of requests", "share of the emptying actions that were granted",
                 per="emptying_actions", column="granted_share_of_requests", fmt=".3f",
                 shows=frozenset({"table", "terminal", "row", "cli"}))


def test_a_metric_declared_once_reaches_every_evaluation_file_and_renderer(tmp_path, monkeypatch, capsys):
    from containergym_marl.cli import _print_evaluation
    from containergym_marl.orchestration.publish import row_block

    monkeypatch.setattr(metric_module, "METRICS", (*metric_module.METRICS, GRANTED))
    policy = policy_from_run(RUN)
    one = evaluate(policy, "n11_m2_dt120", SHORT)
    batched = evaluate_batched(policy, "n11_m2_dt120", SHORT)
    for a, b, record in zip(one.episodes, batched.episodes, one.records):
        expected = record.granted.sum() / record.requested.sum()
        assert a.granted_request_share == pytest.approx(expected) and b.granted_request_share == pytest.approx(expected)
    summary = one.summary()
    assert summary["granted_request_share"] == pytest.approx(np.mean([e.granted_request_share for e in one.episodes]))
    assert batched.summary()["granted_request_share"] == pytest.approx(summary["granted_request_share"])

    # the evaluation files: one seedless method and one learned method with two seeds
    folder = tmp_path / "evaluations" / "n11_m2_dt120"
    folder.mkdir(parents=True)
    data = json.loads(one.to_json())
    assert [e["granted_request_share"] for e in data["episodes"]] == pytest.approx(
        [e.granted_request_share for e in one.episodes])
    (folder / "rules.json").write_text(one.to_json())
    (folder / "learned_s1.json").write_text(one.to_json())
    (folder / "learned_s2.json").write_text(batched.to_json())

    table = tables.build_table(tables.load_evaluations(tmp_path), reps=50)
    table.write(tmp_path)
    cell = format(summary["granted_request_share"], ".3f")
    assert all(r["granted_share_of_requests"] == pytest.approx(summary["granted_request_share"]) for r in table.rows)
    with (tmp_path / "table.csv").open() as f:
        header = next(csv.reader(f))
    assert header == list(tables.columns()) and "granted_share_of_requests" in header
    md_header = table.markdown.splitlines()[2]
    assert "| granted share |" in md_header and f"| {cell} |" in table.markdown
    assert len(md_header.split("|")) == len(table.markdown.splitlines()[4].split("|"))  # every row has the cell

    tables.print_table(table, stream=(out := _Text()))
    assert " granted " in out.text and cell in out.text
    block = row_block(tmp_path, "n11_m2_dt120")
    assert "| granted share |" in block.splitlines()[0] and f"| {cell} |" in block

    _print_evaluation(one, None)
    printed = capsys.readouterr().out.splitlines()
    assert printed[1].split("overflowed")[0].split()[-1] == "granted"  # the last per-episode column
    assert f"granted share {cell}" in printed[-1]


class _Text:
    def __init__(self):
        self.text = ""

    def write(self, s: str) -> int:
        self.text += s
        return len(s)

    def flush(self) -> None:
        pass


def test_without_the_added_metric_no_renderer_shows_it():
    assert GRANTED not in metric_module.METRICS
    assert "granted_share_of_requests" not in tables.columns()
