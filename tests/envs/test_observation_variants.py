"""The container agents' observation variants (``observation=``): the default is the observation as it
was, bit for bit; each variant's extra entries equal hand computations from the simulator's state, the
config and the actions taken; spaces hold every observation at reset and over steps, in the PettingZoo
views and the vectorised env alike; bad values are refused naming the argument.

The hand computations read the config's fields, the simulator's state and the step infos, not the
package's observation code; the default is compared with ``agent_observations``, the kernel the
variants leave untouched."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from containergym_marl import container_agents_v1
from containergym_marl.core.observations import OBSERVATIONS, agent_observation_bounds, agent_observations
from containergym_marl.envs.container_agents_v0 import parallel_env
from containergym_marl.envs.vector import ContainerAgentsVecEnv
from tests.helpers import CFG

VARIANTS = [v for v in OBSERVATIONS if v != "local"]
F0 = {"n5_m2_dt120": 12 + 2 + 5, "n11_m2_dt120": 12 + 2 + 11}


def _rollout(env, seed: int, steps: int, p_request: float = 0.3, rng_seed: int = 0):
    """(observations, actions taken before them, infos) of up to ``steps`` steps from ``reset(seed)``,
    resetting (without a seed) where an episode ends; actions None at a reset."""
    rng = np.random.default_rng(rng_seed)
    obs, infos = env.reset(seed=seed)
    out = [(obs, None, infos)]
    for _ in range(steps):
        if not env.agents:
            obs, infos = env.reset()
            out.append((obs, None, infos))
            continue
        actions = {a: int(rng.random() < p_request) for a in env.agents}
        obs, _, _, _, infos = env.step(actions)
        out.append((obs, actions, infos))
    return out


def _stack(obs: dict) -> np.ndarray:
    return np.stack(list(obs.values()))


# ---- the default ---------------------------------------------------------------------------------
@pytest.mark.parametrize("config", ["n5_m2_dt120", "n11_m2_dt120", "n5_m5_dt60"])
def test_the_default_is_the_observation_kernel_bit_for_bit_in_every_view(config):
    """The PettingZoo views (v0 and v1, default and ``observation="local"``) and the vectorised env
    (its observations and terminal observations across autoresets) give exactly what
    ``agent_observations`` gives for the simulator's state and last requests, with the same space."""
    for make in (lambda **k: parallel_env(config, **k), lambda **k: container_agents_v1.parallel_env(config, **k)):
        default, local = make(episode_length_steps=25), make(episode_length_steps=25, observation="local")
        rng = np.random.default_rng(1)
        for env in (default, local):
            assert env.observation_space(env.possible_agents[0]) == make().observation_space(env.possible_agents[0])
            low, high = agent_observation_bounds(env.simulator.params)
            np.testing.assert_array_equal(env.observation_space(env.possible_agents[0]).low, low)
            np.testing.assert_array_equal(env.observation_space(env.possible_agents[0]).high, high)
        for episode in range(2):
            obs, _ = default.reset(seed=episode)
            twin, _ = local.reset(seed=episode)
            while True:
                sim = default.simulator
                expected = agent_observations(sim.state, sim.params, sim.previous_requests)[0]
                got = _stack(obs)
                assert got.dtype == np.float32 and got.tobytes() == expected.tobytes()
                assert _stack(twin).tobytes() == expected.tobytes()
                if not default.agents:
                    break
                actions = {a: int(rng.random() < 0.3) for a in default.agents}
                obs, *_ = default.step(actions)
                twin, *_ = local.step(dict(actions))

    # the vectorised env, simulation b beside a PettingZoo env seeded as it (checked against the kernel above)
    T = 15
    vec = ContainerAgentsVecEnv(config, 3, episode_length_steps=T)
    singles = [parallel_env(config, episode_length_steps=T) for _ in range(3)]
    n = vec.n_agents
    vec.seed(4)
    obs = vec.reset()
    last = [env.reset(seed=4 + b)[0] for b, env in enumerate(singles)]
    rng, ends = np.random.default_rng(2), 0
    for _ in range(2 * T + 3):
        sim = vec.simulator
        expected = agent_observations(sim.state, sim.params, sim.previous_requests).reshape(vec.num_envs, -1)
        assert obs.dtype == np.float32 and obs.tobytes() == expected.tobytes()
        actions = rng.integers(0, 2, vec.num_envs)
        vec.step_async(actions)
        obs, _, dones, infos = vec.step_wait()
        for b, env in enumerate(singles):
            last[b], *_ = env.step({a: int(actions[b * n + i]) for i, a in enumerate(env.possible_agents)})
            if dones[b * n]:  # the terminal observation: the single env's last one, bit for bit
                ends += 1
                final = np.stack([infos[b * n + i]["terminal_observation"] for i in range(n)])
                assert final.dtype == np.float32 and final.tobytes() == _stack(last[b]).tobytes()
                last[b], _ = env.reset()
            assert obs[b * n:(b + 1) * n].tobytes() == _stack(last[b]).tobytes()
    assert ends >= 3


