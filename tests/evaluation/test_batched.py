"""The batched evaluation gives, episode by episode, what the one-environment evaluation gives for
the same policy, plant and protocol: checked on published models of every learned adapter (native
controller and shared policy, SB3 controller and shared policy, MAPPO's actor), on a contended row
where some episodes overflow."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from containergym_marl.evaluation import EvalProtocol, evaluate
from containergym_marl.evaluation.batched import evaluate_batched
from containergym_marl.evaluation.metrics import METRICS
from containergym_marl.evaluation.run_policies import policy_from_run

REPO = Path(__file__).resolve().parents[2]
RUNS = REPO / "results" / "paper_rows" / "runs"
# fresh-range episodes of the test protocol, enough for overflows of the weaker models
EPISODES = EvalProtocol(episodes=12, first_seed=30_000)


# (method, row, whether the compared episodes include an overflow as well as time-limit ends): each on the
# first published seed whose first fresh episodes end both ways (the fewest such episodes), or, without
# overflows, four that reach the time limit; found by the batched evaluation, so a republished method needs
# no edit here, and the one-environment evaluation must then agree on it
COMPARED = [("fast_shared_ppo", "n11_m2_dt120", False), ("fast_ppo", "n11_m2_dt120", True),
            ("ppo", "n11_m2_dt120", True), ("shared_ppo", "n11_m2_dt120", False),
            ("mappo", "n11_m2_dt120", True), ("fast_shared_ppo_team", "n5_m2_dt60", True)]
MOST_EPISODES, NO_OVERFLOW_EPISODES = 8, 4


def compared_run(method: str, row: str, overflows: bool) -> tuple[Path, int]:
    """(run, episodes): the first published seed of ``method`` on ``row`` whose first fresh episodes end
    both ways (the fewest of at most MOST_EPISODES), or never overflow in NO_OVERFLOW_EPISODES."""
    seeds = sorted((run for run in RUNS.glob(f"{method}_{row}_s*") if run.name[len(f"{method}_{row}_s"):].isdigit()),
                   key=lambda run: int(run.name.rsplit("_s", 1)[1]))
    for run in seeds:
        protocol = dataclasses.replace(EPISODES, episodes=MOST_EPISODES if overflows else NO_OVERFLOW_EPISODES)
        ends = [e.overflow for e in evaluate_batched(policy_from_run(run), row, protocol).episodes]
        if not overflows and not any(ends):
            return run, NO_OVERFLOW_EPISODES
        if overflows:
            both = [k for k in range(2, MOST_EPISODES + 1) if set(ends[:k]) == {True, False}]
            if both:
                return run, both[0]
    raise AssertionError(f"no published {method} seed on {row} has the episode ends this comparison needs")


@pytest.mark.parametrize("method, row, overflows", COMPARED)
def test_batched_evaluation_equals_the_one_environment_evaluation(method, row, overflows):
    run, episodes = compared_run(method, row, overflows)
    policy = policy_from_run(run)
    config = json.loads((run / "args.json").read_text())["config"]
    assert config == row
    protocol = dataclasses.replace(EPISODES, episodes=episodes)
    one = evaluate(policy, config, protocol, keep_records=False)
    batched = evaluate_batched(policy, config, protocol)
    assert [e.seed for e in batched.episodes] == protocol.seeds
    assert {e.overflow for e in one.episodes} == ({False, True} if overflows else {False})
    for a, b in zip(one.episodes, batched.episodes):
        assert b.values.keys() == a.values.keys() == {m.name for m in METRICS}
        for name, x, y in [("cumulative_reward", a.cumulative_reward, b.cumulative_reward),
                           *((k, a.values[k], b.values[k]) for k in a.values)]:
            assert type(y) is type(x), (run, a.seed, name)
            if isinstance(x, float) and np.isnan(x):
                assert np.isnan(y), (run, a.seed, name)
            else:
                assert y == pytest.approx(x, rel=1e-9, abs=1e-9), (run, a.seed, name)
    assert batched.summary() == pytest.approx(one.summary(), nan_ok=True)


def test_stochastic_policies_and_policies_without_a_batched_act_are_refused():
    from containergym_marl.core.params import PlantParams
    from containergym_marl.policies import RuleBasedAgents

    policy = policy_from_run(RUNS / "fast_ppo_n11_m2_dt120_s2")
    with pytest.raises(ValueError, match="deterministic"):
        evaluate_batched(policy, "n11_m2_dt120", dataclasses.replace(EPISODES, deterministic=False))
    rule = RuleBasedAgents(PlantParams.from_config(EPISODES.plant("n5_m2_dt120")))
    with pytest.raises(ValueError, match="batched act"):
        evaluate_batched(rule, "n5_m2_dt120", EPISODES)
    with pytest.raises(ValueError, match="different number of containers"):
        evaluate_batched(policy, "n5_m2_dt120", EPISODES)
