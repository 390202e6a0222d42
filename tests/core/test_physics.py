"""The core's physics against hand-computed values from the paper's equations (section 5)."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest

from containergym_marl import load_config
from containergym_marl.core import dynamics, emptying_reward, emptying_rewards, pu_busy_time_s
from containergym_marl.core.simulator import EpisodeFinishedError, PlantSimulator
from containergym_marl.config.pu_time import pu_time_s
from containergym_marl.core.params import PlantParams, pack_params, unpack_params
from tests.helpers import make_state

R_PEN = -0.1


def zeros(n):
    return np.zeros((1, n))


# ---- reward (paper eq. 5) ---------------------------------------------------------------------
@pytest.mark.parametrize(
    "container, volume, expected",
    [
        # C1-20: one peak v*=27, h=1, w=2.
        ("C1-20", 27.0, 1.0),
        ("C1-20", 25.0, R_PEN + 1.1 * math.exp(-4.0 / 8.0)),  # 0.567178...
        ("C1-20", 31.0, R_PEN + 1.1 * math.exp(-16.0 / 8.0)),
        # C1-60: peaks 25.5/17/8.5, heights 1/0.4/0.2, widths 2.5/0.5/0.25.
        ("C1-60", 17.0, R_PEN + 1.1 * math.exp(-(8.5**2) / 12.5) + 0.5 + 0.3 * math.exp(-(8.5**2) / 0.125)),
        ("C1-60", 8.5, R_PEN + 1.1 * math.exp(-(17.0**2) / 12.5) + 0.5 * math.exp(-(8.5**2) / 0.5) + 0.3),
        ("C1-60", 25.5, 1.0 + 0.5 * math.exp(-(8.5**2) / 0.5)),
        # C1-70: peaks 31.5/21/10.5, heights 1/0.25/0.1 → at 21 the local optimum 0.25 (plus tails).
        ("C1-70", 21.0, R_PEN + 1.1 * math.exp(-(10.5**2) / 12.5) + 0.35),
        # far from every optimum the reward tends to r_pen
        ("C1-80", 3.0, R_PEN + 1.1 * math.exp(-(22.0**2) / 8.0) + 0.4 * math.exp(-(9.5**2) / 0.5)),
        # an empty container: r_pen
        ("C1-20", 0.0, R_PEN),
    ],
)
def test_emptying_reward_matches_hand_computation(cfg5, container, volume, expected):
    i = cfg5.container_names.index(container)
    v = np.zeros(cfg5.n_containers)
    v[i] = volume
    params = PlantParams.from_config(cfg5)
    assert emptying_reward(i, volume, params) == pytest.approx(expected, rel=1e-12, abs=1e-15)
    assert emptying_rewards(v[None], params)[0, i] == emptying_reward(i, volume, params)


def test_reward_range_and_peaks(cfg5):
    """The reward lies in [r_pen, 1] (]r_pen, 1] up to float underflow far from any peak) and is
    ≈ 1 at each global optimum."""
    params = PlantParams.from_config(cfg5)
    v = np.linspace(1e-3, 39.999, 4001)[:, None].repeat(cfg5.n_containers, axis=1)
    r = emptying_rewards(v, params)
    assert r.max() <= 1.0 + 1e-12 and r.min() >= R_PEN
    for i, c in enumerate(cfg5.containers):
        assert emptying_reward(i, c.target_volume, params) == pytest.approx(1.0, abs=2e-3)


# ---- PU timers (paper eq. 2 and the state update) -------------------------------------------
def test_pu_busy_time_is_beta_plus_lambda_floor(cfg5):
    params = PlantParams.from_config(cfg5)
    v = np.array([[27.3, 12.4, 17.0, 31.5, 0.0]])
    expected = [106.798502 + 264.9 * 1, 95.399 + 149.88 * 0, 65.998499 + 191.64 * 2,
                56.398501 + 172.32 * 3, 53.999001]
    got = [pu_busy_time_s(i, v[0, i], params) for i in range(cfg5.n_containers)]
    np.testing.assert_allclose(got, expected, rtol=1e-12)


@pytest.mark.parametrize("volume, expected", [
    (0.0, 10.0), (2.4999, 10.0), (2.5, 13.0), (7.6, 19.0), (25.0, 40.0)])
def test_pu_time_is_beta_plus_lambda_floor_of_products(volume, expected):
    """g(v) = β + λ·⌊v / b⌋ with β = 10 s, λ = 3 s per product, b = 2.5: a PU time grows by λ only
    at whole products."""
    assert pu_time_s(volume, 10.0, 3.0, 2.5) == expected


def test_max_pu_time_is_the_largest_g_at_v_max(cfg5):
    """The timer bound: no container is emptied at v ≥ v_max, so max_i g_i(v_max,i) bounds every
    timer (computed here from the config by hand)."""
    by_hand = [c.pu_offset_s + c.pu_time_per_product_s * math.floor(c.max_volume / c.product_size)
               for c in cfg5.containers]
    assert PlantParams.from_config(cfg5).max_pu_time_s == max(by_hand)


def test_timer_set_to_g_at_t_plus_1_then_counts_down_by_delta(cfg5):
    """The paper's p_{k,t+1} = g(v_t): no δ is subtracted in the emptying step (unlike the
    reference code); the PU is free again only once its timer reaches exactly 0."""
    params = PlantParams.from_config(cfg5)
    n = cfg5.n_containers
    state = make_state([27.3, 5, 5, 5, 5], [0.0, 500.0])
    requests = np.zeros((1, n), bool)
    requests[0, 0] = True
    state, out = dynamics.step(state, requests, params, zeros(n), zeros(n))
    g = 106.798502 + 264.9
    assert out.granted[0, 0] and out.pu_index[0, 0] == 0
    assert state.pu_timers_s[0, 0] == pytest.approx(g)
    assert state.pu_timers_s[0, 1] == pytest.approx(500.0 - 120.0)
    expected = [g - 120, g - 240, g - 360, 0.0]  # 251.7, 131.7, 11.7, 0
    for exp in expected:
        state, _ = dynamics.step(state, np.zeros((1, n), bool), params, zeros(n), zeros(n))
        assert state.pu_timers_s[0, 0] == pytest.approx(exp)
    assert state.pu_timers_s[0, 1] == 0.0  # 500 → 380 → 260 → 140 → 20 → 0


def test_busy_pu_with_small_remaining_time_is_not_free(cfg5):
    """A timer of 11.7 s is still busy: an emptying request is denied with r_pen and the
    container keeps filling."""
    params = PlantParams.from_config(cfg5)
    n = cfg5.n_containers
    state = make_state([27.0, 5, 5, 5, 5], [11.7, 3.0])
    requests = np.zeros((1, n), bool)
    requests[0, 0] = True
    new, out = dynamics.step(state, requests, params, zeros(n), zeros(n))
    assert out.denied[0, 0] and not out.granted[0, 0]
    assert out.container_reward[0, 0] == R_PEN and out.plant_reward[0] == R_PEN
    assert new.volumes[0, 0] == pytest.approx(27.0 + params.fill_mean_per_step[0])
    np.testing.assert_allclose(new.pu_timers_s[0], [0.0, 0.0])


def test_emptying_an_empty_container_costs_r_pen_and_still_uses_a_pu(cfg5):
    params = PlantParams.from_config(cfg5)
    n = cfg5.n_containers
    state = make_state([0.0, 5, 5, 5, 5], [0.0, 0.0])
    requests = np.zeros((1, n), bool)
    requests[0, 0] = True
    new, out = dynamics.step(state, requests, params, zeros(n), zeros(n))
    assert out.granted[0, 0] and out.container_reward[0, 0] == R_PEN
    assert new.volumes[0, 0] == 0.0
    assert new.pu_timers_s[0, 0] == pytest.approx(106.798502)  # g(0) = β


# ---- volumes -------------------------------------------------------------------------------------
def test_emptied_container_is_zero_and_reward_uses_volume_before_inflow(cfg5):
    params = PlantParams.from_config(cfg5)
    n = cfg5.n_containers
    state = make_state([25.0, 10, 10, 10, 10], [0.0, 0.0])
    requests = np.zeros((1, n), bool)
    requests[0, 0] = True
    normals = np.full((1, n), 3.0)  # large inflow this step must not affect the reward
    new, out = dynamics.step(state, requests, params, normals, zeros(n))
    assert new.volumes[0, 0] == 0.0
    assert out.container_reward[0, 0] == pytest.approx(R_PEN + 1.1 * math.exp(-0.5))
    assert out.emptied_volume[0, 0] == 25.0
    c = cfg5.containers[1]
    assert new.volumes[0, 1] == pytest.approx(10 + c.fill_rate_per_s * 120 + c.fill_noise_per_sqrt_s * math.sqrt(120) * 3)


def test_volume_is_clipped_at_zero(cfg5):
    params = PlantParams.from_config(cfg5)
    n = cfg5.n_containers
    new, _ = dynamics.step(make_state([0.1] * n, [0, 0]), np.zeros((1, n), bool), params,
                           np.full((1, n), -10.0), zeros(n))
    assert np.all(new.volumes == 0.0)


def test_fill_increments_match_random_walk_statistics():
    """Increments over 20 000 simulated steps (fixed seed) have mean μδ and variance σ²δ within
    statistical bounds (5 standard errors), for δ = 60 and 120."""
    for name in ("n5_m2_dt60", "n5_m2_dt120"):
        cfg = load_config(name, initial_volume_min=15.0, initial_volume_max=15.0)
        sim = PlantSimulator(cfg, num_sims=20_000)
        sim.reset(generators=[np.random.default_rng(s) for s in range(20_000)])
        before = sim.state.volumes.copy()
        sim.step(np.zeros((20_000, cfg.n_containers), bool))
        inc = sim.state.volumes - before
        dt = cfg.timestep_s
        for i, c in enumerate(cfg.containers):
            mean, var, n_obs = c.fill_rate_per_s * dt, c.fill_noise_per_sqrt_s**2 * dt, inc.shape[0]
            assert abs(inc[:, i].mean() - mean) < 5 * math.sqrt(var / n_obs), (name, c.name)
            # standard error of the sample variance of a normal: var·sqrt(2/(N−1))
            assert abs(inc[:, i].var(ddof=1) - var) < 5 * var * math.sqrt(2 / (n_obs - 1)), (name, c.name)


def test_fill_over_many_steps_of_one_simulation():
    """Within one long episode the increments are i.i.d. N(μδ, σ²δ): check the mean and the lag-1
    autocorrelation (≈ 0) of C1-80's increments, with volumes reset by emptying to avoid overflow."""
    cfg = load_config("n5_m5_dt60", episode_length_steps=100_000)
    sim = PlantSimulator(cfg)
    sim.reset(generators=[np.random.default_rng(7)])
    i = cfg.container_names.index("C1-80")
    incs = []
    for _ in range(20_000):
        before = sim.state.volumes[0].copy()
        req = (before > 20.0)[None, :]  # m = n: a request always finds a free PU
        out = sim.step(req)
        if not out.granted[0, i] and before[i] > 5.0:  # no clipping possible far from 0
            incs.append(sim.state.volumes[0, i] - before[i])
    incs = np.array(incs)
    c = cfg.containers[i]
    mean, sd = c.fill_rate_per_s * 60, c.fill_noise_per_sqrt_s * math.sqrt(60)
    assert abs(incs.mean() - mean) < 5 * sd / math.sqrt(incs.size)
    assert abs(np.corrcoef(incs[:-1], incs[1:])[0, 1]) < 5 / math.sqrt(incs.size)


