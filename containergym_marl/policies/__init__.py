"""Non-learned controllers."""

from containergym_marl.policies.rule_based import RuleBasedAgents, RuleBasedController

__all__ = ["RuleBasedAgents", "RuleBasedController"]
