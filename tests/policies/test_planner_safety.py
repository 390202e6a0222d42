"""The planner's deadline check (containergym_marl.policies.safety) and its shield in the planner."""

from __future__ import annotations

import math

import numpy as np
import pytest

from containergym_marl import load_config
from containergym_marl.core.dynamics import PlantState
from containergym_marl.core.params import PlantParams
from containergym_marl.evaluation import EvalProtocol, evaluate
from containergym_marl.policies import PlannerAgents, RolloutPlanner
from containergym_marl.policies.safety import DeadlineCheck, deadlines, waiting_risk

SMALL = dict(futures=4, horizon=6)


def _params(name: str = "n5_m2_dt120") -> PlantParams:
    return PlantParams.from_config(load_config(name))


def _tail(x: float) -> float:
    return 0.5 * math.erfc(x / math.sqrt(2.0))


def _state(volumes, timers_s, step: int = 100) -> PlantState:
    return PlantState(np.array([volumes], dtype=float), np.array([timers_s], dtype=float), np.array([step]))


def test_the_default_planner_is_unchanged():
    """Both views, K = 4, H = 6, a 200-step episode of n16_m2: the return and emptyings of the
    planner before the deadline check existed (main at 42cd76f), to the last bit."""
    protocol = EvalProtocol(episodes=1, episode_length_steps=200, first_seed=20_000)
    expected = {RolloutPlanner: ([35.60410729691495], [47]), PlannerAgents: ([38.58437420229669], [49])}
    for cls, (returns, emptyings) in expected.items():
        result = evaluate(cls(**SMALL), "n16_m2_dt120", protocol)
        assert result.returns.tolist() == returns
        assert [int(r.granted.sum()) for r in result.records] == emptyings


def test_waiting_risk_is_the_union_of_the_k_step_normal_tails():
    """C1-20 of n5_m2 (μδ = 0.692, σ√δ = 0.609) at 36: P(s) = Σₖ P(36 + kμδ + √k σ√δ Z >= 40)."""
    params = _params()
    mean, std = params.fill_mean_per_step[0], params.fill_std_per_step[0]
    risk = waiting_risk(np.array([36.0, 5.0, 5.0, 5.0, 5.0]), params, 6)
    by_hand = np.cumsum([_tail((40.0 - 36.0 - k * mean) / (std * math.sqrt(k))) for k in range(1, 7)])
    np.testing.assert_allclose(risk[0], np.minimum(by_hand, 1.0), rtol=1e-12)
    assert risk[0, 0] < 1e-7 < 1e-3 < risk[0, 1]  # it can wait one fill with ε = 1e-3, not two
    assert deadlines(risk, 1e-3)[0] == 1
    assert deadlines(risk, 1e-3)[1:].tolist() == [6] * 4  # at 5 units: no deadline within 6 steps


def test_the_check_sees_two_containers_due_before_a_pu_frees():
    """n5_m2, C1-20 and C1-30 at 36, PU 0 busy 1000 s, PU 1 free. Emptying C1-20 takes PU 1 for
    g = 106.8 + 264.9·⌊36/27⌋ = 371.7 s (free from step 1 + ⌈371.7/120⌉ = 5); PU 0 frees at step
    1 + ⌈880/120⌉ = 9. So C1-30 (deadline 4 fills at ε = 1e-3) waits 5 fills: unsafe. Waiting
    instead serves C1-20 (deadline 1) at step 1 and C1-30 at 1 + 5 = 6: unsafe too; emptying C1-30
    leaves C1-20 five fills: unsafe. Every choice breaks a deadline, and the check says so."""
    params = _params()
    check = DeadlineCheck(np.array([36.0, 36.0, 5.0, 5.0, 5.0]), np.array([1000.0, 0.0]), params, 1e-3, 24)
    assert check.deadline[:2].tolist() == [1, 4] and check.due.tolist()[:2] == [0, 1]
    empty_0, empty_1, wait = (np.eye(5, dtype=bool)[0], np.eye(5, dtype=bool)[1], np.zeros(5, dtype=bool))
    assert check.schedule_risk(empty_0)[1] == check.risk[1, 5 - 1]
    assert check.schedule_risk(empty_1)[0] == check.risk[0, 5 - 1]
    waiting = check.schedule_risk(wait)
    assert waiting[0] == check.risk[0, 1 - 1] and waiting[1] == check.risk[1, 6 - 1]
    assert not any(check.safe(c) for c in (empty_0, empty_1, wait))
    # with PU 0 free in 2 steps instead, emptying C1-20 now leaves C1-30 a PU at step 2 (<= 4): safe
    # a planner whose look-ahead prefers waiting takes the choice of least total schedule risk
    # (P_1(5) ≈ 0.013 against P_0(5) ≈ 0.35 and P_0(1) + P_1(6) ≈ 0.08): emptying C1-20
    planner = RolloutPlanner(**SMALL, safety_risk=1e-3)
    planner._value_candidates = lambda state, params, candidates, simulated: np.repeat(
        (~candidates.any(axis=1)).astype(float)[:, None], simulated.rewards.shape[1], axis=1)
    assert np.flatnonzero(planner.decide(_state([36.0, 36.0, 5.0, 5.0, 5.0], [1000.0, 0.0]), params)).tolist() == [0]
    assert planner.shielded == 1
    slack = DeadlineCheck(np.array([36.0, 36.0, 5.0, 5.0, 5.0]), np.array([130.0, 0.0]), params, 1e-3, 24)
    assert slack.schedule_risk(empty_0)[1] == slack.risk[1, 2 - 1] and slack.safe(empty_0)