# ---- each variant's entries, by hand ----------------------------------------------------------------
def _max_pu_time(cfg) -> float:
    return max(c.pu_offset_s + c.pu_time_per_product_s * math.floor(c.max_volume / c.product_size)
               for c in cfg.containers)


@pytest.mark.parametrize("config", ["n5_m2_dt120", "n11_m2_dt120"])
def test_global_entries_are_every_containers_volume_over_its_vmax_and_every_pu_timer(config):
    env = parallel_env(config, observation="global", episode_length_steps=40)
    local = parallel_env(config, episode_length_steps=40)
    cfg = env.config
    n, m, f0 = cfg.n_containers, cfg.num_processing_units, F0[config]
    vmax = np.array([c.max_volume for c in cfg.containers])
    names = env.feature_names()
    assert names[f0] == "global_volume_frac[0]" and names[f0 + n] == "global_pu_timer_frac[0]" and len(names) == f0 + n + m
    rng = np.random.default_rng(3)
    obs, _ = env.reset(seed=5)
    twin, _ = local.reset(seed=5)
    for _ in range(40):
        got = _stack(obs)
        v, p = env.simulator.state.volumes[0], env.simulator.state.pu_timers_s[0]
        hand = np.concatenate([np.clip(v / vmax, 0, 2), np.clip(p / _max_pu_time(cfg), 0, 1)])
        assert got.shape == (n, f0 + n + m)
        np.testing.assert_array_equal(got[:, :f0], _stack(twin))  # the local entries first, unchanged
        for i in range(n):  # the same public block for every agent
            np.testing.assert_allclose(got[i, f0:], hand, rtol=1e-6, atol=0)
            assert got[i, f0 + i] == got[i, 0]  # its own container's entry is its volume_frac
            np.testing.assert_array_equal(got[i, f0 + n:], got[i, 12:12 + m])  # the timers, as entries 12+j
        if not env.agents:
            break
        actions = {a: int(rng.random() < 0.3) for a in env.agents}
        obs, *_ = env.step(actions)
        twin, *_ = local.step(dict(actions))


