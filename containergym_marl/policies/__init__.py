"""Controllers: the paper's rule-based controller and adapters for trained models."""

from containergym_marl.policies.learned import CentralisedModelPolicy, SharedModelPolicy
from containergym_marl.policies.rule_based import RuleBasedAgents, RuleBasedController

__all__ = ["CentralisedModelPolicy", "RuleBasedAgents", "RuleBasedController", "SharedModelPolicy"]