# ---- episode end ---------------------------------------------------------------------------------
def test_overflow_terminates_with_r_min_replacing_the_step_reward(cfg5):
    """Container 2 overflows in the same step as container 1 is emptied at its optimum: the plant
    reward is r_min (not r_min + 1), individual rewards give r_min only to the overflowing one."""
    params = PlantParams.from_config(cfg5)
    n = cfg5.n_containers
    state = make_state([27.0, 39.9, 5, 5, 5], [0.0, 0.0])
    requests = np.zeros((1, n), bool)
    requests[0, 0] = True
    normals = np.zeros((1, n))
    new, out = dynamics.step(state, requests, params, normals, zeros(n))
    assert new.volumes[0, 1] >= 40.0
    assert out.terminated[0] and not out.truncated[0]
    assert out.plant_reward[0] == -1.0
    assert out.container_reward[0, 0] == pytest.approx(1.0)
    np.testing.assert_allclose(out.individual_reward[0], [1.0, -1.0, 0, 0, 0])
    assert out.overflowed[0].tolist() == [False, True, False, False, False]


def test_volume_exactly_v_max_counts_as_overflow(cfg5):
    """v(t+1) == v_max is an overflow (the paper's ≥). A noiseless container with μδ = 1 exactly
    goes from 39 to 40."""
    c0 = cfg5.containers[0]
    exact = type(c0)(**{**c0.__dict__, "fill_rate_per_s": 0.5, "fill_noise_per_sqrt_s": 0.0})
    cfg = cfg5.replace(timestep_s=2.0, containers=(exact, *cfg5.containers[1:]))
    params = PlantParams.from_config(cfg)
    n = cfg.n_containers
    new, out = dynamics.step(make_state([39.0, 5, 5, 5, 5], [0, 0]), np.zeros((1, n), bool), params,
                             zeros(n), zeros(n))
    assert new.volumes[0, 0] == 40.0
    assert out.terminated[0] and out.overflowed[0, 0]


