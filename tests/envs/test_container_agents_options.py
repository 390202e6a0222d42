"""Options of the decentralised view for MARL libraries: Dict observations with action masks,
a normalised global state, indexed agent names, positional ``config`` and the PettingZoo-style
module path; PettingZoo's own checkers on each.
"""

from __future__ import annotations

import contextlib
import importlib
import math
import warnings

import numpy as np
import pytest
from gymnasium import spaces
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test, seed_test, state_test

from containergym_marl import load_config
from containergym_marl.envs.container_agents_v0 import env as aec_env
from containergym_marl.envs.container_agents_v0 import parallel_env, raw_env
from tests.reference_model import busy_time

from tests.helpers import CFG
# api_test's advice for Dict observations, given to every environment outside its list of classic ones
DICT_WARNINGS = ("Observation space for each agent probably should be gymnasium.spaces.box or",
                 "Observation is not a NumPy array")
AGENT_NAME_WARNING = 'We recommend agents to be named in the format <descriptor>_<number>, like "player_0"'
DICT = {"observation_mode": "dict"}
NORMALISED = {"state_mode": "normalised"}
INDEXED = {"agent_names": "indexed"}
ALL = {**DICT, **NORMALISED, **INDEXED, "action_masking": True}
ENDS = dict(episode_length_steps=20, initial_volume_min=25.0, initial_volume_max=39.5)


@contextlib.contextmanager
def checks_without_warnings(kwargs):
    """Every warning is an error, except PettingZoo's advice on agent names (container names) and
    on Dict observation spaces (which PettingZoo's own classic environments use for masks)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        if kwargs.get("agent_names") != "indexed":
            warnings.filterwarnings("ignore", message=AGENT_NAME_WARNING, category=UserWarning)
        if kwargs.get("observation_mode") == "dict":  # the checks of the mask and features stay
            for message in DICT_WARNINGS:
                warnings.filterwarnings("ignore", message=message, category=UserWarning)
        yield


# ---- PettingZoo's checkers on the new modes -------------------------------------------------------
VARIANTS = [DICT, NORMALISED, INDEXED, ALL, {**ALL, **ENDS, "arbitration": "random", "reward_mode": "team"}]
IDS = ["dict", "normalised", "indexed", "all", "all+ends"]


@pytest.mark.parametrize("kwargs", VARIANTS, ids=IDS)
def test_parallel_api_test(kwargs):
    with checks_without_warnings(kwargs):
        parallel_api_test(parallel_env(CFG, **kwargs), num_cycles=100)


@pytest.mark.parametrize("kwargs", VARIANTS, ids=IDS)
def test_aec_api_test(kwargs):
    with checks_without_warnings(kwargs):
        api_test(aec_env(CFG, **kwargs), num_cycles=30)


@pytest.mark.parametrize("kwargs", [ALL, {**ALL, **ENDS}], ids=["all", "all+ends"])
def test_seed_tests(kwargs):
    kwargs = {**kwargs, "arbitration": "random"}
    with checks_without_warnings(kwargs):
        seed_test(lambda: aec_env(CFG, **kwargs), num_cycles=50)
        parallel_seed_test(lambda: parallel_env(CFG, **kwargs), num_cycles=50)


@pytest.mark.parametrize("kwargs", [NORMALISED, ALL], ids=["normalised", "all"])
def test_state_test(kwargs):
    with checks_without_warnings(kwargs):
        state_test(aec_env(CFG, **kwargs), parallel_env(CFG, **kwargs))


def test_indexed_names_silence_pettingzoos_naming_advice():
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        api_test(aec_env(CFG, **INDEXED), num_cycles=10)
    assert [str(w.message) for w in rec] == []
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        api_test(aec_env(CFG), num_cycles=10)
    assert {str(w.message) for w in rec} == {AGENT_NAME_WARNING}


# ---- Dict observations with the action mask --------------------------------------------------------
def test_dict_observation_space_is_cached_and_wraps_the_box():
    box_env = parallel_env(CFG)
    e = parallel_env(CFG, **DICT)
    for a in e.possible_agents:
        space = e.observation_space(a)
        assert space is e.observation_space(a)
        assert isinstance(space, spaces.Dict) and set(space.spaces) == {"observation", "action_mask"}
        assert space["observation"] == box_env.observation_space(a)
        mask = space["action_mask"]
        assert isinstance(mask, spaces.Box) and mask.dtype == np.int8 and mask.shape == (2,)
        assert (mask.low == 0).all() and (mask.high == 1).all()


def test_dict_observations_equal_the_box_observations_and_masks():
    """Same seed and actions: the "observation" entries equal the box mode's observations and the
    "action_mask" entries equal the info masks; everything lies in its space, with stable dtypes."""
    box = parallel_env(CFG, **ENDS)
    e = parallel_env(CFG, **DICT, action_masking=True, **ENDS)
    rng = np.random.default_rng(3)
    bobs, _ = box.reset(seed=3)
    obs, infos = e.reset(seed=3)
    masked = ends = 0
    for _ in range(200):
        for a in e.possible_agents:
            assert list(obs[a]) == ["action_mask", "observation"]
            np.testing.assert_array_equal(obs[a]["observation"], bobs[a])
            assert obs[a]["observation"].dtype == np.float32 and obs[a]["action_mask"].dtype == np.int8
            np.testing.assert_array_equal(obs[a]["action_mask"], infos[a]["action_mask"])
            assert e.observation_space(a).contains(obs[a])
        free = int((e.simulator.state.pu_timers_s[0] == 0).sum())
        assert obs[e.possible_agents[0]]["action_mask"].tolist() == [1, int(free > 0)]
        masked += free == 0
        if not e.agents:
            ends += 1
            bobs, _ = box.reset()
            obs, infos = e.reset()
            continue
        actions = {a: int(rng.random() < 0.5) for a in e.agents}
        bobs, brew, *_ = box.step(actions)
        obs, rew, *_, infos = e.step(actions)
        assert rew == brew
    assert masked and ends


def test_dict_mask_blocks_request_only_while_no_pu_is_free():
    e = parallel_env(CFG, **DICT, num_processing_units=1)
    obs, _ = e.reset(seed=0)
    assert all(o["action_mask"].tolist() == [1, 1] for o in obs.values())
    g = busy_time(e.config.containers[0], float(e.simulator.state.volumes[0, 0]))
    obs, *_ = e.step({a: int(a == "C1-20") for a in e.agents})
    for _ in range(math.ceil(g / e.config.timestep_s)):  # busy after steps 1 … ⌈g/δ⌉
        assert all(o["action_mask"].tolist() == [1, 0] for o in obs.values())
        obs, *_ = e.step({a: 0 for a in e.agents})
    assert all(o["action_mask"].tolist() == [1, 1] for o in obs.values())


def test_dict_masks_are_separate_arrays():
    """Libraries delete or write masks in place (TorchRL deep-copies, others may not): one agent's
    mask must not be another's."""
    obs, _ = parallel_env(CFG, **DICT).reset(seed=0)
    masks = [o["action_mask"] for o in obs.values()]
    assert len({id(m) for m in masks}) == len(masks)


