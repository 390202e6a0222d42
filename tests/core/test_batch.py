"""One core, many simulations: batch equals single runs; the core equals an independent oracle."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from containergym_marl import ContainerSpec, PlantConfig, load_config
from containergym_marl.core import ARBITRATION_RULES, BLOCK_ROWS, dynamics
from containergym_marl.core.simulator import PlantSimulator
from containergym_marl.core.params import PlantParams
from tests import reference_model


@pytest.mark.parametrize("rule", tuple(ARBITRATION_RULES))
def test_batch_of_B_equals_B_single_runs(rule):
    """B simulations stepped together, with per-simulation resets at different times, give exactly
    the trajectories of B simulators run one by one with the same seeds and requests."""
    cfg = load_config("n5_m2_dt120", episode_length_steps=40)
    B, steps = 7, 3 * BLOCK_ROWS + 5  # cross several refills of the random blocks
    seeds = [11 * b + 3 for b in range(B)]
    action_rng = np.random.default_rng(99)
    requests = action_rng.random((steps, B, cfg.n_containers)) < 0.15

    batch = PlantSimulator(cfg, num_sims=B, arbitration=rule)
    batch.reset(generators=[np.random.default_rng(s) for s in seeds])
    singles = [PlantSimulator(cfg, arbitration=rule) for _ in range(B)]
    for s, sim in zip(seeds, singles):
        sim.reset(generators=[np.random.default_rng(s)])

    resets = 0
    for t in range(steps):
        out = batch.step(requests[t])
        for b, sim in enumerate(singles):
            single_out = sim.step(requests[t, b][None])
            np.testing.assert_array_equal(sim.state.volumes[0], batch.state.volumes[b])
            np.testing.assert_array_equal(sim.state.pu_timers_s[0], batch.state.pu_timers_s[b])
            assert single_out.plant_reward[0] == out.plant_reward[b]
            np.testing.assert_array_equal(single_out.granted[0], out.granted[b])
            if sim.finished[0]:
                sim.reset()
        done = np.flatnonzero(batch.finished)
        if done.size:
            resets += done.size
            batch.reset(sims=done)
    assert resets > 0  # the test exercised partial resets


@pytest.mark.parametrize("rule", tuple(ARBITRATION_RULES))
def test_threaded_step_equals_the_one_thread_step(rule, monkeypatch):
    """A batch large enough to be stepped in threads (row blocks) gives every output of the step
    in one thread, bit for bit."""
    cfg = load_config("n11_m2_dt120")
    params = PlantParams.from_config(cfg)
    B, n, m = dynamics.PARALLEL_MIN_BATCH + 37, cfg.n_containers, cfg.num_processing_units
    rng = np.random.default_rng(5)
    state = dynamics.PlantState(rng.uniform(0.0, 40.0, (B, n)), np.where(rng.random((B, m)) < 0.5, 0.0, 90.0),
                                rng.integers(0, cfg.episode_length_steps, B))
    args = (state, rng.random((B, n)) < 0.4, params, rng.standard_normal((B, n)), rng.random((B, n)), rule)
    monkeypatch.setattr(dynamics, "_THREADS", 2)
    threaded = dynamics.step(*args)
    monkeypatch.setattr(dynamics, "_THREADS", 1)
    single = dynamics.step(*args)
    for got, expected in zip((*threaded[0], *threaded[1]), (*single[0], *single[1])):
        np.testing.assert_array_equal(got, expected)
    assert threaded[1].granted.any() and threaded[1].denied.any() and threaded[1].terminated.any()


def test_look_ahead_steps_large_batches_in_the_calling_thread(monkeypatch):
    """The planner's look-ahead works within its caller's core: a batch of futures larger than the
    threaded step's threshold never reaches the thread pool (``threaded=False``), and ``step_checked``
    with ``threaded=False`` gives the threaded step's outputs."""
    from containergym_marl.core.whatif import simulate_future_groups
    from containergym_marl.policies.planner import fullest_base

    cfg = load_config("n11_m2_dt120")
    params = PlantParams.from_config(cfg)
    B, n = dynamics.PARALLEL_MIN_BATCH + 37, cfg.n_containers
    rng = np.random.default_rng(6)
    state = dynamics.PlantState(rng.uniform(0.0, 30.0, (B, n)), np.zeros((B, 2)), np.zeros(B, dtype=np.int64))
    args = (state, np.ascontiguousarray(rng.random((B, n)) < 0.2), params, rng.standard_normal((B, n)),
            rng.random((B, n)), dynamics.get_rule("fullest"))
    monkeypatch.setattr(dynamics, "_THREADS", 2)
    threaded = dynamics.step_checked(*args)

    def no_threads():
        raise AssertionError("the thread pool was used")

    monkeypatch.setattr(dynamics, "_thread_pool", no_threads)
    single = dynamics.step_checked(*args, threaded=False)
    for got, expected in zip((*threaded[0], *threaded[1]), (*single[0], *single[1])):
        np.testing.assert_array_equal(got, expected)
    with pytest.raises(AssertionError, match="thread pool"):
        dynamics.step_checked(*args)
    groups = [(b, rng.random((4, n)) < 0.2, rng.standard_normal((3, 16, n))) for b in range(40)]  # 2,560 futures
    simulate_future_groups(state, groups, lambda s, p: fullest_base(s, p, n), params)