def test_truncation_at_T_and_overflow_on_the_last_step_is_termination():
    cfg = load_config("n5_m2_dt120", episode_length_steps=3)
    params = PlantParams.from_config(cfg)
    n = cfg.n_containers
    state = make_state([5] * n, [0, 0], step_count=2)
    _, out = dynamics.step(state, np.zeros((1, n), bool), params, zeros(n), zeros(n))
    assert out.truncated[0] and not out.terminated[0]
    state = make_state([5, 5, 5, 5, 39.99], [0, 0], step_count=2)
    _, out = dynamics.step(state, np.zeros((1, n), bool), params, zeros(n), zeros(n))
    assert out.terminated[0] and not out.truncated[0]


def test_simulator_refuses_to_step_a_finished_episode():
    cfg = load_config("n5_m2_dt120", episode_length_steps=2)
    sim = PlantSimulator(cfg)
    with pytest.raises(RuntimeError, match="reset"):
        sim.reset()  # no generator yet
    sim.reset(generators=[np.random.default_rng(0)])
    no = np.zeros((1, cfg.n_containers), bool)
    sim.step(no)
    out = sim.step(no)
    assert out.truncated[0]
    before = sim.state.volumes.copy()
    with pytest.raises(EpisodeFinishedError, match="reset"):
        sim.step(no)
    np.testing.assert_array_equal(sim.state.volumes, before)
    sim.reset()
    sim.step(no)


