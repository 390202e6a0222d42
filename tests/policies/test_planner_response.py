"""PlannerAgents.respond: each container agent's best response to the other agents' requests, by the
planner's look-ahead with the plant's arbitration (the labels of dagger_response_agents). Hand-made
states of n5_m2_dt120 (v_max = 40; container 4 fills 0.98 ± 1.34 a step) where the answer follows
from the rules: a request no free PU takes is denied and costs, and the fullest request is granted
first."""

from __future__ import annotations

import numpy as np

from containergym_marl import load_config
from containergym_marl.core.dynamics import PlantState
from containergym_marl.core.params import PlantParams
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
