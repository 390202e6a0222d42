"""Bad inputs are refused where they are given, name what is wrong, and change nothing.

Issue 14, items 6, 7 and 9: actions checked at each AEC agent's own turn, float and NaN requests
refused by every API, documented bounds on every config number, integral numbers of any type for
integer fields, clear errors for bad vector-env seeds and sizes, and the team reward's per-request
penalty pinned.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from containergym_marl import load_config
from containergym_marl.config import (
    MAX_SIMS,
    MAX_CONTAINERS,
    MAX_PROCESSING_UNITS,
    ConfigError,
)
from containergym_marl.core import PlantParams, PlantSimulator, dynamics
from containergym_marl.envs.centralised import ContainerGymEnv
from containergym_marl.envs.container_agents_v0 import env as aec_env
from containergym_marl.envs.container_agents_v0 import parallel_env, raw_env
from containergym_marl.envs.vector import (
    ContainerAgentsVecEnv,
    ContainerGymVecEnv,
    ContainerGymVectorEnv,
)

from tests.helpers import CFG


def _same(a, b, path="") -> None:
    """Nested equality of env outputs (dicts, arrays, numbers), types included."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), path
        for k in a:
            _same(a[k], b[k], f"{path}/{k}")
    elif isinstance(a, (list, tuple)):
        assert type(a) is type(b) and len(a) == len(b), path
        for k, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{path}[{k}]")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype, path
        np.testing.assert_array_equal(a, b, err_msg=path)
    else:
        assert type(a) is type(b) and (a == b or (a != a and b != b)), (path, a, b)


# ==== 1. the AEC env checks each action at its agent's own turn =====================================
BAD_AEC_ACTIONS = [3, -1, None, 0.0, 1.0, float("nan"), True, np.bool_(True), "1", np.array(1.0),
                   np.array([0, 1]), np.float64(1.0)]


def _aec_snapshot(e):
    u = e.unwrapped
    sim = u.simulator
    st = sim.state
    return (e.agent_selection, st.volumes.copy(), st.pu_timers_s.copy(), st.step_count.copy(),
            sim.previous_requests.copy(), dict(e.rewards), dict(e._cumulative_rewards),
            copy.deepcopy(sim.generator(0).bit_generator.state))


def _aec_play(e, rng, steps):
    """Valid random actions for ``steps`` agent turns; returns what each turn saw."""
    seen = []
    for _ in range(steps):
        if not e.agents:
            break
        obs, reward, term, trunc, info = e.last()
        seen.append((e.agent_selection, obs, reward, term, trunc, info))
        e.step(None if term or trunc else int(rng.random() < 0.5))
    return seen


@pytest.mark.parametrize("make", [aec_env, raw_env], ids=["env", "raw_env"])
@pytest.mark.parametrize("turn", [0, 2, 4], ids=["first", "middle", "last"])
@pytest.mark.parametrize("bad", BAD_AEC_ACTIONS, ids=[repr(b) for b in BAD_AEC_ACTIONS])
def test_aec_refuses_a_bad_action_at_its_own_turn_and_stays_usable(make, turn, bad):
    e, twin = make(CFG), make(CFG)
    e.reset(seed=3)
    twin.reset(seed=3)
    rng_e, rng_t = np.random.default_rng(0), np.random.default_rng(0)
    _aec_play(e, rng_e, 5 * 3 + turn)  # three full steps, then up to the agent of that turn
    _aec_play(twin, rng_t, 5 * 3 + turn)
    agent = e.agent_selection
    before = _aec_snapshot(e)
    with pytest.raises((ValueError, TypeError), match=repr(agent)):
        e.step(bad)
    after = _aec_snapshot(e)
    _same(before, after)
    # the same agent is still to act, and the game goes on exactly as in the twin
    _same(_aec_play(e, rng_e, 5 * 40), _aec_play(twin, rng_t, 5 * 40))