def test_reset_draws_uniform_initial_volumes_and_free_pus():
    cfg = load_config("n11_m2_dt120")
    sim = PlantSimulator(cfg, num_sims=5000)
    sim.reset(generators=[np.random.default_rng(s) for s in range(5000)])
    v = sim.state.volumes
    assert v.min() >= 0.0 and v.max() <= 30.0
    # U[0, 30]: mean 15, sd 30/sqrt(12) → standard error over 55 000 draws ≈ 0.037
    assert abs(v.mean() - 15.0) < 5 * (30 / math.sqrt(12)) / math.sqrt(v.size)
    assert np.all(sim.state.pu_timers_s == 0.0) and np.all(sim.state.step_count == 0)


# ---- the kernel's parameters and outputs by name -------------------------------------------------
@numba.njit
def _unpacked_in_compiled_code(per_container, reward_table, scalars):
    return unpack_params(per_container, reward_table, scalars)


def test_every_parameter_round_trips_through_the_kernel_arrays_by_name():
    """Each field, given a value of its own, reads back the same by name in Python and in compiled
    code, with its type; the arrays are read-only views of the three arrays the kernel takes."""
    ints = ("n_containers", "n_pus", "episode_length_steps")
    floats = ("timestep_s", "initial_volume_min", "initial_volume_max", "overflow_reward", "penalty_reward",
              "max_pu_time_s")
    columns = ("fill_mean_per_step", "fill_std_per_step", "max_volume", "product_size", "pu_offset_s",
               "pu_time_per_product_s", "target_volume")
    reward_rows = ("reward_peaks", "reward_coef", "reward_two_width_sq")
    storage = ("per_container", "reward_table", "scalars")
    assert sorted(ints + floats + columns + reward_rows + storage) == sorted(PlantParams._fields)
    n, k = 3, 2
    fields = {name: 10 + j for j, name in enumerate(ints)}
    fields |= {name: 0.5 + j for j, name in enumerate(floats)}
    fields |= {name: np.arange(n) + 100.0 * (j + 1) for j, name in enumerate(columns)}
    fields |= {name: np.arange(n * k).reshape(n, k) - 100.0 * (j + 1) for j, name in enumerate(reward_rows)}
    params = pack_params(fields)
    compiled = _unpacked_in_compiled_code(*params.kernel_arrays())
    assert params.kernel_arrays() == (params.per_container, params.reward_table, params.scalars)
    for unpacked in (params, compiled):
        for name in ints + floats:
            assert getattr(unpacked, name) == fields[name], name
            assert type(getattr(unpacked, name)) is (int if name in ints else float), name
        for name in columns + reward_rows:
            got = getattr(unpacked, name)
            np.testing.assert_array_equal(got, fields[name], err_msg=name)
            assert not got.flags.writeable, name
            assert any(np.shares_memory(got, getattr(params, s)) for s in storage), name


