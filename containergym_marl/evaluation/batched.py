"""The test protocol's episodes of a learned policy, all at once: one batched simulation of every
episode, one forward of the policy per step for all of them.

:func:`evaluate_batched` gives what :func:`~containergym_marl.evaluation.evaluate` gives for the same
policy, plant and protocol (the same per-episode metrics: simulation b is seeded with the protocol's
seed b exactly as the single environment's ``reset(seed=...)`` seeds it, and each step's actions come
from the same observations), without the episode records, at a small share of the cost: hundreds of
fresh episodes of every published model become affordable. It takes deterministic learned policies
with a batched act (``act_batch(observations, masks)``: the adapters of
:mod:`containergym_marl.policies`); rules and planners go through :func:`evaluate`.
"""

from __future__ import annotations

import numpy as np

from containergym_marl.core.dynamics import DEFAULT_ARBITRATION, overflow_probabilities
from containergym_marl.config import PlantConfig
from containergym_marl.core.observations import AgentObservations
from containergym_marl.core.simulator import PlantSimulator
from containergym_marl.envs.vector import _agent_requests, _centralised_requests
from containergym_marl.evaluation.metrics import BatchTotals, Steps
from containergym_marl.evaluation.protocol import (
    PAPER,
    EpisodeMetrics,
    EvalProtocol,
    EvaluationResult,
    check_observation_shape,
    policy_observation,
)


def evaluate_batched(policy, config: str | PlantConfig, protocol: EvalProtocol = PAPER, *,
                     arbitration: str = DEFAULT_ARBITRATION) -> EvaluationResult:
    """Every episode of ``protocol`` at once; an :class:`EvaluationResult` without records."""
    from gymnasium.utils import seeding

    if not protocol.deterministic or not getattr(policy, "deterministic", True):
        raise ValueError(f"policy {policy.name!r}: the batched evaluation takes deterministic policies only")
    if not hasattr(policy, "act_batch"):
        raise ValueError(f"policy {policy.name!r} has no batched act; evaluate it with evaluate()")
    plant = protocol.plant(config)
    episodes = protocol.episodes
    sim = PlantSimulator(plant, num_sims=episodes, arbitration=arbitration)
    params, n = sim.params, plant.n_containers
    sim.reset(generators=[seeding.np_random(seed)[0] for seed in protocol.seeds])
    # the observation variant the policy was trained on, as evaluate() builds it
    agent_obs = AgentObservations(params, policy_observation(policy), episodes) if policy.view == "decentralised" \
        else None
    _check_fits(policy, sim, plant, agent_obs)
    if hasattr(policy, "bind"):  # a policy whose rule needs the plant's description (a model's shared check)
        policy.bind(params, arbitration)

    active = np.ones(episodes, dtype=bool)  # the episode of simulation b has not ended yet
    totals, returns = BatchTotals(episodes), np.zeros(episodes)
    while active.any():
        free = sim.free_pu_count() > 0
        if policy.view == "centralised":
            obs = sim.global_state(sim.state)
            masks = np.ones((episodes, n + 1), dtype=bool)
            masks[:, 1:] = free[:, None]
            requests = _centralised_requests(np.asarray(policy.act_batch(obs, masks)), episodes, n)
        else:
            obs = agent_obs(sim.state, sim.previous_requests, sim.previous_granted).reshape(episodes * n, -1)
            masks = np.stack([np.ones(episodes * n, dtype=bool), np.repeat(free, n)], axis=1)
            requests = _agent_requests(np.asarray(policy.act_batch(obs, masks)), episodes, n)
        before = sim.state.volumes.copy()
        out = sim.step(requests)
        returns += active * out.plant_reward  # only the episodes still running
        totals.add(Steps(requested=out.requested, granted=out.granted, denied=out.denied,
                         container_reward=out.container_reward, pu_busy=sim.state.pu_timers_s > 0,
                         terminated=out.terminated,
                         overflow_probability=overflow_probabilities(before, out.granted, params)), active)
        done = out.terminated | out.truncated
        active &= ~done
        if done.any():
            sim.reset(sims=np.flatnonzero(done))  # a simulation whose episode ended steps on for nothing
            if agent_obs is not None:
                agent_obs.reset(np.flatnonzero(done))

    metrics = [EpisodeMetrics(seed, float(returns[b]), totals.values(b)) for b, seed in enumerate(protocol.seeds)]
    return EvaluationResult(policy.name, policy.view, plant.name, protocol, metrics)


def _check_fits(policy, sim: PlantSimulator, plant: PlantConfig, agent_obs: AgentObservations | None) -> None:
    size = sim.global_state(sim.state).shape[-1] if agent_obs is None else agent_obs.size
    check_observation_shape(policy, (size,), plant.name)


__all__ = ["evaluate_batched"]