def test_aec_finished_agent_must_pass_none():
    e = aec_env(CFG, episode_length_steps=1)
    e.reset(seed=0)
    for _ in e.possible_agents:
        e.step(0)
    agent = e.agent_selection
    assert e.truncations[agent]
    with pytest.raises(ValueError, match=rf"{agent!r}.*None"):
        e.step(0)
    assert e.agent_selection == agent
    for _ in e.possible_agents:  # every finished agent leaves with None, nothing raises
        e.step(None)
    assert e.agents == []


# ---- float and NaN requests are refused by every API --------------------------------------------
FLOAT_REQUESTS = [np.full((1, 5), 0.0), np.full((1, 5), np.nan), np.array([[1.0, 0, 0, 0, 0]]),
                  np.full((1, 5), 0.5)]


@pytest.mark.parametrize("requests", FLOAT_REQUESTS, ids=["zeros", "nan", "one", "half"])
def test_core_step_refuses_float_requests(requests):
    cfg = load_config(CFG)
    params = PlantParams.from_config(cfg)
    state = dynamics.PlantState(np.full((1, 5), 20.0), np.zeros((1, 2)), np.zeros(1, np.int64))
    with pytest.raises(ValueError, match="requests"):
        dynamics.step(state, requests, params, np.zeros((1, 5)), np.zeros((1, 5)))
    with pytest.raises(ValueError, match="requests"):
        dynamics.step(state, np.array([[2, 0, 0, 0, 0]]), params, np.zeros((1, 5)), np.zeros((1, 5)))
    # booleans and integers 0/1 are the same request
    a, _ = dynamics.step(state, np.array([[1, 0, 0, 0, 0]]), params, np.zeros((1, 5)), np.zeros((1, 5)))
    b, _ = dynamics.step(state, np.array([[True, False, False, False, False]]), params,
                         np.zeros((1, 5)), np.zeros((1, 5)))
    np.testing.assert_array_equal(a.volumes, b.volumes)


@pytest.mark.parametrize("requests", FLOAT_REQUESTS, ids=["zeros", "nan", "one", "half"])
def test_simulator_refuses_float_requests_before_consuming_randomness(requests):
    sim, twin = PlantSimulator(load_config(CFG)), PlantSimulator(load_config(CFG))
    sim.reset(generators=[np.random.default_rng(1)])
    twin.reset(generators=[np.random.default_rng(1)])
    with pytest.raises(ValueError, match="requests"):
        sim.step(requests)
    a, b = sim.step(np.zeros((1, 5), bool)), twin.step(np.zeros((1, 5), bool))
    np.testing.assert_array_equal(sim.state.volumes, twin.state.volumes)
    np.testing.assert_array_equal(a.plant_reward, b.plant_reward)


BAD_SCALARS = [0.0, 1.0, float("nan"), np.float32(1.0), np.array(np.nan), True]


@pytest.mark.parametrize("bad", BAD_SCALARS, ids=[repr(b) for b in BAD_SCALARS])
def test_parallel_and_centralised_envs_refuse_float_and_nan_actions(bad):
    p, p_twin = parallel_env(CFG), parallel_env(CFG)
    p.reset(seed=2)
    p_twin.reset(seed=2)
    for agent in p.possible_agents:
        with pytest.raises((TypeError, ValueError), match=repr(agent)):
            p.step({a: (bad if a == agent else 0) for a in p.possible_agents})
    good = {a: 1 for a in p.possible_agents}
    _same(p.step(good), p_twin.step(dict(good)))

    c, c_twin = ContainerGymEnv(CFG), ContainerGymEnv(CFG)
    c.reset(seed=2)
    c_twin.reset(seed=2)
    with pytest.raises((TypeError, ValueError), match="action"):
        c.step(bad)
    _same(c.step(1), c_twin.step(1))


def _vec_envs(b=3):
    return {
        "sb3_central": (lambda: ContainerGymVecEnv(CFG, num_envs=b), b),
        "sb3_agents": (lambda: ContainerAgentsVecEnv(CFG, num_sims=b), b * 5),
        "gymnasium": (lambda: ContainerGymVectorEnv(num_envs=b, config=CFG), b),
    }


