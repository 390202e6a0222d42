"""Tests of the decentralised PettingZoo view (``container_agents_v0``).

Expected observations and rewards are computed here by hand from the config's per-container fields
and the simulator's state, not with the package's observation or reward functions.
"""

from __future__ import annotations

import contextlib
import math
import tomllib
import warnings
from importlib import resources

import numpy as np
import pytest
from gymnasium import spaces
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test, seed_test, state_test

from containergym_marl import load_config
from containergym_marl.core import EpisodeFinishedError
from containergym_marl.envs import container_agents_v0
from containergym_marl.envs.centralised import ContainerGymEnv
from containergym_marl.envs.container_agents_v0 import env as aec_env
from containergym_marl.envs.container_agents_v0 import parallel_env, raw_env
from tests.reference_model import busy_time, paper_reward

from tests.helpers import CFG
AGENT_NAME_WARNING = 'We recommend agents to be named in the format <descriptor>_<number>, like "player_0"'
READY_MARGIN = 1.0  # documented: "within 1 volume unit of their target or past it"
N_SCALARS = 12


# ---- independent helpers ------------------------------------------------------------------------
def target_volume(spec) -> float:
    best = 0
    for k, h in enumerate(spec.reward_heights):
        if h > spec.reward_heights[best]:
            best = k
    return spec.reward_peaks[best]


def toml_names(name: str) -> list[str]:
    text = (resources.files("containergym_marl.configs") / f"{name}.toml").read_text(encoding="utf-8")
    return [c["name"] for c in tomllib.loads(text)["containers"]]


def expected_observations(env, prev_requests) -> np.ndarray:
    """(n, 12 + m + n) observations computed by hand from the simulator state and the config."""
    cfg = env.config
    specs = cfg.containers
    n, m = cfg.n_containers, cfg.num_processing_units
    dt = cfg.timestep_s
    v = env.simulator.state.volumes[0]
    p = env.simulator.state.pu_timers_s[0]
    vmax = np.array([c.max_volume for c in specs])
    vstar = np.array([target_volume(c) for c in specs])
    max_pu = max(c.pu_offset_s + c.pu_time_per_product_s * math.floor(c.max_volume / c.product_size) for c in specs)
    others = max(n - 1, 1)
    frac = v / vmax
    ready = v >= vstar - READY_MARGIN
    req = np.asarray(prev_requests, dtype=bool)
    out = np.zeros((n, N_SCALARS + m + n))
    for i, c in enumerate(specs):
        out[i, 0] = min(max(v[i] / vmax[i], 0.0), 2.0)
        out[i, 1] = vstar[i] / vmax[i]
        out[i, 2] = min(max((vstar[i] - v[i]) / vmax[i], -2.0), 1.0)
        out[i, 3] = vmax[i] / vmax.max()
        out[i, 4] = min(c.fill_rate_per_s * dt / vmax[i], 1.0)
        out[i, 5] = min(c.fill_noise_per_sqrt_s * math.sqrt(dt) / vmax[i], 1.0)
        out[i, 6] = min(c.product_size / vmax[i], 1.0)
        out[i, 7] = min(max(paper_reward(c, v[i], cfg.penalty_reward), cfg.penalty_reward), 1.0)
        out[i, 8] = np.count_nonzero(p == 0.0) / m
        out[i, 9] = (req.sum() - req[i]) / others
        out[i, 10] = (ready.sum() - ready[i]) / others
        out[i, 11] = sum(frac[j] > frac[i] for j in range(n)) / others
        out[i, N_SCALARS : N_SCALARS + m] = np.minimum(p / max_pu, 1.0)
        out[i, N_SCALARS + m + i] = 1.0
    return out


def random_actions(rng, agents, p_request=0.5):
    return {a: int(rng.random() < p_request) for a in agents}


def sim_snapshot(env):
    st = env.simulator.state
    return (st.volumes.copy(), st.pu_timers_s.copy(), st.step_count.copy(),
            env.simulator.previous_requests.copy(), list(env.agents))


def assert_nested_equal(a, b, path="") -> None:
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), path
        for k in a:
            assert_nested_equal(a[k], b[k], f"{path}/{k}")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype, path
        np.testing.assert_array_equal(a, b, err_msg=path)
    else:
        assert type(a) is type(b) and a == b, (path, a, b)


