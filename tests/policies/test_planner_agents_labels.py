"""PlannerAgents.respond: each container agent's best response to the other agents' requests, by the
planner's look-ahead with the plant's arbitration (the labels of dagger_response_agents). Hand-made
states of n5_m2_dt120 (v_max = 40; container 4 fills 0.98 ± 1.34 a step) where the answer follows
from the rules: a request no free PU takes is denied and costs, and the fullest request is granted
first. And PlannerAgents.contended, the states dagger_contended_agents oversamples: by hand, and
their share of the planner's own steps."""

from __future__ import annotations

import numpy as np
import pytest

from containergym_marl import load_config
from containergym_marl.core.dynamics import PlantState
from containergym_marl.core.params import PlantParams
from containergym_marl.envs.container_agents_v0 import parallel_env
from containergym_marl.policies import PlannerAgents

PARAMS = PlantParams.from_config(load_config("n5_m2_dt120"))
ONE_FREE = [0.0, 100.0]  # PU 1 busy for 100 s more


def _state(volumes, timers_s, step: int = 100) -> PlantState:
    return PlantState(np.array([volumes], dtype=float), np.array([timers_s], dtype=float), np.array([step]))


def _respond(volumes, timers_s, requested) -> list[int]:
    planner = PlannerAgents()
    planner.reset(1)
    return np.flatnonzero(planner.respond(_state(volumes, timers_s), PARAMS, np.isin(np.arange(5), requested))).tolist()


def test_the_container_about_to_overflow_requests_and_no_one_else_whatever_the_others_asked():
    """Container 4 one unit below v_max (about even odds of overflowing at the next fill), the rest
    nearly empty, one PU free. Whether nobody, container 4 alone, or 4 and container 0 request: 4's
    best response is to request (without it the free PU stays idle or empties container 0, and 4
    overflows); every other container's is not to (its request is denied where 4 requests, being
    less full, and where 4 does not it would take the PU that 4 needs)."""
    volumes = [20.0, 5.0, 5.0, 5.0, 39.0]
    for requested in ([], [4], [0, 4], [0]):
        assert _respond(volumes, ONE_FREE, requested) == [4], requested


def test_two_containers_past_their_optimum_both_request_when_two_pus_are_free():
    """Containers 0 and 4 a unit below v_max and both PUs free: each one's request is granted whatever
    the other does, so each requests, asked together or alone."""
    volumes = [39.0, 5.0, 5.0, 5.0, 39.0]
    for requested in ([], [0], [4], [0, 4]):
        assert _respond(volumes, [0.0, 0.0], requested) == [0, 4], requested


def test_no_free_pu_means_no_request_and_no_look_ahead():
    planner = PlannerAgents()
    planner.reset(1)
    state = _state([39.0, 5.0, 5.0, 5.0, 39.0], [50.0, 100.0])
    assert not planner.respond(state, PARAMS, np.ones(5, dtype=bool)).any()
    assert planner.planned == 0 and planner.decisions == 1


def test_contended_states_are_those_with_more_containers_worth_emptying_than_free_pus():
    """PlannerAgents.contended (the states dagger_contended_agents oversamples), on a batch of hand-made
    states: a container is due within 1 unit below its optimum or past it (v* = 27, 25, 25.5, 31.5,
    25), not merely where emptying it earns something (container 1 at 20 earns 0.049); the state is
    contended when at least one PU is free and due containers outnumber them."""
    cases = [  # (volumes, PU timers, contended)
        ([27.0, 25.0, 5.0, 5.0, 5.0], [0.0, 0.0], False),  # two worth emptying, two PUs free
        ([27.0, 25.0, 5.0, 5.0, 5.0], ONE_FREE, True),  # two for one PU
        ([27.0, 25.0, 25.5, 5.0, 5.0], [0.0, 0.0], True),  # three for two
        ([27.0, 25.0, 25.5, 5.0, 5.0], [50.0, 100.0], False),  # no PU free: nothing to contest
        ([5.0, 5.0, 5.0, 5.0, 5.0], ONE_FREE, False),  # nobody worth emptying
        ([5.0, 20.0, 5.0, 5.0, 39.0], ONE_FREE, False),  # 1 earns 0.049 at 20 but is not due: only 4
        ([5.0, 24.0, 5.0, 5.0, 39.0], ONE_FREE, True),  # 1 a unit below its optimum, 4 past it
    ]
    state = PlantState(np.array([c[0] for c in cases]), np.array([c[1] for c in cases]), np.full(len(cases), 100))
    assert PlannerAgents().contended(state, PARAMS).tolist() == [c[2] for c in cases]


@pytest.mark.parametrize("config", ["n11_m2_dt120", "n16_m2_dt120"])
def test_contended_states_are_a_few_percent_of_planner_agents_steps(config):
    """One validation episode (seed 20000) of planner_agents on a contended plant: the contended steps
    (what the docs call a few percent) are between 0.2 % and 6 % of its steps, where counting every
    container that merely earns something (decide's eligible ones) would make a third or more."""
    env = parallel_env(config)
    planner = PlannerAgents()
    planner.reset(20000)
    observations, _ = env.reset(seed=20000)
    contended = broad = steps = 0
    while env.agents:
        sim = env.unwrapped.simulator
        free = int((sim.state.pu_timers_s[0] == 0.0).sum())
        contended += int(planner.contended(sim.state, sim.params)[0])
        broad += int(free >= 1 and planner._eligible(sim.state.volumes[:1], sim.params).sum() > free)
        steps += 1
        observations, *_ = env.step(planner.act(observations, env))
    assert steps > 300 and 0.002 < contended / steps < 0.06 and broad / steps > 0.3, (contended, broad, steps)