def _vec_reset(v, seed):
    if isinstance(v, ContainerGymVectorEnv):
        return v.reset(seed=seed)[0]
    v.seed(seed)
    return v.reset()


def _vec_step(v, actions):
    if isinstance(v, ContainerGymVectorEnv):
        return v.step(actions)
    return v.step(actions)


@pytest.mark.parametrize("kind", sorted(_vec_envs()))
@pytest.mark.parametrize("fill", [0.0, 1.0, np.nan, 0.5])
def test_vector_envs_refuse_float_and_nan_actions(kind, fill):
    make, slots = _vec_envs()[kind]
    v, twin = make(), make()
    _same(_vec_reset(v, 4), _vec_reset(twin, 4))
    bad = np.zeros(slots)
    bad[-1] = fill
    with pytest.raises(ValueError, match="actions"):
        _vec_step(v, bad)
    good = np.ones(slots, dtype=np.int64)
    _same(_vec_step(v, good), _vec_step(twin, good.copy()))


# ==== 2. documented bounds on every config number ===================================================
def _base_dict() -> dict:
    cfg = load_config(CFG)
    return {
        "num_processing_units": cfg.num_processing_units,
        "timestep_s": cfg.timestep_s,
        "episode_length_steps": cfg.episode_length_steps,
        "initial_volume_min": cfg.initial_volume_min,
        "initial_volume_max": cfg.initial_volume_max,
        "overflow_reward": cfg.overflow_reward,
        "penalty_reward": cfg.penalty_reward,
        "containers": [
            {k: (list(v) if isinstance(v, tuple) else v) for k, v in c.__dict__.items()}
            for c in cfg.containers
        ],
    }


def _with(path: str, value):
    d = _base_dict()
    parts = path.split(".")
    target = d
    for p in parts[:-1]:
        target = target[int(p)] if p.isdigit() else target[p]
    target[parts[-1]] = value
    return d


# container 1 is "C1-30"
OUT_OF_BOUNDS = {
    "width_tiny": ("containers.1.reward_widths", [1e-160], r"'C1-30'.*reward_widths"),
    "width_denormal": ("containers.1.reward_widths", [1e-200], r"'C1-30'.*reward_widths"),
    "width_below_min": ("containers.1.reward_widths", [9.9e-4], r"'C1-30'.*reward_widths"),
    "width_huge": ("containers.1.reward_widths", [1e200], r"'C1-30'.*reward_widths"),
    "pus_1e9": ("num_processing_units", 10**9, r"num_processing_units"),
    "pus_1e400": ("num_processing_units", 10**400, r"num_processing_units"),
    "pus_above_cap": ("num_processing_units", MAX_PROCESSING_UNITS + 1, r"num_processing_units"),
    "fill_huge": ("containers.1.fill_rate_per_s", 1e307, r"'C1-30'.*fill_rate_per_s"),
    "noise_huge": ("containers.1.fill_noise_per_sqrt_s", 1e307, r"'C1-30'.*fill_noise_per_sqrt_s"),
    "lambda_huge": ("containers.1.pu_time_per_product_s", 1e308, r"'C1-30'.*pu_time_per_product_s"),
    "beta_huge": ("containers.1.pu_offset_s", 1e300, r"'C1-30'.*pu_offset_s"),
    "max_volume_huge": ("containers.1.max_volume", 1e300, r"'C1-30'.*max_volume"),
    "max_volume_tiny": ("containers.1.max_volume", 1e-9, r"'C1-30'.*max_volume"),
    "product_size_tiny": ("containers.1.product_size", 1e-9, r"'C1-30'.*product_size"),
    "product_size_huge": ("containers.1.product_size", 1e300, r"'C1-30'.*product_size"),
    "peak_above_v_max": ("containers.1.reward_peaks", [40.5, 12.5], r"'C1-30'.*reward_peaks.*max_volume"),
    "timestep_tiny": ("timestep_s", 1e-9, r"timestep_s"),
    "timestep_huge": ("timestep_s", 1e300, r"timestep_s"),
    "episode_huge": ("episode_length_steps", 10**10, r"episode_length_steps"),
    "episode_1e400": ("episode_length_steps", 10**400, r"episode_length_steps"),
    "r_min_huge": ("overflow_reward", -1e300, r"overflow_reward"),
}