def test_no_intervention_with_slack():
    """Low volumes and both PUs free: every candidate passes the check, and the planner with the
    check decides as the one without it, drawing the same futures."""
    params = _params()
    rng = np.random.default_rng(3)
    for _ in range(5):
        volumes = rng.uniform(15.0, 27.0, size=5)
        check = DeadlineCheck(volumes, np.zeros(2), params, 1e-4, 24)
        assert all(check.safe(c) for c in np.eye(5, dtype=bool)) and check.safe(np.zeros(5, dtype=bool))
        plain, shielded = PlannerAgents(**SMALL), PlannerAgents(**SMALL, safety_risk=1e-4)
        for p in (plain, shielded):
            p.reset(7)
        state = _state(volumes, [0.0, 0.0])
        assert plain.decide(state, params).tolist() == shielded.decide(state, params).tolist()
        assert shielded.shielded == 0


def test_the_shield_replaces_an_unsafe_look_ahead_choice(monkeypatch):
    """n5_m2, PU 0 busy 1000 s, PU 1 free; C1-50 (v* = 31.5) at its optimum and C1-60 (μδ = 0.98,
    σ√δ = 1.34) at 30, ten units from v_max with eight steps to wait for PU 0 if C1-50 takes PU 1.
    A look-ahead that prefers emptying C1-50, then C1-60, then waiting (its values stubbed) is
    overruled: C1-60 is emptied. Waiting is safe too (PU 1 stays free for C1-60), so with waiting
    preferred to C1-60 the shield waits."""
    params = _params()
    state = _state([5.0, 5.0, 5.0, 31.5, 30.0], [1000.0, 0.0])

    for c1_60, wait, expected in ((0.5, 0.0, [4]), (0.0, 0.5, [])):
        def stub(self, state, params, candidates, simulated, c1_60=c1_60, wait=wait):
            value = np.where(candidates[:, 3], 1.0, np.where(candidates[:, 4], c1_60, wait))
            return np.repeat(value[:, None], simulated.rewards.shape[1], axis=1)

        monkeypatch.setattr(RolloutPlanner, "_value_candidates", stub)
        plain = RolloutPlanner(**SMALL)
        assert np.flatnonzero(plain.decide(state, params)).tolist() == [3]
        shielded = RolloutPlanner(**SMALL, safety_risk=1e-4)
        assert np.flatnonzero(shielded.decide(state, params)).tolist() == expected
        assert shielded.shielded == 1


def test_the_container_agents_shield_weighs_sets_without_the_look_ahead_s_choice(monkeypatch):
    """n5_m2, both PUs free; C1-20 at its optimum, the one request of the base policy (stubbed) and the
    look-ahead's favourite (values stubbed); C1-50 and C1-60 half a unit below v_max, each unable to
    wait one fill (deadline 0). Every set holding C1-20 leaves one of them waiting, and waiting leaves
    both: all unsafe. Only emptying both now is safe, and the shield takes it (its earlier candidates,
    all built around the base's request, did not hold it: found on validation episode 20049 of n16_m2,
    where it let a container reach a step's overflow probability of 0.17)."""
    params = _params()
    v_max = np.asarray(params.max_volume)
    volumes = [float(params.target_volume[0]), 5.0, 5.0, v_max[3] - 0.5, v_max[4] - 0.5]
    state = _state(volumes, [0.0, 0.0])
    check = DeadlineCheck(np.array(volumes), np.zeros(2), params, 1e-4, 24)
    assert check.deadline[[3, 4]].tolist() == [0, 0]
    for around_base in ([], [0], [0, 3], [0, 4]):
        assert not check.safe(np.isin(np.arange(5), around_base)), around_base
    assert check.safe(np.isin(np.arange(5), [3, 4]))

    def values(self, state, params, candidates, simulated):
        return np.repeat(np.where(candidates[:, 0], 1.0, 0.0)[:, None], simulated.rewards.shape[1], axis=1)

    monkeypatch.setattr(PlannerAgents, "_value_candidates", values)
    shielded = PlannerAgents(**SMALL, safety_risk=1e-4)
    shielded._base = lambda state, params, limit, margin: np.repeat(  # every simulation: C1-20
        np.isin(np.arange(params.n_containers), [0])[None, :], state.volumes.shape[0], axis=0)
    assert np.flatnonzero(shielded.decide(state, params)).tolist() == [3, 4] and shielded.shielded == 1