@contextlib.contextmanager
def no_warnings_but_agent_names():
    """Turn every warning into an error, except PettingZoo's agent-naming recommendation (our
    agents are named after their containers on purpose)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", message=AGENT_NAME_WARNING, category=UserWarning)
        yield


# ---- PettingZoo's own checks ---------------------------------------------------------------------
PZ_VARIANTS = [
    {},
    {"action_masking": True},
    {"arbitration": "random", "reward_mode": "team"},
    {"episode_length_steps": 7},  # several episode ends within the test's cycles
    {"initial_volume_min": 39.0, "initial_volume_max": 39.9},  # overflow at once
]


@pytest.mark.parametrize("kwargs", PZ_VARIANTS, ids=lambda k: ",".join(k) or "default")
def test_parallel_api_test(kwargs):
    with no_warnings_but_agent_names():
        parallel_api_test(parallel_env(config=CFG, **kwargs), num_cycles=100)


@pytest.mark.parametrize("kwargs", PZ_VARIANTS, ids=lambda k: ",".join(k) or "default")
def test_aec_api_test(kwargs):
    with no_warnings_but_agent_names():
        api_test(aec_env(config=CFG, **kwargs), num_cycles=30)


def test_aec_api_test_emits_only_the_agent_name_warning():
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        api_test(aec_env(config=CFG, action_masking=True), num_cycles=10)
    messages = {str(w.message) for w in rec}
    assert messages == {AGENT_NAME_WARNING}


def test_seed_test_aec_with_random_arbitration():
    with no_warnings_but_agent_names():
        seed_test(lambda: aec_env(config=CFG, arbitration="random"), num_cycles=100)


def test_parallel_seed_test_with_random_arbitration():
    with no_warnings_but_agent_names():
        parallel_seed_test(lambda: parallel_env(config=CFG, arbitration="random"), num_cycles=100)


def test_state_test():
    with no_warnings_but_agent_names():
        state_test(aec_env(config=CFG), parallel_env(config=CFG))


def test_raw_env_and_env_expose_same_agents():
    raw = raw_env(config=CFG)
    wrapped = aec_env(config=CFG)
    assert list(raw.possible_agents) == list(wrapped.possible_agents) == toml_names(CFG)
    assert container_agents_v0.parallel_env is parallel_env


# ---- determinism ----------------------------------------------------------------------------------
@pytest.mark.parametrize("arbitration", ["fullest", "random"])
def test_same_seed_same_actions_give_identical_steps(arbitration):
    e1 = parallel_env(config=CFG, arbitration=arbitration, action_masking=True)
    e2 = parallel_env(config=CFG, arbitration=arbitration, action_masking=True)
    o1, i1 = e1.reset(seed=42)
    o2, i2 = e2.reset(seed=42)
    assert_nested_equal(o1, o2)
    assert_nested_equal(i1, i2)
    rng = np.random.default_rng(0)
    steps = 0
    while e1.agents and steps < 200:
        actions = random_actions(rng, e1.agents, p_request=0.3)
        r1 = e1.step(actions)
        r2 = e2.step(dict(actions))
        for x, y in zip(r1, r2):
            assert_nested_equal(x, y)
        np.testing.assert_array_equal(e1.state(), e2.state())
        assert e1.agents == e2.agents
        steps += 1
    assert steps >= 50


def test_different_seeds_differ():
    e1, e2 = parallel_env(config=CFG), parallel_env(config=CFG)
    o1, _ = e1.reset(seed=1)
    o2, _ = e2.reset(seed=2)
    assert not np.array_equal(e1.state(), e2.state())
    assert any(not np.array_equal(o1[a], o2[a]) for a in e1.agents)
    zeros = {a: 0 for a in e1.agents}
    e1.step(zeros)
    e2.step(zeros)
    assert not np.array_equal(e1.state(), e2.state())


def test_reset_without_seed_continues_stream():
    e1, e2 = parallel_env(config=CFG), parallel_env(config=CFG)
    e1.reset(seed=7)
    s1 = e1.state()
    e1.reset()
    s2 = e1.state()
    assert not np.array_equal(s1, s2)
    e2.reset(seed=7)
    e2.reset()
    np.testing.assert_array_equal(e2.state(), s2)


# ---- agents and spaces ----------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["n5_m2_dt120", "n11_m2_dt60", "n16_m2_dt120"])
def test_possible_agents_are_container_names_and_fixed(name):
    e = parallel_env(config=name)
    expected = toml_names(name)
    assert e.possible_agents == expected == list(e.config.container_names)
    assert e.agents == []
    e.reset(seed=0)
    assert e.agents == expected
    e.step({a: 0 for a in e.agents})
    assert e.agents == expected
    assert e.possible_agents == expected


def test_agents_empty_after_truncation():
    e = parallel_env(config=CFG, episode_length_steps=3)
    e.reset(seed=0)
    for t in range(3):
        assert len(e.agents) == 5
        _, rewards, terms, truncs, infos = e.step({a: 0 for a in e.agents})
        assert set(rewards) == set(terms) == set(truncs) == set(infos) == set(e.possible_agents)
        assert all(v is False for v in terms.values())
        assert all(v is (t == 2) for v in truncs.values())
    assert e.agents == []
    assert e.possible_agents == toml_names(CFG)


def test_observation_and_action_spaces():
    e = parallel_env(config=CFG)
    n, m = 5, 2
    first = e.observation_space(e.possible_agents[0])
    for a in e.possible_agents:
        sp = e.observation_space(a)
        assert sp is e.observation_space(a)
        assert isinstance(sp, spaces.Box)
        assert sp == first
        assert sp.dtype == np.float32
        assert sp.shape == (N_SCALARS + m + n,)
        act = e.action_space(a)
        assert act is e.action_space(a)
        assert act == spaces.Discrete(2)
    assert len(e.feature_names()) == N_SCALARS + m + n
    assert len(set(e.feature_names())) == len(e.feature_names())


@pytest.mark.parametrize("method", ["observation_space", "action_space"])
def test_unknown_agent_in_space_lookup_raises_key_error(method):
    e = parallel_env(config=CFG)
    with pytest.raises(KeyError, match="ghost_7"):
        getattr(e, method)("ghost_7")


@pytest.mark.parametrize("p_request", [0.5, 0.02])
def test_every_observation_lies_in_its_space_during_long_rollout(p_request):
    e = parallel_env(config=CFG)
    rng = np.random.default_rng(1)
    obs, _ = e.reset(seed=3)
    steps = 0
    while True:
        for a, o in obs.items():
            assert o.dtype == np.float32
            assert e.observation_space(a).contains(o), (a, o)
        assert e.state_space.contains(e.state())
        if not e.agents:
            break
        obs, *_ = e.step(random_actions(rng, e.agents, p_request))
        steps += 1
    assert steps >= 20


def test_metadata():
    md = parallel_env(config=CFG).metadata
    assert md["name"] == "container_agents_v0"
    assert md["render_modes"] == ["human", "rgb_array", "ansi"]
    assert md["is_parallelizable"] is True
    assert aec_env(config=CFG).metadata["name"] == "container_agents_v0"


# ---- state and observations -----------------------------------------------------------------------
def test_state_is_global_volumes_and_timers():
    e = parallel_env(config=CFG)
    rng = np.random.default_rng(5)
    e.reset(seed=0)
    assert isinstance(e.state_space, spaces.Box) and e.state_space.dtype == np.float32
    assert e.state_space.shape == (5 + 2,)
    for _ in range(40):
        st = e.simulator.state
        expected = np.concatenate([st.volumes[0], st.pu_timers_s[0]]).astype(np.float32)
        s = e.state()
        assert s.dtype == np.float32
        np.testing.assert_array_equal(s, expected)
        assert e.state_space.contains(s)
        if not e.agents:  # the terminal state was checked too
            break
        e.step(random_actions(rng, e.agents, 0.3))


def _single_container_config():
    cfg = load_config(CFG)
    return cfg.replace(containers=(cfg.containers[1],), name="n1_m2")


@pytest.mark.parametrize("name", ["n5_m2_dt120", "n16_m2_dt120", "n5_m5_dt60", "n1"])
def test_observation_entries_match_hand_computation(name):
    e = parallel_env(config=_single_container_config() if name == "n1" else name)
    n = e.config.n_containers
    rng = np.random.default_rng(0)
    obs, _ = e.reset(seed=0)
    prev = np.zeros(n, dtype=bool)
    for _ in range(25):
        exp = expected_observations(e, prev)
        for i, a in enumerate(e.possible_agents):
            np.testing.assert_allclose(obs[a], exp[i], rtol=1e-5, atol=1e-6, err_msg=f"{a}: {e.feature_names()}")
        actions = random_actions(rng, e.agents, 0.25)
        prev = np.array([actions[a] == 1 for a in e.possible_agents])
        obs, *_ = e.step(actions)
        if not e.agents:
            break


def test_observation_one_hot_and_timer_layout():
    e = parallel_env(config=CFG)
    n, m = 5, 2
    names = e.feature_names()
    assert names[8] == "free_pu_frac"
    assert names[N_SCALARS] == "pu_timer_frac[0]"
    obs, _ = e.reset(seed=0)
    for i, a in enumerate(e.possible_agents):
        np.testing.assert_array_equal(obs[a][N_SCALARS + m :], np.eye(n, dtype=np.float32)[i])
        assert obs[a][8] == 1.0
        np.testing.assert_array_equal(obs[a][N_SCALARS : N_SCALARS + m], [0.0, 0.0])
    # Agent 0 (v = 29.3 > b) requests: PU 0 busy for β + λ seconds, half the PUs free.
    spec = e.config.containers[0]
    v0 = float(e.simulator.state.volumes[0, 0])
    obs, *_ = e.step({a: int(a == e.possible_agents[0]) for a in e.agents})
    max_pu = max(c.pu_offset_s + c.pu_time_per_product_s * math.floor(c.max_volume / c.product_size)
                 for c in e.config.containers)
    for a in e.possible_agents:
        assert obs[a][8] == pytest.approx(0.5)
        assert obs[a][N_SCALARS] == pytest.approx(busy_time(spec, v0) / max_pu, rel=1e-6)
        assert obs[a][N_SCALARS + 1] == 0.0
    assert obs[e.possible_agents[0]][0] == 0.0


# ---- errors -----------------------------------------------------------------------------------------
def _fresh(seed=0, **kw):
    e = parallel_env(config=CFG, **kw)
    e.reset(seed=seed)
    e.step({a: 0 for a in e.agents})
    return e


def _assert_failed_step_harmless(e, bad_actions, exc, match):
    twin = _fresh()
    before = sim_snapshot(e)
    with pytest.raises(exc, match=match):
        e.step(bad_actions)
    after = sim_snapshot(e)
    for x, y in zip(before, after):
        if isinstance(x, np.ndarray):
            np.testing.assert_array_equal(x, y)
        else:
            assert x == y
    good = {a: int(i % 2 == 0) for i, a in enumerate(e.possible_agents)}
    r1, r2 = e.step(good), twin.step(dict(good))
    for x, y in zip(r1, r2):
        assert_nested_equal(x, y)


def test_step_before_reset_raises():
    e = parallel_env(config=CFG)
    with pytest.raises(EpisodeFinishedError):
        e.step({a: 0 for a in e.possible_agents})


def test_unknown_agent_in_actions_raises_key_error():
    e = _fresh()
    actions = {a: 0 for a in e.agents}
    actions["ghost_7"] = 1
    _assert_failed_step_harmless(e, actions, KeyError, "ghost_7")


def test_missing_live_agent_raises_key_error():
    e = _fresh()
    actions = {a: 1 for a in e.agents}
    del actions["C1-60"]
    _assert_failed_step_harmless(e, actions, KeyError, "C1-60")


BAD_AGENT_ACTIONS = [2, -1, 1.5, 1.0, True, np.bool_(False), "1", None, np.array([0, 1]), np.array(1.0)]


@pytest.mark.parametrize("bad", BAD_AGENT_ACTIONS, ids=[repr(b) for b in BAD_AGENT_ACTIONS])
def test_invalid_agent_action_raises_naming_agent(bad):
    e = _fresh()
    # Earlier agents make valid requests; the bad action belongs to the last agent.
    actions = {a: 1 for a in e.agents}
    actions["C1-80"] = bad
    _assert_failed_step_harmless(e, actions, (ValueError, TypeError), "C1-80")


@pytest.mark.parametrize("value", [np.int64(1), np.int32(1), np.array(1), 1])
def test_integer_like_agent_actions_accepted(value):
    e, ref = _fresh(), _fresh()
    r1 = e.step({a: (value if a == "C1-30" else 0) for a in e.agents})
    r2 = ref.step({a: int(a == "C1-30") for a in ref.agents})
    for x, y in zip(r1, r2):
        assert_nested_equal(x, y)
    assert r1[4]["C1-30"]["granted"] is True


@pytest.mark.parametrize("bad", [[0, 0, 0, 0, 0], (0,) * 5, None, np.zeros(5, dtype=np.int64)],
                         ids=["list", "tuple", "None", "array"])
def test_non_dict_actions_raise_type_error(bad):
    e = _fresh()
    _assert_failed_step_harmless(e, bad, TypeError, "dict")


def test_step_after_episode_end_raises_until_reset():
    e = parallel_env(config=CFG, episode_length_steps=2)
    e.reset(seed=0)
    e.step({a: 0 for a in e.agents})
    e.step({a: 0 for a in e.agents})
    with pytest.raises(EpisodeFinishedError):
        e.step({a: 0 for a in e.possible_agents})
    e.reset(seed=0)
    _, _, terms, truncs, _ = e.step({a: 0 for a in e.agents})
    assert not any(terms.values()) and not any(truncs.values())


@pytest.mark.parametrize("kw", [{"reward_mode": "selfish"}, {"arbitration": "loudest"}, {"render_mode": "bogus"}])
def test_invalid_constructor_arguments_raise_value_error(kw):
    key = next(iter(kw))
    with pytest.raises(ValueError, match=key):
        parallel_env(config=CFG, **kw)


# ---- action masking ---------------------------------------------------------------------------------
def test_action_mask_follows_free_pus():
    e = parallel_env(config=CFG, action_masking=True, num_processing_units=1)
    dt = e.config.timestep_s
    _, infos = e.reset(seed=0)
    for a in e.agents:
        mask = infos[a]["action_mask"]
        assert mask.dtype == np.int8
        np.testing.assert_array_equal(mask, [1, 1])
    g = busy_time(e.config.containers[0], float(e.simulator.state.volumes[0, 0]))
    _, rewards, _, _, infos = e.step({a: int(a == "C1-20") for a in e.agents})
    assert infos["C1-20"]["granted"] is True
    for a in e.agents:
        assert infos[a]["action_mask"].dtype == np.int8
        np.testing.assert_array_equal(infos[a]["action_mask"], [1, 0])
    # A request while masked is denied with r_pen.
    _, rewards, _, _, infos = e.step({a: int(a == "C1-30") for a in e.agents})
    assert infos["C1-30"]["denied"] is True and infos["C1-30"]["granted"] is False
    assert infos["C1-30"]["pu_index"] == -1
    assert rewards["C1-30"] == e.config.penalty_reward
    assert all(rewards[a] == 0.0 for a in e.agents if a != "C1-30")
    for a in e.agents:
        np.testing.assert_array_equal(infos[a]["action_mask"], [1, 0])
    # The PU's timer is g after step 1 and g − (k−1)·δ after step k: busy through step ⌈g/δ⌉.
    steps_busy = math.ceil(g / dt)
    assert steps_busy >= 3
    for k in range(3, steps_busy + 1):
        _, _, _, _, infos = e.step({a: 0 for a in e.agents})
        assert e.simulator.state.pu_timers_s[0, 0] == pytest.approx(g - (k - 1) * dt)
        for a in e.agents:
            np.testing.assert_array_equal(infos[a]["action_mask"], [1, 0])
    _, _, _, _, infos = e.step({a: 0 for a in e.agents})
    assert e.simulator.state.pu_timers_s[0, 0] == 0.0
    for a in e.agents:
        np.testing.assert_array_equal(infos[a]["action_mask"], [1, 1])


def test_no_action_mask_without_masking():
    e = parallel_env(config=CFG)
    _, infos = e.reset(seed=0)
    assert all("action_mask" not in i for i in infos.values())
    _, _, _, _, infos = e.step({a: 0 for a in e.agents})
    assert all("action_mask" not in i for i in infos.values())


# ---- rewards, arbitration and the link to the centralised view ---------------------------------------
def test_granted_request_gets_paper_reward_and_pu_timer():
    e = parallel_env(config=CFG)
    e.reset(seed=0)
    cfg = e.config
    v = e.simulator.state.volumes[0].copy()
    actions = {a: int(a in ("C1-20", "C1-70")) for a in e.agents}
    _, rewards, _, _, infos = e.step(actions)
    for i, a in enumerate(e.possible_agents):
        spec = cfg.containers[i]
        if actions[a]:
            assert infos[a]["granted"] is True
            assert rewards[a] == pytest.approx(paper_reward(spec, v[i], cfg.penalty_reward), rel=1e-9)
            assert infos[a]["emptying_reward"] == pytest.approx(rewards[a])
            assert infos[a]["emptied_volume"] == pytest.approx(v[i], rel=1e-12)
            pu = infos[a]["pu_index"]
            assert e.simulator.state.pu_timers_s[0, pu] == pytest.approx(busy_time(spec, v[i]))
            assert e.simulator.state.volumes[0, i] == 0.0
        else:
            assert rewards[a] == 0.0
            assert infos[a]["requested"] is False and infos[a]["pu_index"] == -1
            assert infos[a]["emptied_volume"] == 0.0
        assert infos[a]["free_pus"] == 2
        assert infos[a]["step"] == 1
    # Both PUs were free: the two grants use distinct PUs.
    assert {infos["C1-20"]["pu_index"], infos["C1-70"]["pu_index"]} == {0, 1}


@pytest.mark.parametrize("arbitration", ["fullest", "index", "best_reward", "random"])
def test_arbitration_with_one_free_pu(arbitration):
    # seed 0 volumes: C1-20 ≈ 29.3 (fuller, lower reward), C1-80 ≈ 25.9 (closer to its peak 25).
    e = parallel_env(config=CFG, num_processing_units=1, arbitration=arbitration)
    e.reset(seed=0)
    cfg = e.config
    v = e.simulator.state.volumes[0]
    i20, i80 = 0, 4
    r20 = paper_reward(cfg.containers[i20], v[i20], cfg.penalty_reward)
    r80 = paper_reward(cfg.containers[i80], v[i80], cfg.penalty_reward)
    assert v[i20] > v[i80] and r80 > r20  # the scenario distinguishes the rules
    _, rewards, _, _, infos = e.step({a: int(a in ("C1-20", "C1-80")) for a in e.agents})
    winner = {"fullest": "C1-20", "index": "C1-20", "best_reward": "C1-80"}.get(arbitration)
    granted = [a for a in ("C1-20", "C1-80") if infos[a]["granted"]]
    assert len(granted) == 1
    if winner is not None:
        assert granted == [winner]
    loser = "C1-80" if granted == ["C1-20"] else "C1-20"
    assert infos[loser]["denied"] is True
    assert rewards[loser] == cfg.penalty_reward
    assert rewards[granted[0]] == pytest.approx(r20 if granted == ["C1-20"] else r80)


def test_team_reward_is_sum_of_individual_rewards():
    ind = parallel_env(config=CFG, reward_mode="individual")
    team = parallel_env(config=CFG, reward_mode="team")
    ind.reset(seed=8)
    team.reset(seed=8)
    rng = np.random.default_rng(3)
    saw_denial = False
    steps = 0
    while ind.agents and steps < 300:
        actions = random_actions(rng, ind.agents, 0.4)
        _, ri, ti, _, ii = ind.step(actions)
        _, rt, tt, _, it = team.step(dict(actions))
        values = set(rt.values())
        assert len(values) == 1
        if any(ti.values()):
            assert values == {ind.config.overflow_reward}
        else:
            assert values.pop() == pytest.approx(sum(ri.values()), abs=1e-12)
        saw_denial |= any(i["denied"] for i in ii.values())
        np.testing.assert_array_equal(ind.state(), team.state())
        steps += 1
    assert saw_denial  # the sums included r_pen penalties


def test_team_mode_matches_centralised_view():
    par = parallel_env(config=CFG, reward_mode="team")
    cen = ContainerGymEnv(CFG)
    cobs, _ = cen.reset(seed=21)
    par.reset(seed=21)
    np.testing.assert_array_equal(par.state(), cobs)
    rng = np.random.default_rng(4)
    for _ in range(150):
        a = int(rng.integers(0, 6))
        cobs, creward, cterm, ctrunc, cinfo = cen.step(a)
        actions = {name: int(k + 1 == a) for k, name in enumerate(par.possible_agents)}
        _, rewards, terms, truncs, infos = par.step(actions)
        np.testing.assert_array_equal(par.state(), cobs)
        assert all(r == creward for r in rewards.values())
        assert all(t is cterm for t in terms.values())
        assert all(t is ctrunc for t in truncs.values())
        if cterm or ctrunc:
            break


# ---- overflow -----------------------------------------------------------------------------------------
OVERFLOW_KW = {"initial_volume_min": 39.0, "initial_volume_max": 39.9}


@pytest.mark.parametrize("reward_mode", ["individual", "team"])
def test_overflow_terminates_everyone(reward_mode):
    e = parallel_env(config=CFG, reward_mode=reward_mode, **OVERFLOW_KW)
    cfg = e.config
    e.reset(seed=0)
    for _ in range(50):
        _, rewards, terms, truncs, infos = e.step({a: 0 for a in e.agents})
        if any(terms.values()):
            break
    assert set(terms) == set(e.possible_agents)
    assert all(t is True for t in terms.values())
    assert all(t is False for t in truncs.values())
    vmax = np.array([c.max_volume for c in cfg.containers])
    over = e.simulator.state.volumes[0] >= vmax
    assert over.any() and not over.all()  # seed 0: some, not all containers overflow
    for i, a in enumerate(e.possible_agents):
        assert infos[a]["overflowed"] is bool(over[i])
        if reward_mode == "team":
            assert rewards[a] == cfg.overflow_reward
        else:
            assert rewards[a] == (cfg.overflow_reward if over[i] else 0.0)
    assert e.agents == []
    with pytest.raises(EpisodeFinishedError):
        e.step({a: 0 for a in e.possible_agents})


def test_overflow_step_keeps_non_overflowing_requesters_reward_in_individual_mode():
    probe = parallel_env(config=CFG, **OVERFLOW_KW)
    probe.reset(seed=0)
    _, _, _, _, pinfo = probe.step({a: 0 for a in probe.agents})
    calm = [a for a in probe.possible_agents if not pinfo[a]["overflowed"]]
    assert calm
    requester = calm[0]
    k = probe.possible_agents.index(requester)

    e = parallel_env(config=CFG, **OVERFLOW_KW)
    cfg = e.config
    e.reset(seed=0)
    v = float(e.simulator.state.volumes[0, k])
    _, rewards, terms, _, infos = e.step({a: int(a == requester) for a in e.agents})
    assert all(terms.values())
    assert infos[requester]["granted"] is True
    assert rewards[requester] == pytest.approx(paper_reward(cfg.containers[k], v, cfg.penalty_reward))
    for a in e.possible_agents:
        if infos[a]["overflowed"]:
            assert rewards[a] == cfg.overflow_reward
    # The same step in team mode: r_min for everyone.
    t = parallel_env(config=CFG, reward_mode="team", **OVERFLOW_KW)
    t.reset(seed=0)
    _, trewards, *_ = t.step({a: int(a == requester) for a in t.agents})
    assert set(trewards.values()) == {cfg.overflow_reward}


# ---- rendering --------------------------------------------------------------------------------------
def test_ansi_render():
    e = parallel_env(config=CFG, render_mode="ansi")
    e.reset(seed=0)
    e.step({a: int(a == "C1-20") for a in e.agents})
    text = e.render()
    assert isinstance(text, str)
    for name, v in zip(e.possible_agents, e.simulator.state.volumes[0]):
        assert name in text
        assert f"{v:.2f}" in text
    assert parallel_env(config=CFG).render() is None