@pytest.mark.parametrize("case", sorted(OUT_OF_BOUNDS))
def test_out_of_bounds_numbers_raise_config_error_naming_the_field(case):
    from containergym_marl.config import config_from_dict

    path, value, pattern = OUT_OF_BOUNDS[case]
    with pytest.raises(ConfigError, match=pattern):
        config_from_dict(_with(path, value))


def test_longest_pu_time_is_bounded():
    from containergym_marl.config import config_from_dict

    d = _with("containers.1.product_size", 1e-3)
    d["containers"][1]["pu_time_per_product_s"] = 1e9  # 1e9 s × 40,000 products
    with pytest.raises(ConfigError, match=r"'C1-30'.*pu_time_per_product_s.*longest PU time"):
        config_from_dict(d)


def test_longest_pu_time_bound_is_g_at_v_max():
    """β + λ·⌊v_max / b⌋ with β = λ = 1e9 s and b = 1: v_max = 999.5 gives 999 products, exactly
    the bound 1e12 s (allowed); v_max = 1000 one product more."""
    from containergym_marl.config import MAX_PU_TIME_S, config_from_dict

    d = _base_dict()
    d["containers"][1].update(product_size=1.0, pu_offset_s=1e9, pu_time_per_product_s=1e9, max_volume=999.5)
    assert MAX_PU_TIME_S == 1e9 + 1e9 * 999
    config_from_dict(d)
    d["containers"][1]["max_volume"] = 1000.0
    with pytest.raises(ConfigError, match=r"'C1-30'.*longest PU time.* = 1001000000000.0 s exceeds"):
        config_from_dict(d)


def test_too_many_containers_named():
    from containergym_marl.config import config_from_dict

    d = _base_dict()
    c = d["containers"][0]
    d["containers"] = [{**c, "name": f"C{i}"} for i in range(MAX_CONTAINERS + 1)]
    with pytest.raises(ConfigError, match=r"containers.*1024"):
        config_from_dict(d)


def test_reference_format_container_count_is_bounded_before_anything_is_built():
    from containergym_marl.config.reference_format import config_from_reference_json

    data = {"MAX_EPISODE_LENGTH": 10, "TIMESTEP": 60, "ENABLED_CONTAINERS": 10**9, "N_PRESSES": 1,
            "MIN_STARTING_VOLUME": 0, "MAX_STARTING_VOLUME": 10, "FAILURE_PENALTY": -1,
            "RW_MUS": [], "RW_SIGMAS": [], "MAX_VOLUMES": [], "BALE_SIZES": [], "PRESS_OFFSETS": [],
            "PRESS_SLOPES": [], "REWARD_PARAMS": [], "MIN_REWARD": -0.1}
    with pytest.raises(ConfigError, match="ENABLED_CONTAINERS"):
        config_from_reference_json(data)


