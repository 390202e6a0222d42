"""The method registry (containergym_marl.methods) is the one list that compare, the sweep, the
table and the CLI read: each method's view and kind follow from what it is, the table's pairs set a
decentralised method against a centralised one, and the CLI offers exactly the registry's choices."""

from __future__ import annotations

import pytest

from containergym_marl.algorithms import ALGORITHMS
from containergym_marl.cli import build_parser
from containergym_marl.methods import COMPARABLE, CONTROLLERS, METHODS, PAIRS, get_method
from containergym_marl.policies import (
    PlannerAgents,
    RolloutPlanner,
    RuleBasedAgents,
    RuleBasedController,
    ShieldedPlanner,
    ShieldedPlannerAgents,
)


def _choices(command: str, option: str):
    sub = build_parser()._subparsers._group_actions[0].choices[command]
    return next(a for a in sub._actions if option in a.option_strings).choices


def test_each_method_is_what_its_name_says():
    # written out by hand: the paper's rule, the planner, and the learned methods with their views
    expected = {
        "rule_based": ("rule", "centralised"), "rule_based_agents": ("rule", "decentralised"),
        "planner": ("planner", "centralised"), "planner_agents": ("planner", "decentralised"),
        "planner_shielded": ("planner", "centralised"), "planner_agents_shielded": ("planner", "decentralised"),
        "ppo": ("learned", "centralised"), "trpo": ("learned", "centralised"), "dqn": ("learned", "centralised"),
        "maskable_ppo": ("learned", "centralised"), "shared_ppo": ("learned", "decentralised"),
        "shared_ppo_team": ("learned", "decentralised"), "fast_ppo": ("learned", "centralised"),
        "fast_shared_ppo": ("learned", "decentralised"), "fast_shared_ppo_team": ("learned", "decentralised"),
        "fast_shared_ppo_checked": ("learned", "decentralised"),
        "dagger_agents": ("learned", "decentralised"), "dagger_ppo_agents": ("learned", "decentralised"),
        "dagger_response_agents": ("learned", "decentralised"), "mappo": ("learned", "decentralised"),
        "dagger_contended_agents": ("learned", "decentralised"), "dagger_dapg_agents": ("learned", "decentralised"),
        "dagger_checked_agents": ("learned", "decentralised"), "dagger_messaging_agents": ("learned", "decentralised"),
    }
    assert {name: (m.kind, m.view) for name, m in METHODS.items()} == expected
    assert CONTROLLERS == {"rule_based": RuleBasedController, "rule_based_agents": RuleBasedAgents,
                           "planner": RolloutPlanner, "planner_agents": PlannerAgents,
                           "planner_shielded": ShieldedPlanner, "planner_agents_shielded": ShieldedPlannerAgents}
    # the shielded planners are the planners with the deadline check at the setting chosen on validation episodes
    for name in ("planner_shielded", "planner_agents_shielded"):
        planner = CONTROLLERS[name]()
        assert (planner.safety_risk, planner.safety_horizon_steps, planner.futures, planner.horizon) == (1e-6, 24, 16, 8)
        assert CONTROLLERS[name](safety_risk=1e-3).safety_risk == 1e-3
    assert METHODS["planner_agents_shielded"].counterpart == "planner_shielded"
    team = METHODS["shared_ppo_team"]
    assert (team.algo, team.train_settings()) == ("shared_ppo", {"reward_mode": "team"})
    assert METHODS["ppo"].train_settings() == {}
    # the imitations of planner_agents are set against the centralised planner, as planner_agents is
    # its fine-tuning is rewarded with the plant's reward, what the planner plans for
    assert METHODS["dagger_ppo_agents"].train_settings() == {"reward_mode": "team"}
    assert {METHODS[m].counterpart for m in ("dagger_agents", "dagger_ppo_agents", "dagger_response_agents",
                                             "dagger_contended_agents", "dagger_dapg_agents", "planner_agents")
            } == {"planner"}
    assert METHODS["dagger_dapg_agents"].train_settings() == {"reward_mode": "team"}
    # the imitation of the reference is set against the centralised reference
    assert METHODS["dagger_checked_agents"].counterpart == METHODS["dagger_messaging_agents"].counterpart \
        == "planner_shielded"
    # who learns from a teacher (the planner's imitations), and who carries a fixed rule beside its network
    assert {n: m.teacher for n, m in METHODS.items() if m.teacher} == {
        **{n: "planner_agents" for n in ("dagger_agents", "dagger_ppo_agents", "dagger_response_agents",
                                         "dagger_contended_agents", "dagger_dapg_agents")},
        "dagger_checked_agents": "planner_agents_shielded", "dagger_messaging_agents": "planner_agents_shielded"}
    assert {n: m.shield for n, m in METHODS.items() if m.shield} == {
        "fast_shared_ppo_checked": "the agents' own check", "dagger_checked_agents": "the agents' own check",
        "dagger_messaging_agents": "the agents' own check and shared check"}


def test_pairs_set_a_decentralised_method_against_a_centralised_one():
    assert ("shared_ppo", "ppo") in PAIRS and ("fast_shared_ppo_team", "fast_ppo") in PAIRS and ("mappo", "ppo") in PAIRS
    for decentralised, centralised in PAIRS:
        assert (METHODS[decentralised].view, METHODS[centralised].view) == ("decentralised", "centralised")


def test_compare_runs_every_method_but_those_trained_by_a_script_of_their_own():
    assert set(COMPARABLE) == set(METHODS) - {"mappo"}
    assert {m for m in COMPARABLE if METHODS[m].learned} == {
        METHODS[m].name for m in COMPARABLE if METHODS[m].algo in ALGORITHMS}
    from containergym_marl.orchestration import CompareArgs, compare

    with pytest.raises(ValueError, match=r"mappo \(trained by baselines/train_mappo.py\)"):
        compare(CompareArgs(methods=["mappo"], seeds=[1], timesteps=64))


def test_the_cli_offers_the_registry():
    assert tuple(_choices("compare", "--methods")) == COMPARABLE
    assert tuple(_choices("train", "--algo")) == ALGORITHMS
    with pytest.raises(ValueError, match="unknown method 'a2c'"):
        get_method("a2c")