def test_reseeding_one_simulation_leaves_the_others_alone():
    cfg = load_config("n5_m2_dt120")
    a = PlantSimulator(cfg, num_sims=3)
    a.reset(generators=[np.random.default_rng(s) for s in (1, 2, 3)])
    b = PlantSimulator(cfg, num_sims=3)
    b.reset(generators=[np.random.default_rng(s) for s in (1, 2, 3)])
    no = np.zeros((3, cfg.n_containers), bool)
    for _ in range(5):
        a.step(no)
        b.step(no)
    b.reset(sims=[1], generators=[np.random.default_rng(42)])
    a.step(no), b.step(no)
    np.testing.assert_array_equal(a.state.volumes[[0, 2]], b.state.volumes[[0, 2]])
    fresh = PlantSimulator(cfg)
    fresh.reset(generators=[np.random.default_rng(42)])
    fresh.step(no[:1])
    np.testing.assert_array_equal(fresh.state.volumes[0], b.state.volumes[1])


def test_independent_seeds_give_independent_streams():
    cfg = load_config("n11_m2_dt120")
    sim = PlantSimulator(cfg, num_sims=64)
    sim.reset(generators=[np.random.default_rng(s) for s in range(64)])
    v0 = sim.state.volumes
    # no two simulations share initial volumes, and the correlation across simulations is ~0
    assert len({tuple(row) for row in v0.round(12)}) == 64
    c = np.corrcoef(v0)
    off = c[~np.eye(64, dtype=bool)]
    assert abs(off.mean()) < 0.1


# ---- the core against the naive oracle of tests/reference_model.py on generated plants ----------
@st.composite
def plants(draw):
    n = draw(st.integers(1, 6))
    m = draw(st.integers(1, 3))
    containers = []
    for i in range(n):
        k = draw(st.integers(1, 3))
        vmax = draw(st.floats(20.0, 60.0))
        containers.append(ContainerSpec(
            name=f"C{i}",
            fill_rate_per_s=draw(st.floats(0.0, 0.02)),
            fill_noise_per_sqrt_s=draw(st.floats(0.0, 0.15)),
            max_volume=vmax,
            product_size=draw(st.floats(2.0, 30.0)),
            pu_offset_s=draw(st.floats(10.0, 200.0)),
            pu_time_per_product_s=draw(st.floats(10.0, 500.0)),
            reward_peaks=tuple(draw(st.lists(st.floats(1.0, vmax), min_size=k, max_size=k))),
            reward_heights=tuple(draw(st.lists(st.floats(0.01, 1.0), min_size=k, max_size=k))),
            reward_widths=tuple(draw(st.lists(st.floats(0.1, 3.0), min_size=k, max_size=k))),
        ))
    r_pen = draw(st.floats(-0.5, -0.01))
    return PlantConfig(
        name="generated",
        containers=tuple(containers),
        num_processing_units=m,
        timestep_s=draw(st.sampled_from([30.0, 60.0, 120.0])),
        episode_length_steps=draw(st.integers(1, 30)),
        initial_volume_min=0.0,
        initial_volume_max=draw(st.floats(0.0, 19.0)),
        overflow_reward=r_pen - draw(st.floats(0.1, 5.0)),
        penalty_reward=r_pen,
    )


