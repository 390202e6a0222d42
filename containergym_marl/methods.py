"""Every method the package evaluates, in one registry: the rule-based controllers, the rollout
planners and the learned methods (an algorithm of :mod:`containergym_marl.algorithms` trained with a
reward mode). compare, the sweep, the results table, the CLI's choices and the docs read it.

A method says which view it acts on, how its policy comes to be (a controller built from the plant's
parameters, or a run trained by ``containergym-marl train`` or by a script of its own) and which
centralised method the table compares it with (``counterpart``: :data:`PAIRS`). Adding a method =
one entry in :data:`METHODS`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from containergym_marl.core.dynamics import DEFAULT_ARBITRATION
from containergym_marl.algorithms import AlgorithmSpec, get_algorithm
from containergym_marl.policies import RuleBasedAgents, RuleBasedController
from containergym_marl.policies.planner import PlannerAgents, RolloutPlanner, ShieldedPlanner, ShieldedPlannerAgents

#: The kinds of method: a fixed rule, a planner that simulates ahead, a learned policy.
KINDS = ("rule", "planner", "learned")


@dataclass(frozen=True)
class Method:
    """One method of the comparison.

    ``controller``: the policy class of a rule or a planner, built as ``controller(params)``;
    ``algo`` and ``reward_mode``: the algorithm and reward mode of a learned method;
    ``counterpart``: the centralised method the table compares this (decentralised) one with;
    ``twin``: the same algorithm in another implementation (SB3's for the package's own PPO), which
    this one should learn at least as well as;
    ``arbitration``: the rule that assigns free PUs to the decentralised view's requests;
    ``teacher``: the method a learned one imitates in training (None: it learns from the rewards alone);
    ``shield``: the fixed rule a learned policy carries beside its network (None: the network alone)."""

    name: str
    kind: str
    controller: type | None = None
    algo: str | None = None
    reward_mode: str | None = None
    counterpart: str | None = None
    twin: str | None = None
    arbitration: str = DEFAULT_ARBITRATION
    teacher: str | None = None
    shield: str | None = None

    @property
    def learned(self) -> bool:
        return self.kind == "learned"

    @property
    def algorithm(self) -> AlgorithmSpec | None:
        return get_algorithm(self.algo) if self.algo is not None else None

    @property
    def view(self) -> str:
        """"centralised" or "decentralised"."""
        return self.controller.view if self.controller is not None else self.algorithm.view

    @property
    def trained_here(self) -> bool:
        """Trained by ``containergym-marl train``, ``compare`` and the sweep (not by a script of its own)."""
        return self.learned and self.algorithm.trained_here

    @property
    def description(self) -> str:
        if self.controller is not None:
            return (self.controller.__doc__ or self.name).strip().splitlines()[0]
        mode = f", {self.reward_mode} reward" if self.algorithm.reward_modes else ""
        return f"{self.algorithm.description}{mode}"

    def train_settings(self) -> dict[str, Any]:
        """The TrainArgs fields this method fixes (its reward mode)."""
        return {"reward_mode": self.reward_mode} if self.reward_mode is not None else {}


def _controller(cls: type, kind: str, counterpart: str | None = None) -> Method:
    return Method(cls.name, kind, controller=cls, counterpart=counterpart)


def _learned(algo: str, reward_mode: str | None = None, counterpart: str | None = None,
             twin: str | None = None, teacher: str | None = None, shield: str | None = None) -> Method:
    """A learned method, named by its algorithm's rule (``shared_ppo`` + team = ``shared_ppo_team``)."""
    return Method(get_algorithm(algo).method_name(reward_mode), "learned", algo=algo, reward_mode=reward_mode,
                  counterpart=counterpart, twin=twin, teacher=teacher, shield=shield)


#: Every method, by name, in the order of the table's columns.
METHODS: dict[str, Method] = {m.name: m for m in (
    _controller(RuleBasedController, "rule"),
    _controller(RuleBasedAgents, "rule", counterpart="rule_based"),
    _controller(RolloutPlanner, "planner"),
    _controller(PlannerAgents, "planner", counterpart="planner"),
    # the same planners with the deadline check (policies.planner.SHIELD), beside the plain ones
    _controller(ShieldedPlanner, "planner"),
    _controller(ShieldedPlannerAgents, "planner", counterpart="planner_shielded"),
    _learned("ppo"),
    _learned("trpo"),
    _learned("dqn"),
    _learned("maskable_ppo"),
    _learned("shared_ppo", "individual", counterpart="ppo"),
    _learned("shared_ppo", "team", counterpart="ppo"),
    _learned("fast_ppo", twin="ppo"),
    _learned("fast_shared_ppo", "individual", counterpart="fast_ppo", twin="shared_ppo"),
    _learned("fast_shared_ppo", "team", counterpart="fast_ppo", twin="shared_ppo_team"),
    # reinforcement learning with a rule in the policy (policies.safety.own_deadline_due): no planner in training
    _learned("fast_shared_ppo_checked", "individual", counterpart="fast_ppo", shield="the agents' own check"),
    # imitation of planner_agents: the centralised planner is their counterpart, as planner_agents'
    _learned("dagger_agents", counterpart="planner", teacher="planner_agents"),
    _learned("dagger_ppo_agents", "team", counterpart="planner", teacher="planner_agents"),
    _learned("dagger_response_agents", counterpart="planner", teacher="planner_agents"),
    _learned("dagger_contended_agents", counterpart="planner", teacher="planner_agents"),
    _learned("dagger_dapg_agents", "team", counterpart="planner", teacher="planner_agents"),
    # the imitation of the reference, with the agents' own check beside its network
    _learned("dagger_checked_agents", counterpart="planner_shielded", teacher="planner_agents_shielded",
             shield="the agents' own check"),
    # the same with one message per agent and step and the rule all apply to them (policies.shared_check)
    _learned("dagger_messaging_agents", counterpart="planner_shielded", teacher="planner_agents_shielded",
             shield="the agents' own check and shared check"),
    _learned("mappo", "team", counterpart="ppo"),  # trained by baselines/train_mappo.py; compare reads its files
)}
#: The controllers (rules and planners) by name: what ``containergym-marl evaluate NAME`` builds.
CONTROLLERS: dict[str, type] = {m.name: m.controller for m in METHODS.values() if m.controller is not None}
#: The methods ``compare`` can run: every controller, and every learned method it trains itself.
COMPARABLE: tuple[str, ...] = tuple(m.name for m in METHODS.values() if not m.learned or m.trained_here)
#: (decentralised, centralised) pairs whose probability of improvement the table reports.
PAIRS: tuple[tuple[str, str], ...] = tuple((m.name, m.counterpart) for m in METHODS.values() if m.counterpart)
#: (method, twin) pairs: the package's own implementation of an algorithm and another one of it.
TWINS: tuple[tuple[str, str], ...] = tuple((m.name, m.twin) for m in METHODS.values() if m.twin)


def get_method(name: str) -> Method:
    """The registry entry of ``name``; a ValueError naming the choices for an unknown one."""
    try:
        return METHODS[name]
    except (KeyError, TypeError):
        raise ValueError(f"method: unknown method {name!r}; choose one of {tuple(METHODS)}") from None


__all__ = ["COMPARABLE", "CONTROLLERS", "KINDS", "METHODS", "PAIRS", "TWINS", "Method", "get_method"]