def test_numbers_at_the_bounds_are_accepted_and_stay_finite():
    """The extreme valid plant steps with finite volumes, rewards and observation bounds."""
    from containergym_marl.config import config_from_dict
    from containergym_marl.core.observations import agent_observation_bounds, global_state_bounds

    d = _base_dict()
    c = d["containers"]
    c[0]["reward_widths"] = [1e-3] * len(c[0]["reward_peaks"])
    c[1]["fill_rate_per_s"] = 1e12
    c[1]["fill_noise_per_sqrt_s"] = 1e12
    c[2]["max_volume"] = 1e12
    c[2]["product_size"] = 1e10  # else 1e12 / b products would take longer than 1e12 s
    c[2]["reward_widths"] = [1e12] * len(c[2]["reward_peaks"])
    d["containers"][3]["pu_offset_s"] = 1e9
    d["timestep_s"] = 1e-3
    d["overflow_reward"] = -1e6
    cfg = config_from_dict(d)
    params = PlantParams.from_config(cfg)
    for bounds in (global_state_bounds(params), agent_observation_bounds(params)):
        assert all(np.isfinite(b).all() for b in bounds)
    sim = PlantSimulator(cfg, num_sims=4)
    sim.reset(generators=[np.random.default_rng(s) for s in range(4)])
    out = sim.step(np.ones((4, 5), bool))
    assert np.isfinite(sim.state.volumes).all() and np.isfinite(out.container_reward).all()
    # a width of 1e-3 at its own peak gives the peak's height, next to it r_pen: never NaN
    spec = cfg.containers[0]
    for k, (peak, height) in enumerate(zip(spec.reward_peaks, spec.reward_heights)):
        at_peak = dynamics.emptying_rewards(np.array([[peak, 1.0, 1.0, 1.0, 1.0]]), params)[0, 0]
        assert at_peak == pytest.approx(height)
        beside = dynamics.emptying_rewards(np.array([[peak + 0.5, 1.0, 1.0, 1.0, 1.0]]), params)[0, 0]
        assert beside == cfg.penalty_reward


@pytest.mark.parametrize("value", [600, 600.0, np.float32(600), np.float64(600), np.int64(600),
                                   np.int32(600), np.uint16(600)])
