"""A comparison on validation or fresh episodes: the protocol travels with every evaluation task."""

from __future__ import annotations

import json
from dataclasses import asdict

import pytest

from containergym_marl.evaluation.protocol import FRESH, PAPER, VALIDATION
from containergym_marl.orchestration.compare_args import CompareArgs
from containergym_marl.orchestration.plan import cached_evaluation, eval_spec
from containergym_marl.orchestration.tasks import evaluate_policy


def test_the_protocol_names_the_episodes_and_episodes_only_how_many():
    assert CompareArgs().eval_protocol() == PAPER
    assert CompareArgs(protocol="fresh").eval_protocol() == FRESH
    validation = CompareArgs(protocol="validation", episodes=4).eval_protocol()
    assert (validation.first_seed, validation.episodes) == (VALIDATION.first_seed, 4)
    assert (validation.timestep_s, validation.episode_length_steps) == (120.0, 600)


@pytest.mark.parametrize("field,value", [("protocol", "test"), ("episodes", 0), ("episodes", True)])
def test_a_bad_protocol_or_episode_count_is_refused_naming_it(field, value):
    with pytest.raises(ValueError, match=f"^{field}:"):
        CompareArgs(configs=["n5_m2_dt120"], methods=["rule_based"], **{field: value}).validate()


def test_an_evaluation_task_runs_the_comparisons_episodes():
    args = CompareArgs(configs=["n5_m2_dt120"], methods=["rule_based"], protocol="validation", episodes=2)
    spec = eval_spec(args, "n5_m2_dt120", "rule_based", None)
    assert spec.protocol == args.eval_protocol()
    result, _ = evaluate_policy(spec)
    assert [e.seed for e in result.episodes] == [20_000, 20_001]


def test_an_evaluation_on_other_episodes_is_not_reused(tmp_path):
    path = tmp_path / "rule_based.json"
    fingerprint = {"run": None}
    path.write_text(json.dumps({"compare": fingerprint, "protocol": asdict(PAPER)}))
    assert cached_evaluation(path, fingerprint, asdict(PAPER)) is not None
    assert cached_evaluation(path, fingerprint, asdict(VALIDATION)) is None