@pytest.mark.parametrize("kwargs, field", [({"safety_risk": 0.0}, "safety_risk"),
                                           ({"safety_risk": 1.0}, "safety_risk"),
                                           ({"safety_risk": float("nan")}, "safety_risk"),
                                           ({"safety_risk": True}, "safety_risk"),
                                           ({"safety_risk": "0.01"}, "safety_risk"),
                                           ({"safety_horizon_steps": 0}, "safety_horizon_steps"),
                                           ({"safety_horizon_steps": 2.5}, "safety_horizon_steps"),
                                           ({"safety_horizon_steps": True}, "safety_horizon_steps")])
def test_bad_safety_settings_are_named(kwargs, field):
    with pytest.raises(ValueError, match=field):
        PlannerAgents(**kwargs)


def test_the_check_refuses_more_emptyings_than_free_pus():
    check = DeadlineCheck(np.full(5, 10.0), np.array([50.0, 0.0]), _params(), 1e-3, 8)
    with pytest.raises(ValueError, match="emptied"):
        check.schedule_risk(np.array([True, True, False, False, False]))


def test_the_centralised_schedule_starts_one_emptying_a_step():
    """Both PUs free, two containers that can each wait one fill (deadline 1 at ε = 1e-3), waiting now.
    The container agents can empty both at the next step (on the two PUs): both within their deadline.
    The centralised controller empties one container a step, so the second waits two fills: past its
    deadline, which the check with ``one_per_step`` sees and the one without it does not."""
    params = _params()
    first = 36.0  # C1-20: deadline 1 (test_waiting_risk_is_the_union_of_the_k_step_normal_tails)
    second = next(v for v in np.arange(30.0, 40.0, 0.05)  # C1-30 at the lowest volume with deadline 1
                  if deadlines(waiting_risk(np.array([first, v, 5.0, 5.0, 5.0]), params, 24), 1e-3)[1] == 1)
    volumes, wait = np.array([first, second, 5.0, 5.0, 5.0]), np.zeros(5, dtype=bool)
    agents = DeadlineCheck(volumes, np.zeros(2), params, 1e-3, 24)
    central = DeadlineCheck(volumes, np.zeros(2), params, 1e-3, 24, one_per_step=True)
    assert agents.deadline[:2].tolist() == central.deadline[:2].tolist() == [1, 1]
    assert agents.schedule_risk(wait)[:2].tolist() == [agents.risk[0, 0], agents.risk[1, 0]]  # both at step 1
    assert max(agents.schedule_risk(wait)[:2]) <= 1e-3
    order = central.due.tolist()[:2]  # EDF, ties riskier first: the second served at step 2
    assert central.schedule_risk(wait)[order[1]] == central.risk[order[1], 1] > 1e-3
    # emptying one of them now leaves the other the next step, in both views: within its deadline
    now = np.eye(5, dtype=bool)[order[0]]
    assert central.schedule_risk(now)[order[1]] == central.risk[order[1], 0] <= 1e-3
    # the planners: a look-ahead that prefers waiting is overruled in the centralised view (one emptying a
    # step), and in the agents' view only if waiting is unsafe there
    prefer_waiting = lambda state, params, candidates, simulated: np.repeat(  # noqa: E731
        (~candidates.any(axis=1)).astype(float)[:, None], simulated.rewards.shape[1], axis=1)
    planner, agents_planner = RolloutPlanner(**SMALL, safety_risk=1e-3), PlannerAgents(**SMALL, safety_risk=1e-3)
    for p in (planner, agents_planner):
        p._value_candidates = prefer_waiting
    assert planner.decide(_state(volumes, [0.0, 0.0]), params).sum() == 1 and planner.shielded == 1
    assert agents_planner.decide(_state(volumes, [0.0, 0.0]), params).any() == (not agents.safe(wait))
