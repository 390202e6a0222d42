"""Arbitration of competing emptying requests: invariants and each rule's order."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from containergym_marl import load_config
from containergym_marl.core import ARBITRATION_RULES, dynamics, emptying_rewards
from containergym_marl.core.simulator import PlantSimulator
from containergym_marl.envs.container_agents_v0 import parallel_env
from containergym_marl.core.params import PlantParams
from tests.helpers import make_state

CFG = load_config("n11_m2_dt120")
N, M = CFG.n_containers, CFG.num_processing_units


@st.composite
def contested_step(draw):
    volumes = draw(st.lists(st.floats(0.0, 39.9), min_size=N, max_size=N))
    timers = draw(st.lists(st.sampled_from([0.0, 0.0, 50.0, 300.0]), min_size=M, max_size=M))
    requests = draw(st.lists(st.booleans(), min_size=N, max_size=N))
    uniforms = draw(st.lists(st.floats(0.0, 0.999), min_size=N, max_size=N))
    rule = draw(st.sampled_from(tuple(ARBITRATION_RULES)))
    return volumes, timers, requests, uniforms, rule


@settings(max_examples=300, deadline=None)
@given(contested_step())
def test_arbitration_invariants(case):
    """Never more grants than free PUs; grants ⊆ requests; granted = min(requests, free);
    distinct free PUs; every denied request earns r_pen and stays unemptied."""
    volumes, timers, requests, uniforms, rule = case
    state = make_state(volumes, timers)
    req = np.array([requests])
    new, out = dynamics.step(state, req, PlantParams.from_config(CFG), np.zeros((1, N)), np.array([uniforms]), rule)
    free = [j for j, t in enumerate(timers) if t == 0.0]
    granted = np.flatnonzero(out.granted[0])
    assert len(granted) == min(sum(requests), len(free))
    assert np.all(req[0][granted])
    pus = out.pu_index[0, granted]
    assert len(set(pus.tolist())) == len(pus) and set(pus.tolist()) <= set(free)
    assert np.all(out.pu_index[0, ~out.granted[0]] == -1)
    denied = np.flatnonzero(out.denied[0])
    assert set(denied.tolist()) == set(np.flatnonzero(req[0]).tolist()) - set(granted.tolist())
    assert np.all(out.container_reward[0, denied] == CFG.penalty_reward)
    assert np.all(new.volumes[0, granted] == 0.0)
    assert np.all(out.container_reward[0, ~req[0]] == 0.0)


def _contest(rule, volumes, requests, free_pus, uniforms=None):
    timers = [0.0] * free_pus + [100.0] * (M - free_pus)
    u = np.zeros((1, N)) if uniforms is None else np.array([uniforms])
    _, out = dynamics.step(make_state(volumes, timers), np.array([requests]), PlantParams.from_config(CFG),
                           np.zeros((1, N)), u, rule)
    return set(np.flatnonzero(out.granted[0]).tolist())


VOLS = [10.0, 30.0, 20.0, 35.0, 5.0, 25.0, 12.0, 33.0, 8.0, 22.0, 31.0]
ALL = [True] * N


def test_fullest_grants_highest_fill_fraction():
    # all v_max are 40, so the fullest are containers 3 (35) and 7 (33)
    assert _contest("fullest", VOLS, ALL, 2) == {3, 7}
    assert _contest("fullest", VOLS, ALL, 1) == {3}
    only = [i in (0, 4, 8) for i in range(N)]
    assert _contest("fullest", VOLS, only, 2) == {0, 8}  # 10 and 8 beat 5


def test_fullest_uses_fraction_of_v_max():
    c = list(CFG.containers)
    # peaks no higher than the new v_max (a bound of the config); they play no part in "fullest"
    c[0] = type(c[0])(**{**c[0].__dict__, "max_volume": 20.0,
                         "reward_peaks": tuple(min(p, 20.0) for p in c[0].reward_peaks)})
    cfg = CFG.replace(containers=tuple(c), initial_volume_max=15.0)
    vols = [15.0, 30.0] + [0.0] * (N - 2)  # 15/20 = 0.75 beats 30/40 = 0.75? tie → lower index
    _, out = dynamics.step(make_state(vols, [0.0, 100.0]), np.array([[True, True] + [False] * (N - 2)]),
                           PlantParams.from_config(cfg), np.zeros((1, N)), np.zeros((1, N)), "fullest")
    assert out.granted[0].tolist()[:2] == [True, False]
    vols = [14.0, 30.0] + [0.0] * (N - 2)  # 0.70 < 0.75
    _, out = dynamics.step(make_state(vols, [0.0, 100.0]), np.array([[True, True] + [False] * (N - 2)]),
                           PlantParams.from_config(cfg), np.zeros((1, N)), np.zeros((1, N)), "fullest")
    assert out.granted[0].tolist()[:2] == [False, True]


def test_index_grants_lowest_indices():
    assert _contest("index", VOLS, ALL, 2) == {0, 1}
    only = [i in (3, 5, 9) for i in range(N)]
    assert _contest("index", VOLS, only, 2) == {3, 5}


def test_best_reward_grants_highest_immediate_reward():
    rewards = emptying_rewards(np.array([VOLS], dtype=float), PlantParams.from_config(CFG))[0]
    expected = set(np.argsort(-rewards, kind="stable")[:2].tolist())
    assert _contest("best_reward", VOLS, ALL, 2) == expected
    # independent check: at 27 C1-20 (index 0) earns ≈1, more than anyone at these volumes
    vols = list(VOLS)
    vols[0] = 27.0
    assert 0 in _contest("best_reward", vols, ALL, 1)


def test_ties_go_to_the_lower_index():
    equal = [20.0] * N
    assert _contest("fullest", equal, ALL, 2) == {0, 1}
    assert _contest("random", equal, ALL, 2, uniforms=[0.5] * N) == {0, 1}


def test_random_uses_the_uniform_row():
    u = [0.1] * N
    u[6], u[2] = 0.9, 0.8
    assert _contest("random", VOLS, ALL, 2, uniforms=u) == {6, 2}


def test_random_arbitration_is_fair_and_seeded():
    """3 containers always request, 1 PU: over 3000 contested steps each wins ≈ 1/3 (within 5
    standard errors); the same seed reproduces the same winners."""
    cfg = load_config("n5_m2_dt120", num_processing_units=1)
    sims = 3000
    sim = PlantSimulator(cfg, num_sims=sims, arbitration="random")
    sim.reset(generators=[np.random.default_rng(s) for s in range(sims)])
    req = np.zeros((sims, cfg.n_containers), bool)
    req[:, :3] = True
    out = sim.step(req)
    wins = out.granted[:, :3].sum(axis=0)
    assert wins.sum() == sims
    se = np.sqrt(sims * (1 / 3) * (2 / 3))
    assert np.all(np.abs(wins - sims / 3) < 5 * se), wins
    sim2 = PlantSimulator(cfg, num_sims=sims, arbitration="random")
    sim2.reset(generators=[np.random.default_rng(s) for s in range(sims)])
    np.testing.assert_array_equal(sim2.step(req).granted, out.granted)


def test_decentralised_env_reports_grants_and_denials():
    env = parallel_env(config="n11_m2_dt120", arbitration="index")
    env.reset(seed=3)
    _, rewards, _, _, infos = env.step({a: 1 for a in env.agents})
    names = env.possible_agents
    assert [infos[a]["granted"] for a in names] == [True, True] + [False] * (N - 2)
    assert [infos[a]["denied"] for a in names] == [False, False] + [True] * (N - 2)
    assert all(rewards[a] == CFG.penalty_reward for a in names[2:])
    assert {infos[names[0]]["pu_index"], infos[names[1]]["pu_index"]} == {0, 1}


def test_unknown_rule_is_rejected():
    with pytest.raises(ValueError, match="arbitration"):
        PlantSimulator(CFG, arbitration="loudest")
    with pytest.raises(ValueError, match="arbitration"):
        parallel_env(config="n5_m2_dt120", arbitration="loudest")