@settings(max_examples=150, deadline=None)
@given(plants(), st.integers(0, 2**32 - 1), st.sampled_from(tuple(ARBITRATION_RULES)))
def test_core_matches_oracle_on_generated_plants(cfg, seed, rule):
    """Any valid plant: step by step, the vectorised core equals the scalar oracle written from the
    paper (volumes, timers, rewards, grants, termination, truncation)."""
    rng = np.random.default_rng(seed)
    params = PlantParams.from_config(cfg)
    n, m = cfg.n_containers, cfg.num_processing_units
    volumes = list(rng.uniform(0, cfg.initial_volume_max, n))
    timers = [0.0] * m
    state = dynamics.PlantState(np.array([volumes]), np.zeros((1, m)), np.zeros(1, dtype=np.int64))
    count = 0
    for _ in range(cfg.episode_length_steps):
        requests = list(rng.random(n) < 0.3)
        normals, uniforms = rng.standard_normal(n), rng.random(n)
        state, out = dynamics.step(state, np.array([requests]), params, normals[None], uniforms[None], rule)
        (volumes, timers, count, individual, plant, term, trunc, granted, pus) = reference_model.step_one(
            cfg, volumes, timers, count, requests, normals, uniforms, rule)
        np.testing.assert_allclose(state.volumes[0], volumes, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(state.pu_timers_s[0], timers, rtol=1e-12, atol=1e-9)
        assert set(np.flatnonzero(out.granted[0]).tolist()) == set(granted)
        for i, j in pus.items():
            assert out.pu_index[0, i] == j
        np.testing.assert_allclose(out.individual_reward[0], individual, rtol=1e-9, atol=1e-12)
        assert out.plant_reward[0] == pytest.approx(plant, rel=1e-9, abs=1e-12)
        assert bool(out.terminated[0]) == term and bool(out.truncated[0]) == trunc
        if term or trunc:
            break
        # keep the oracle and the core on exactly the same state (no drift from float rounding)
        volumes, timers = list(state.volumes[0]), list(state.pu_timers_s[0])


@pytest.mark.parametrize("sims", [None, [1]], ids=["all", "one"])
def test_reset_leaves_the_last_outcome_unchanged(sims):
    """A StepOutcome stays as returned until the step after next: resetting (all simulations, or
    some, as a vector env's autoreset does) must not clear the requests that the last step reports."""
    sim = PlantSimulator(load_config("n5_m2_dt120"), num_sims=3)
    sim.reset(generators=[np.random.default_rng(s) for s in range(3)])
    requests = np.zeros((3, 5), dtype=bool)
    requests[:, 0] = requests[1, 3] = True
    outcome = sim.step(requests)
    kept = {name: np.copy(value) for name, value in outcome._asdict().items()}
    sim.reset(sims)
    for name, value in outcome._asdict().items():
        np.testing.assert_array_equal(value, kept[name], err_msg=name)
    assert sim.last_outcome is outcome
    reset_rows = [0, 1, 2] if sims is None else sims
    assert not sim.previous_requests[reset_rows].any()
    if sims is not None:  # the others still see their own last requests
        np.testing.assert_array_equal(sim.previous_requests[[0, 2]], requests[[0, 2]])


def _stepped_simulator(steps: int, seed: int = 5) -> tuple[PlantSimulator, np.ndarray]:
    sim = PlantSimulator(load_config("n5_m2_dt120"), num_sims=3)
    sim.reset(generators=[np.random.default_rng(seed + b) for b in range(3)])
    requests = np.random.default_rng(seed).random((steps, 3, 5)) < 0.3
    for t in range(steps):
        sim.step(requests[t])
    return sim, requests


def test_outcome_and_state_stay_valid_until_the_step_after_next():
    """The simulator steps into two sets of output arrays in turn: what a step returns (outcome and
    state) is unchanged by the next step, and the step after that reuses its arrays."""
    sim, requests = _stepped_simulator(4)
    first, first_state = sim.step(requests[0]), sim.state
    kept = {name: np.copy(value) for name, value in {**first._asdict(), **first_state._asdict()}.items()}
    second = sim.step(requests[1])
    for name, value in {**first._asdict(), **first_state._asdict()}.items():
        np.testing.assert_array_equal(value, kept[name], err_msg=name)
    assert second is not first and not np.shares_memory(second.granted, first.granted)
    assert not np.shares_memory(sim.state.volumes, first_state.volumes)
    third = sim.step(requests[2])
    assert third is first and sim.state is first_state  # nothing allocated per step


@pytest.mark.parametrize("how", ["deepcopy", "pickle"])
def test_a_copied_simulator_steps_like_the_original_and_apart_from_it(how):
    """SuperSuit and subprocess vector envs copy environments: a copy must own its output arrays,
    with its outcome's names pointing at them (a name left on a copy of the arrays would report
    the state before the copy forever)."""
    import copy
    import pickle

    sim, requests = _stepped_simulator(3)
    twin = copy.deepcopy(sim) if how == "deepcopy" else pickle.loads(pickle.dumps(sim))
    rng = np.random.default_rng(1)
    for _ in range(5):
        r = rng.random((3, 5)) < 0.3
        kept = {name: np.copy(value) for name, value in sim.last_outcome._asdict().items()}
        twin_out = twin.step(r)
        for name, value in sim.last_outcome._asdict().items():  # the copy's step left these alone
            np.testing.assert_array_equal(value, kept[name], err_msg=name)
        out = sim.step(r)
        for name, value in out._asdict().items():
            np.testing.assert_array_equal(twin_out._asdict()[name], value, err_msg=name)
        np.testing.assert_array_equal(twin.state.volumes, sim.state.volumes)
        assert not np.shares_memory(twin.state.volumes, sim.state.volumes)