def test_integral_numbers_of_any_type_are_accepted_for_integer_fields(value):
    cfg = load_config(CFG, episode_length_steps=value, num_processing_units=value // 300)
    assert cfg.episode_length_steps == 600 and type(cfg.episode_length_steps) is int
    assert cfg.num_processing_units == 2 and type(cfg.num_processing_units) is int


@pytest.mark.parametrize("value", [600.5, np.float32(600.5), float("inf"), float("nan"), "600",
                                   True, np.bool_(True), None, [600]])
def test_non_integral_values_are_refused_for_integer_fields(value):
    with pytest.raises(ConfigError, match="episode_length_steps.*integer"):
        load_config(CFG, episode_length_steps=value)


def test_non_utf8_config_file_names_the_file(tmp_path):
    for suffix in (".toml", ".json"):
        path = tmp_path / f"latin1{suffix}"
        path.write_bytes("name = \"Kl\xe4ranlage\"\n".encode("latin-1"))
        with pytest.raises(ConfigError, match=rf"latin1\{suffix}.*UTF-8"):
            load_config(path)


def test_bounds_table_is_in_the_config_docstring():
    import containergym_marl.config.bounds as bounds_module

    doc = bounds_module.__doc__
    for field in ("num_processing_units", "timestep_s", "episode_length_steps", "max_volume",
                  "product_size", "fill_rate_per_s", "fill_noise_per_sqrt_s", "pu_offset_s",
                  "pu_time_per_product_s", "reward_peaks", "reward_heights", "reward_widths",
                  "overflow_reward", "num_sims"):
        assert field in doc, field


# ---- numbers of simulations and vector-env seeds ---------------------------------------------------------
@pytest.mark.parametrize("size", [0, -1, 2.7, 3.0, "3", True, MAX_SIMS + 1])
def test_simulation_counts_are_integers_within_bounds(size):
    cfg = load_config(CFG)
    with pytest.raises(ValueError, match="num_sims"):
        PlantSimulator(cfg, num_sims=size)
    with pytest.raises(ValueError, match="num_envs"):
        ContainerGymVecEnv(CFG, num_envs=size)
    with pytest.raises(ValueError, match="num_sims"):
        ContainerAgentsVecEnv(CFG, num_sims=size)
    with pytest.raises(ValueError, match="num_envs"):
        ContainerGymVectorEnv(num_envs=size, config=CFG)


@pytest.mark.parametrize("seed", [2.7, "5", True, -1, 5.0, np.float64(5), [1, 2, 3]])
def test_sb3_vec_env_seed_refuses_non_integers(seed):
    v = ContainerGymVecEnv(CFG, num_envs=3)
    with pytest.raises(ValueError, match="seed"):
        v.seed(seed)


@pytest.mark.parametrize("seed", [2.7, "5", True, -1, 5.0, [0, 1.5, 2], [0, 1], np.array([0.0, 1, 2]),
                                  np.arange(4), np.zeros((3, 1), dtype=np.int64)])
def test_gymnasium_vector_env_reset_refuses_bad_seeds_and_changes_nothing(seed):
    v = ContainerGymVectorEnv(num_envs=3, config=CFG)
    obs, _ = v.reset(seed=11)
    with pytest.raises(ValueError, match="seed"):
        v.reset(seed=seed)
    np.testing.assert_array_equal(v.simulator.global_state(), obs)


def test_gymnasium_vector_env_takes_an_array_of_seeds():
    """reset(seed=np.arange(B)) seeds simulation b with b, as a list does, and as single envs do."""
    b = 4
    v = ContainerGymVectorEnv(num_envs=b, config=CFG)
    from_array, _ = v.reset(seed=np.arange(b))
    from_list, _ = ContainerGymVectorEnv(num_envs=b, config=CFG).reset(seed=list(range(b)))
    from_int, _ = ContainerGymVectorEnv(num_envs=b, config=CFG).reset(seed=0)
    np.testing.assert_array_equal(from_array, from_list)
    np.testing.assert_array_equal(from_array, from_int)
    for k in range(b):
        single, _ = ContainerGymEnv(CFG).reset(seed=k)
        np.testing.assert_array_equal(from_array[k], single)
    np.testing.assert_array_equal(ContainerGymVectorEnv(num_envs=2, config=CFG).reset(
        seed=np.array([7, 3], dtype=np.uint8))[0][1], ContainerGymEnv(CFG).reset(seed=3)[0])


@pytest.mark.parametrize("seed", [np.int64(5), np.uint32(5), 5])
def test_integer_seeds_of_any_integer_type_are_accepted(seed):
    v = ContainerGymVecEnv(CFG, num_envs=2)
    assert v.seed(seed) == [5, 6]


# ==== 3. team mode: k denied requests in one step score k · r_pen ====================================
@pytest.mark.parametrize("k", [0, 1, 10, 11, 16])
def test_team_step_reward_with_k_denials_is_k_times_r_pen(k):
    """Documented in the env card (Rewards): the plant reward counts every denied request at r_pen,
    as the centralised return does; more than |r_min / r_pen| = 10 denials score below r_min, while
    r_min stays the worst terminal outcome."""
    e = parallel_env("n16_m2_dt120", reward_mode="team")
    e.reset(seed=0)
    sim = e.simulator
    cfg = e.config
    # every PU busy for a long time, every container low (no overflow possible this step)
    sim.state = sim.state._replace(volumes=np.full((1, 16), 5.0), pu_timers_s=np.full((1, 2), 1e4))
    requesters = e.possible_agents[:k]
    _, rewards, terms, truncs, infos = e.step({a: int(a in requesters) for a in e.possible_agents})
    expected = k * -0.1  # r_pen of n16_m2_dt120, by hand
    assert cfg.penalty_reward == -0.1 and cfg.overflow_reward == -1.0
    assert not any(terms.values()) and not any(truncs.values())
    assert sum(info["denied"] for info in infos.values()) == k
    for r in rewards.values():
        assert r == pytest.approx(expected, abs=1e-12)
    assert (rewards[e.possible_agents[0]] < cfg.overflow_reward) == (k > 10)
    # individual mode: each denied agent gets r_pen, the others 0; their sum is the team reward
    ind = parallel_env("n16_m2_dt120", reward_mode="individual")
    ind.reset(seed=0)
    ind.simulator.state = sim.state._replace(volumes=np.full((1, 16), 5.0), pu_timers_s=np.full((1, 2), 1e4))
    _, ind_rewards, _, _, _ = ind.step({a: int(a in requesters) for a in ind.possible_agents})
    assert [ind_rewards[a] for a in ind.possible_agents] == [-0.1] * k + [0.0] * (16 - k)
    assert math.fsum(ind_rewards.values()) == pytest.approx(expected, abs=1e-12)


def test_env_card_documents_team_rewards_below_r_min():
    from containergym_marl.envs.container_agents_v0 import ContainerAgentsParallelEnv

    doc = " ".join(ContainerAgentsParallelEnv.__doc__.split())
    assert "below r_min" in doc and "|r_min / r_pen|" in doc and "terminal" in doc


@pytest.mark.parametrize("field", ["timestep_s", "penalty_reward", "initial_volume_max"])
def test_huge_integers_for_float_fields_raise_config_error(field):
    """10**400 cannot become a float: a ConfigError naming the field, not an OverflowError."""
    with pytest.raises(ConfigError, match=field):
        load_config(CFG, **{field: 10**400 if field != "penalty_reward" else -10**400})


def test_huge_integers_in_files_and_direct_construction_raise_config_error(tmp_path):
    import dataclasses

    base = load_config(CFG)
    path = tmp_path / "huge.toml"
    path.write_text(base.to_toml().replace("max_volume = 40.0", "max_volume = 1" + "0" * 400, 1),
                    encoding="utf-8")
    with pytest.raises(ConfigError, match=r"'C1-20'.*max_volume"):
        load_config(path)
    spec = dataclasses.replace(base.containers[0], reward_widths=(10**400,) * len(base.containers[0].reward_widths))
    with pytest.raises(ConfigError, match=r"'C1-20'.*reward_widths"):
        dataclasses.replace(base, containers=(spec, *base.containers[1:]))


# ---- seeds: the same rule in every view (issue 23) ---------------------------------------------------
@pytest.mark.parametrize("make", ["single", "agents", "vector"])
def test_every_view_takes_numpy_integer_seeds_and_refuses_bools(make):
    import numpy as np

    from containergym_marl.envs.centralised import ContainerGymEnv
    from containergym_marl.envs.container_agents_v0 import parallel_env
    from containergym_marl.envs.vector import ContainerGymVectorEnv

    env = {"single": lambda: ContainerGymEnv("n5_m2_dt120"), "agents": lambda: parallel_env(config="n5_m2_dt120"),
           "vector": lambda: ContainerGymVectorEnv("n5_m2_dt120", 2)}[make]()
    a = env.reset(seed=np.int64(7))[0]
    b = env.reset(seed=7)[0]
    first = lambda obs: obs if not isinstance(obs, dict) else next(iter(obs.values()))  # noqa: E731
    np.testing.assert_array_equal(first(a), first(b))
    for bad in (True, np.bool_(True), -1, 2.0, "3"):
        with pytest.raises(ValueError, match="seed"):
            env.reset(seed=bad)


def test_batched_envs_take_config_then_size():
    """Every batched env of the package takes (config, size): the Gymnasium vector env as the SB3
    ones; the old (num_envs, config) order is refused by name rather than misread."""
    import gymnasium as gym

    from containergym_marl.envs.vector import ContainerGymVectorEnv

    venv = ContainerGymVectorEnv("n5_m2_dt120", 3)
    assert venv.num_envs == 3 and venv.config.name == "n5_m2_dt120"
    with pytest.raises(TypeError, match="config"):
        ContainerGymVectorEnv(3, "n5_m2_dt120")
    made = gym.make_vec("containergym_marl/ContainerGym-v0", num_envs=2, vectorization_mode="vector_entry_point",
                        config="n5_m2_dt120")
    assert made.num_envs == 2
    made.close()