@pytest.mark.parametrize("config", ["n5_m2_dt120", "n16_m2_dt120", "n64_m6_dt120"])
def test_portable_is_fourteen_entries_on_every_plant_the_scalars_then_the_pu_timers_summarised(config):
    env = parallel_env(config, observation="portable", episode_length_steps=40)
    local = parallel_env(config, episode_length_steps=40)
    cfg = env.config
    assert env.feature_names()[12:] == ["next_pu_free_frac", "mean_pu_timer_frac"]
    rng = np.random.default_rng(4)
    obs, _ = env.reset(seed=6)
    twin, _ = local.reset(seed=6)
    busy_seen = False
    for _ in range(40):
        got, p = _stack(obs), env.simulator.state.pu_timers_s[0]
        assert got.shape == (cfg.n_containers, 14) and env.observation_space(env.agents[0]).shape == (14,)
        np.testing.assert_array_equal(got[:, :12], _stack(twin)[:, :12])  # entries 0-11 unchanged
        longest = _max_pu_time(cfg)
        np.testing.assert_allclose(got[:, 12], min(p.min() / longest, 1.0), rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(got[:, 13], min(p.mean() / longest, 1.0), rtol=1e-6, atol=1e-7)
        busy_seen |= bool(p.min() > 0)
        if not env.agents:
            break
        actions = {a: int(rng.random() < 0.5) for a in env.agents}
        obs, *_ = env.step(actions)
        twin, *_ = local.step(dict(actions))
    assert busy_seen  # the steps reached a moment with every PU busy: entry 12 was not always 0


def test_history_shifts_by_one_frame_per_step_and_is_zero_before_the_episode():
    """Frame s of the history4 observation at step t is the local observation at step t − s, 0 before
    the episode's start; a reset (here at the time limit, T = 6) starts from zeros again."""
    env = parallel_env(CFG, observation="history4", episode_length_steps=6)
    local = parallel_env(CFG, episode_length_steps=6)
    f0 = F0[CFG]
    names = env.feature_names()
    assert len(names) == 4 * f0 and names[f0] == "volume_frac@t-1" and names[3 * f0 + 8] == "free_pu_frac@t-3"
    seen = _rollout(local, seed=2, steps=16, rng_seed=7)
    got = _rollout(env, seed=2, steps=16, rng_seed=7)
    episode: list[np.ndarray] = []
    for (obs, actions, _), (twin, twin_actions, _) in zip(got, seen):
        assert actions == twin_actions
        if actions is None:
            episode = []
        episode.insert(0, _stack(twin))
        frames = _stack(obs).reshape(len(obs), 4, f0)
        for s in range(4):
            np.testing.assert_array_equal(frames[:, s], episode[s] if s < len(episode) else np.zeros_like(frames[:, s]))
    assert sum(a is None for _, a, _ in got) >= 2  # the rollout crossed an episode's end


def test_history_in_the_vector_env_keeps_the_ended_episode_in_the_terminal_observation():
    """The vectorised history4 env gives the PettingZoo env's observations, and at an autoreset the
    terminal observation holds the ended episode's frames while the next observation starts from zeros."""
    T = 5
    vec = ContainerAgentsVecEnv(CFG, 2, observation="history4", episode_length_steps=T)
    single = [parallel_env(CFG, observation="history4", episode_length_steps=T) for _ in range(2)]
    n, f0 = vec.n_agents, F0[CFG]
    vec.seed(10)
    obs = vec.reset()
    singles = [env.reset(seed=10 + b)[0] for b, env in enumerate(single)]
    rng = np.random.default_rng(0)
    for t in range(2 * T + 2):
        for b, env in enumerate(single):
            np.testing.assert_array_equal(obs[b * n:(b + 1) * n], _stack(singles[b]))
        actions = rng.integers(0, 2, vec.num_envs)
        vec.step_async(actions)
        obs, _, dones, infos = vec.step_wait()
        for b, env in enumerate(single):
            singles[b], *_ = env.step({a: int(actions[b * n + i]) for i, a in enumerate(env.possible_agents)})
            if dones[b * n]:
                final = np.stack([infos[b * n + i]["terminal_observation"] for i in range(n)])
                np.testing.assert_array_equal(final, _stack(singles[b]))  # the ended episode's last observation
                assert final.reshape(n, 4, f0)[:, 3].any()  # with its earlier frames
                singles[b], _ = env.reset()
                first = obs[b * n:(b + 1) * n].reshape(n, 4, f0)
                assert not first[:, 1:].any() and first[:, 0].any()  # the next episode starts from zeros


def test_broadcast_is_last_steps_requests_and_grants_and_zero_after_reset():
    env = parallel_env(CFG, observation="broadcast", episode_length_steps=12)
    n, f0 = 5, F0[CFG]
    names = env.feature_names()
    assert names[f0:f0 + n] == [f"requested_last_step[{k}]" for k in range(n)]
    assert names[f0 + n:] == [f"granted_last_step[{k}]" for k in range(n)]
    granted_any = False
    for obs, actions, infos in _rollout(env, seed=1, steps=30, p_request=0.4):
        got = _stack(obs)
        if actions is None:
            assert not got[:, f0:].any()  # nothing broadcast before the first step of an episode
            continue
        requested = np.array([actions[a] for a in env.possible_agents], dtype=np.float32)
        granted = np.array([infos[a]["granted"] for a in env.possible_agents], dtype=np.float32)
        granted_any |= bool(granted.any())
        for i in range(n):
            np.testing.assert_array_equal(got[i, f0:f0 + n], requested)
            np.testing.assert_array_equal(got[i, f0 + n:], granted)
    assert granted_any


# ---- spaces, API tests, bad values ----------------------------------------------------------------
@pytest.mark.parametrize("observation", OBSERVATIONS)
def test_parallel_api_test_passes_for_every_variant(observation):
    env = container_agents_v1.parallel_env(CFG, observation=observation, max_cycles=20)
    parallel_api_test(env, num_cycles=60)


@pytest.mark.parametrize("observation", VARIANTS)
@pytest.mark.parametrize("observation_mode", ["box", "dict"])
def test_every_observation_lies_in_its_space_at_reset_and_over_steps(observation, observation_mode):
    """Including the terminal observation of an overflow (volumes past v_max) and several resets."""
    env = container_agents_v1.parallel_env("n11_m2_dt120", observation=observation, observation_mode=observation_mode,
                                           max_cycles=30, action_masking=True)
    space = env.observation_space(env.possible_agents[0])
    assert all(env.observation_space(a) is env.observation_spaces[a] for a in env.possible_agents)
    shapes = set()
    for obs, _, infos in _rollout(env, seed=0, steps=100, p_request=0.05):
        for agent, o in obs.items():
            box = o["observation"] if observation_mode == "dict" else o
            assert box.dtype == np.float32 and space.contains(o), (agent, observation)
            shapes.add(box.shape)
    assert len(shapes) == 1 and len(env.feature_names()) == next(iter(shapes))[0]
    overflowing = container_agents_v1.parallel_env(CFG, observation=observation, initial_volume_min=39.0,
                                                   initial_volume_max=39.9)
    overflowing.reset(seed=0)
    obs, _, terminations, *_ = overflowing.step({a: 0 for a in overflowing.agents})
    assert all(terminations.values())
    assert all(overflowing.observation_space(a).contains(o) for a, o in obs.items())


@pytest.mark.parametrize("observation", VARIANTS)
def test_the_vector_env_space_holds_every_observation_and_matches_the_pettingzoo_view(observation):
    vec = ContainerAgentsVecEnv(CFG, 4, observation=observation, episode_length_steps=9)
    pz = parallel_env(CFG, observation=observation)
    assert vec.observation_space == pz.observation_space(pz.possible_agents[0]) and vec.observation == observation
    vec.seed(0)
    obs = vec.reset()
    rng = np.random.default_rng(0)
    for _ in range(25):
        assert obs.dtype == np.float32 and all(vec.observation_space.contains(o) for o in obs)
        vec.step_async(rng.integers(0, 2, vec.num_envs))
        obs, _, _, infos = vec.step_wait()
        for info in infos:
            if "terminal_observation" in info:
                assert vec.observation_space.contains(info["terminal_observation"])


@pytest.mark.parametrize("make", [lambda v: parallel_env(CFG, observation=v),
                                  lambda v: container_agents_v1.parallel_env(CFG, observation=v),
                                  lambda v: ContainerAgentsVecEnv(CFG, 2, observation=v)])
@pytest.mark.parametrize("bad", ["oracle", "", None, 3, "Local"])
def test_an_unknown_observation_is_refused_naming_the_argument(make, bad):
    with pytest.raises(ValueError, match=r"observation: unknown observation .*choose one of \('local', 'global'"):
        make(bad)