def test_step_outputs_name_every_element_of_the_output_arrays_once():
    """The next state and the outcome are views of the stacked output arrays, of the documented
    shapes and types, and together cover every element of them exactly once."""
    bsz, n, m = 3, 5, 2
    arrays = dynamics._allocate_outputs(bsz, n, m)
    state, outcome = dynamics._named_outputs.py_func(*arrays)
    expected = {"volumes": ((bsz, n), np.float64), "pu_timers_s": ((bsz, m), np.float64),
                "step_count": ((bsz,), np.int64), "pu_index": ((bsz, n), np.int64),
                "plant_reward": ((bsz,), np.float64), "free_pus_before": ((bsz,), np.int64)}
    expected |= {name: ((bsz, n), np.bool_) for name in ("requested", "granted", "denied", "overflowed")}
    expected |= {name: ((bsz, n), np.float64)
                 for name in ("emptied_volume", "container_reward", "individual_reward")}
    expected |= {name: ((bsz,), np.bool_) for name in ("terminated", "truncated")}
    views = {**state._asdict(), **outcome._asdict()}
    assert {name: (v.shape, v.dtype) for name, v in views.items()} == expected
    assert all(any(np.shares_memory(v, a) for a in arrays) for v in views.values())
    assert sum(v.size for v in views.values()) == sum(a.size for a in arrays)
    names = list(views)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            assert not np.shares_memory(views[a], views[b]), (a, b)