# ---- the normalised global state --------------------------------------------------------------------
def test_normalised_state_space_bounds_and_caching():
    cfg = load_config(CFG)
    e = parallel_env(CFG, **NORMALISED)
    n, m = cfg.n_containers, cfg.num_processing_units
    assert e.state_space is e.state_space
    assert isinstance(e.state_space, spaces.Box) and e.state_space.dtype == np.float32
    np.testing.assert_array_equal(e.state_space.low, np.zeros(n + m))
    np.testing.assert_array_equal(e.state_space.high, [2.0] * n + [1.0] * m)
    assert parallel_env(CFG).state_space.high[0] == 2 * cfg.containers[0].max_volume  # physical stays


def test_normalised_state_is_the_physical_state_over_its_scales():
    cfg = load_config(CFG)
    vmax = np.array([c.max_volume for c in cfg.containers])
    max_pu = max(c.pu_offset_s + c.pu_time_per_product_s * math.floor(c.max_volume / c.product_size)
                 for c in cfg.containers)
    phys = parallel_env(CFG, **ENDS)
    e = parallel_env(CFG, **NORMALISED, **ENDS)
    rng = np.random.default_rng(7)
    phys.reset(seed=7)
    e.reset(seed=7)
    overflow = busy = 0
    for _ in range(300):
        s, p = e.state(), phys.state()
        assert s.dtype == np.float32 and s.shape == p.shape and e.state_space.contains(s)
        v, t = e.simulator.state.volumes[0], e.simulator.state.pu_timers_s[0]
        expected = np.concatenate([np.minimum(v / vmax, 2.0), np.minimum(t / max_pu, 1.0)])
        np.testing.assert_allclose(s, expected, rtol=2e-7, atol=0)
        busy += (s[5:] > 0).any()
        if not e.agents:
            overflow += (s[:5] >= 1.0).any()  # an overflow's terminal state reaches 1 and more
            phys.reset()
            e.reset()
            continue
        actions = {a: int(rng.random() < 0.4) for a in e.agents}
        phys.step(actions)
        e.step(actions)
    assert busy and overflow


