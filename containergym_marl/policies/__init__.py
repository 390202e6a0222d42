"""Controllers: the paper's rule-based controller, a rollout planner and adapters for trained models."""

from containergym_marl.policies.learned import CentralisedModelPolicy, SharedModelPolicy
from containergym_marl.policies.planner import PlannerAgents, RolloutPlanner, ShieldedPlanner, ShieldedPlannerAgents
from containergym_marl.policies.rule_based import RuleBasedAgents, RuleBasedController

__all__ = ["CentralisedModelPolicy", "PlannerAgents", "RolloutPlanner", "RuleBasedAgents", "RuleBasedController",
           "SharedModelPolicy", "ShieldedPlanner", "ShieldedPlannerAgents"]