def test_normalised_state_clips_extremes_into_the_space():
    e = parallel_env(CFG, **NORMALISED)
    e.reset(seed=0)
    sim = e.simulator
    st = sim.state
    sim.state = st._replace(volumes=st.volumes * 0 + 1e9, pu_timers_s=st.pu_timers_s * 0 + 1e9)
    s = e.state()
    np.testing.assert_array_equal(s, e.state_space.high)


# ---- agent names ----------------------------------------------------------------------------------
def torchrl_default_groups(agent_names):
    """TorchRL's default grouping for parallel PettingZoo envs (``PettingZooWrapper.
    _get_default_group_map``, torchrl 0.14): ``<name>_<int>`` agents share the group ``<name>``;
    any other agent is a group of its own."""
    groups = {}
    for a in agent_names:
        head, _, tail = a.rpartition("_")
        key = head if head and tail.lstrip("-").isdigit() else a
        groups.setdefault(key, []).append(a)
    return groups


def test_indexed_agent_names_form_one_group_and_keep_container_names():
    cfg = load_config("n11_m2_dt120")
    e = parallel_env("n11_m2_dt120", **INDEXED)
    assert e.possible_agents == [f"container_{i}" for i in range(11)]
    assert e.container_names == cfg.container_names
    assert torchrl_default_groups(e.possible_agents) == {"container": e.possible_agents}
    default = parallel_env("n11_m2_dt120")
    assert default.possible_agents == list(cfg.container_names) == list(default.container_names)
    assert len(torchrl_default_groups(default.possible_agents)) == 11  # one group per agent


@pytest.mark.parametrize("reward_mode", ["individual", "team"])
def test_indexed_agents_behave_as_the_named_agents_of_the_same_index(reward_mode):
    named = parallel_env(CFG, reward_mode=reward_mode, action_masking=True, **ENDS)
    idx = parallel_env(CFG, reward_mode=reward_mode, action_masking=True, **INDEXED, **ENDS)
    pairs = list(zip(idx.possible_agents, named.possible_agents))
    rng = np.random.default_rng(2)
    o1, i1 = named.reset(seed=2)
    o2, i2 = idx.reset(seed=2)
    for _ in range(150):
        for a2, a1 in pairs:
            np.testing.assert_array_equal(o2[a2], o1[a1])
            assert i2[a2].keys() == i1[a1].keys()
        if not named.agents:
            assert not idx.agents
            o1, i1 = named.reset()
            o2, i2 = idx.reset()
            continue
        acts = {a1: int(rng.random() < 0.5) for _, a1 in pairs}
        o1, r1, te1, tr1, i1 = named.step(acts)
        o2, r2, te2, tr2, i2 = idx.step({a2: acts[a1] for a2, a1 in pairs})
        for a2, a1 in pairs:
            assert (r2[a2], te2[a2], tr2[a2]) == (r1[a1], te1[a1], tr1[a1])
            assert i2[a2]["granted"] == i1[a1]["granted"]


@pytest.mark.parametrize("kw", [{"observation_mode": "flat"}, {"observation_mode": None},
                                {"state_mode": "normalized"}, {"agent_names": "index"},
                                {"agent_names": ["a"] * 5}])
def test_unknown_option_values_raise_naming_the_option(kw):
    (name,) = kw
    with pytest.raises(ValueError, match=f"^{name}: unknown value"):
        parallel_env(CFG, **kw)


# ---- positional config and the module path ----------------------------------------------------------
def test_config_is_accepted_by_position():
    assert parallel_env("n11_m2_dt120").config.name == "n11_m2_dt120"
    assert len(raw_env("n11_m2_dt120").possible_agents) == 11
    assert len(aec_env("n11_m2_dt120", **INDEXED).possible_agents) == 11
    assert parallel_env("n11_m2_dt120", timestep_s=60).config.timestep_s == 60


def test_module_imports_as_pettingzoo_env_modules_do():
    mod = importlib.import_module("containergym_marl.container_agents_v0")
    import containergym_marl

    assert containergym_marl.container_agents_v0 is mod
    for name in ("env", "parallel_env", "raw_env"):
        assert callable(getattr(mod, name))
    par = mod.parallel_env("n5_m2_dt120")
    assert par.metadata["name"] == "container_agents_v0"
    assert mod.env("n5_m2_dt120").metadata["name"] == "container_agents_v0"
    assert isinstance(par, mod.ContainerAgentsParallelEnv)
