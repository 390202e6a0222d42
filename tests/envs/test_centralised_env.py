"""Tests of the centralised Gymnasium view (``containergym_marl/ContainerGym-v0``).

Expected values (rewards, PU busy times, bounds) are computed here by hand from the config's
per-container fields, not from the package's ``PlantParams`` arrays or core functions.
"""

from __future__ import annotations

import math
import tomllib
import warnings
from importlib import resources

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

import containergym_marl
from containergym_marl.core import EpisodeFinishedError
from containergym_marl.envs.centralised import ContainerGymEnv
from tests.reference_model import busy_time, paper_reward

from tests.helpers import CFG
ENV_ID = "containergym_marl/ContainerGym-v0"


# ---- independent helpers ------------------------------------------------------------------------
def toml_config(name: str) -> dict:
    text = (resources.files("containergym_marl.configs") / f"{name}.toml").read_text(encoding="utf-8")
    return tomllib.loads(text)


def make(**kwargs) -> ContainerGymEnv:
    return ContainerGymEnv(CFG, **kwargs)


def state_snapshot(env: ContainerGymEnv):
    st = env.simulator.state
    return st.volumes.copy(), st.pu_timers_s.copy(), st.step_count.copy()


def assert_info_equal(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        assert a[k] == b[k], k


# ---- registration and checkers ------------------------------------------------------------------
def test_gym_make_registered_and_returns_container_gym_env():
    env = gym.make(ENV_ID, config=CFG)
    assert isinstance(env.unwrapped, ContainerGymEnv)
    assert env.unwrapped.config.name == CFG
    # No TimeLimit wrapper: the env truncates itself at T.
    assert env.spec.max_episode_steps is None
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    env.close()


def test_gym_make_from_spec_recreates_same_configuration():
    env = gym.make(ENV_ID, config=CFG, episode_length_steps=9, render_mode="ansi")
    again = gym.make(env.spec)
    assert again.unwrapped.config == env.unwrapped.config
    assert again.unwrapped.config.episode_length_steps == 9
    o1, _ = env.reset(seed=6)
    o2, _ = again.reset(seed=6)
    np.testing.assert_array_equal(o1, o2)
    assert isinstance(again.render(), str)


def test_gymnasium_check_env_passes_without_warnings():
    from gymnasium.utils.env_checker import check_env

    env = gym.make(ENV_ID, config=CFG)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)


def test_sb3_check_env_passes_without_warnings():
    from stable_baselines3.common.env_checker import check_env

    env = gym.make(ENV_ID, config=CFG)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env, warn=True)


def test_step_returns_python_float_reward_and_python_bool_flags():
    env = make()
    env.reset(seed=0)
    for action in (0, 1, np.int64(2), 0):
        obs, reward, terminated, truncated, info = env.step(action)
        assert type(reward) is float
        assert type(terminated) is bool
        assert type(truncated) is bool
        assert isinstance(info, dict)
        assert obs.dtype == np.float32


# ---- spaces -------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", containergym_marl.list_configs())
def test_spaces_match_config_file(name):
    raw = toml_config(name)
    n, m = len(raw["containers"]), raw["num_processing_units"]
    env = ContainerGymEnv(name)
    assert env.action_space == spaces.Discrete(n + 1)
    box = env.observation_space
    assert isinstance(box, spaces.Box)
    assert box.dtype == np.float32
    assert box.shape == (n + m,)
    vmax = np.array([c["max_volume"] for c in raw["containers"]])
    max_busy = max(
        c["pu_offset_s"] + c["pu_time_per_product_s"] * math.floor(c["max_volume"] / c["product_size"])
        for c in raw["containers"]
    )
    np.testing.assert_array_equal(box.low, np.zeros(n + m, dtype=np.float32))
    np.testing.assert_allclose(box.high[:n], 2.0 * vmax, rtol=1e-6)
    np.testing.assert_allclose(box.high[n:], np.full(m, max_busy), rtol=1e-6)


def test_observation_is_volumes_then_pu_timers_in_physical_units():
    env = make()
    cfg = env.config
    n, m = cfg.n_containers, cfg.num_processing_units
    obs, _ = env.reset(seed=3)
    st = env.simulator.state
    np.testing.assert_array_equal(obs[:n], st.volumes[0].astype(np.float32))
    np.testing.assert_array_equal(obs[n:], np.zeros(m, dtype=np.float32))
    assert np.all(obs[:n] >= cfg.initial_volume_min) and np.all(obs[:n] <= cfg.initial_volume_max)
    largest_timer = 0.0
    for action in (1, 0, 3, 0, 5, 0, 0):
        obs, *_ = env.step(action)
        st = env.simulator.state
        assert obs.shape == (n + m,)
        np.testing.assert_array_equal(obs[:n], st.volumes[0].astype(np.float32))
        np.testing.assert_array_equal(obs[n:], st.pu_timers_s[0].astype(np.float32))
        largest_timer = max(largest_timer, float(obs[n:].max()))
    # Timers are seconds (β alone is > 50 s for every container), not fractions.
    assert largest_timer > 50.0


# ---- protocol and overrides ---------------------------------------------------------------------
def test_paper_test_protocol_sets_delta_120_and_T_600():
    env = gym.make(ENV_ID, config="n5_m2_dt60", protocol="paper_test")
    cfg = env.unwrapped.config
    assert cfg.timestep_s == 120.0
    assert cfg.episode_length_steps == 600
    # dt60 config's containers are untouched by the protocol
    assert cfg.container_names == ContainerGymEnv("n5_m2_dt60").config.container_names


def test_override_applies_after_protocol():
    env = ContainerGymEnv(CFG, protocol="paper_test", episode_length_steps=7)
    assert env.config.episode_length_steps == 7
    assert env.config.timestep_s == 120.0


def test_unknown_override_raises_value_error():
    with pytest.raises(ValueError, match="no_such_field"):
        ContainerGymEnv(CFG, no_such_field=3)


@pytest.mark.parametrize("via_make", [False, True])
def test_episode_truncates_after_exactly_T_steps(via_make):
    env = gym.make(ENV_ID, config=CFG, episode_length_steps=5) if via_make else make(episode_length_steps=5)
    env.reset(seed=0)
    for t in range(1, 6):
        _, _, terminated, truncated, info = env.step(0)
        assert terminated is False
        assert info["step"] == t
        assert truncated is (t == 5)


# ---- action validation --------------------------------------------------------------------------
BAD_ACTIONS = [
    -1,
    6,  # n + 1 for n = 5
    100,
    1.0,
    2.5,
    True,
    False,
    np.bool_(True),
    "1",
    None,
    np.array([1, 2]),
    np.array([[1]]),
    np.array([], dtype=np.int64),
    np.array(1.0),
    np.float32(1.0),
]


@pytest.mark.parametrize("bad", BAD_ACTIONS, ids=[repr(a) for a in BAD_ACTIONS])
def test_invalid_action_raises_naming_action_and_leaves_state_unchanged(bad):
    env, twin = make(), make()
    env.reset(seed=11)
    twin.reset(seed=11)
    env.step(1)
    twin.step(1)
    before = state_snapshot(env)
    with pytest.raises((ValueError, TypeError), match="action"):
        env.step(bad)
    after = state_snapshot(env)
    for x, y in zip(before, after):
        np.testing.assert_array_equal(x, y)
    # The next valid step behaves as if the bad action had never been seen (no RNG consumed).
    for action in (2, 0, 4):
        o1, r1, te1, tr1, i1 = env.step(action)
        o2, r2, te2, tr2, i2 = twin.step(action)
        np.testing.assert_array_equal(o1, o2)
        assert (r1, te1, tr1) == (r2, te2, tr2)
        assert_info_equal(i1, i2)


@pytest.mark.parametrize(
    "action", [3, np.int64(3), np.int32(3), np.uint8(3), np.array(3), np.array(3, dtype=np.int32)],
    ids=["int", "int64", "int32", "uint8", "0d-int64", "0d-int32"],
)
def test_integer_like_actions_are_accepted_and_equivalent(action):
    env, ref = make(), make()
    env.reset(seed=5)
    ref.reset(seed=5)
    o1, r1, _, _, i1 = env.step(action)
    o2, r2, _, _, i2 = ref.step(3)
    np.testing.assert_array_equal(o1, o2)
    assert r1 == r2
    assert_info_equal(i1, i2)
    assert i1["emptied_container"] == env.config.container_names[2]


# ---- episode end ---------------------------------------------------------------------------------
def test_step_after_truncation_raises_until_reset():
    env = make(episode_length_steps=2)
    env.reset(seed=0)
    env.step(0)
    *_, truncated, _ = env.step(0)
    assert truncated is True
    with pytest.raises(EpisodeFinishedError):
        env.step(0)
    with pytest.raises(EpisodeFinishedError):
        env.step(1)
    obs, info = env.reset()
    assert info["step"] == 0
    _, _, terminated, truncated, info = env.step(0)
    assert (terminated, truncated, info["step"]) == (False, False, 1)


def test_overflow_terminates_with_r_min_and_stepping_after_raises():
    env = make(initial_volume_min=39.0, initial_volume_max=39.9)
    cfg = env.config
    env.reset(seed=0)
    for _ in range(50):
        obs, reward, terminated, truncated, info = env.step(0)
        if terminated:
            break
    assert terminated is True
    assert truncated is False
    assert reward == cfg.overflow_reward
    vmax = np.array([c.max_volume for c in cfg.containers])
    over = tuple(name for name, v, vm in zip(cfg.container_names, env.simulator.state.volumes[0], vmax) if v >= vm)
    assert over and info["overflowed_containers"] == over
    with pytest.raises(EpisodeFinishedError):
        env.step(0)
    env.reset(seed=1)
    env.step(0)


# ---- emptying and info ----------------------------------------------------------------------------
@pytest.mark.parametrize("i", range(5))
def test_emptying_info_reward_and_pu_timer_follow_paper_formulas(i):
    env = make()
    cfg = env.config
    n = cfg.n_containers
    spec = cfg.containers[i]
    prev, _ = env.reset(seed=0)
    v = float(env.simulator.state.volumes[0, i])
    obs, reward, terminated, truncated, info = env.step(i + 1)
    assert not terminated and not truncated
    assert info["emptied_container"] == spec.name
    assert info["emptied_index"] == i
    assert np.float32(info["emptied_volume"]) == prev[i]
    assert info["emptied_volume"] == pytest.approx(v, rel=1e-12)
    expected_r = paper_reward(spec, v, cfg.penalty_reward)
    assert info["emptying_reward"] == pytest.approx(expected_r, rel=1e-9, abs=1e-12)
    assert reward == pytest.approx(expected_r, rel=1e-9, abs=1e-12)
    assert info["pu_index"] == 0  # both PUs free: the first one is taken
    assert info["no_free_pu"] is False
    assert info["free_pus"] == 2
    assert info["overflowed_containers"] == ()
    assert obs[i] == 0.0
    assert obs[n + 0] == pytest.approx(busy_time(spec, v), rel=1e-6)
    assert obs[n + 1] == 0.0
    others = [k for k in range(n) if k != i]
    assert np.all(obs[others] > 0.0)


def test_second_emptying_takes_second_pu_and_first_timer_counts_down():
    env = make()
    cfg = env.config
    n, dt = cfg.n_containers, cfg.timestep_s
    env.reset(seed=0)
    v0 = float(env.simulator.state.volumes[0, 0])  # 29.3 > b=27: busy β + λ
    g0 = busy_time(cfg.containers[0], v0)
    assert g0 > dt
    env.step(1)
    v4 = float(env.simulator.state.volumes[0, 4])
    obs, reward, _, _, info = env.step(5)
    assert info["pu_index"] == 1
    assert info["free_pus"] == 1
    assert info["emptied_volume"] == pytest.approx(v4)
    assert reward == pytest.approx(paper_reward(cfg.containers[4], v4, cfg.penalty_reward))
    assert obs[n] == pytest.approx(g0 - dt, rel=1e-6)
    assert obs[n + 1] == pytest.approx(busy_time(cfg.containers[4], v4), rel=1e-6)


def test_emptying_an_empty_container_gives_r_pen_and_still_uses_a_pu():
    env = make()
    cfg = env.config
    n = cfg.n_containers
    env.reset(seed=0)
    env.step(1)  # container 0 is now exactly empty, PU 0 busy
    assert env.simulator.state.volumes[0, 0] == 0.0
    obs, reward, _, _, info = env.step(1)
    assert reward == cfg.penalty_reward
    assert info["emptying_reward"] == cfg.penalty_reward
    assert info["emptied_container"] == cfg.container_names[0]
    assert info["emptied_volume"] == 0.0
    assert info["pu_index"] == 1
    assert info["no_free_pu"] is False
    assert obs[0] == 0.0
    assert obs[n + 1] == pytest.approx(cfg.containers[0].pu_offset_s, rel=1e-6)  # g(0) = β


def test_doing_nothing_gives_zero_reward_and_no_emptying():
    env = make()
    prev, _ = env.reset(seed=2)
    obs, reward, _, _, info = env.step(0)
    assert reward == 0.0
    assert info["emptied_container"] == ""
    assert info["emptied_index"] == -1
    assert info["emptied_volume"] == 0.0
    assert info["pu_index"] == -1
    assert info["no_free_pu"] is False
    assert info["emptying_reward"] == 0.0


# ---- action masks ---------------------------------------------------------------------------------
def test_action_masks_with_one_pu_and_penalty_when_busy():
    env = ContainerGymEnv(CFG, num_processing_units=1)
    twin = ContainerGymEnv(CFG, num_processing_units=1)
    cfg = env.config
    n, dt = cfg.n_containers, cfg.timestep_s
    assert env.observation_space.shape == (n + 1,)
    env.reset(seed=0)
    twin.reset(seed=0)
    mask = env.action_masks()
    assert mask.dtype == np.bool_ and mask.shape == (n + 1,)
    assert mask.all()

    v0 = float(env.simulator.state.volumes[0, 0])
    g = busy_time(cfg.containers[0], v0)
    obs, *_ = env.step(1)
    twin.step(1)
    assert obs[n] == pytest.approx(g, rel=1e-6)
    np.testing.assert_array_equal(env.action_masks(), [True] + [False] * n)

    # Emptying while masked: r_pen, nothing emptied; the physics is that of "do nothing".
    obs_pen, r_pen, te, tr, info = env.step(2)
    obs_wait, r_wait, *_ = twin.step(0)
    assert r_pen == cfg.penalty_reward
    assert r_wait == 0.0
    assert info["no_free_pu"] is True
    assert info["emptied_container"] == ""
    assert info["emptied_index"] == -1
    assert info["pu_index"] == -1
    assert info["free_pus"] == 0
    assert info["emptying_reward"] == cfg.penalty_reward
    np.testing.assert_array_equal(obs_pen, obs_wait)
    assert obs_pen[1] > 0.0
    assert obs_pen[n] == pytest.approx(g - dt, rel=1e-6)

    # The PU frees up after ⌈g/δ⌉ steps in total; the mask follows the timer.
    steps_busy = math.ceil(g / dt)
    for k in range(2, steps_busy):
        obs, *_ = env.step(0)
        assert obs[n] == pytest.approx(g - k * dt, rel=1e-6)
        np.testing.assert_array_equal(env.action_masks(), [True] + [False] * n)
    obs, *_ = env.step(0)
    assert obs[n] == 0.0
    assert env.action_masks().all()


# ---- seeding --------------------------------------------------------------------------------------
def _trajectory(env, seed, steps=50):
    out = []
    obs, info = env.reset(seed=seed)
    out.append((obs.copy(), None, None, None, info))
    for t in range(steps):
        obs, r, te, tr, info = env.step(t % (env.n_containers + 1))
        out.append((obs.copy(), r, te, tr, info))
        if te or tr:
            break
    return out


def test_same_seed_gives_identical_trajectories():
    t1 = _trajectory(make(), 123)
    t2 = _trajectory(make(), 123)
    assert len(t1) == len(t2) == 51
    for a, b in zip(t1, t2):
        np.testing.assert_array_equal(a[0], b[0])
        assert a[1:4] == b[1:4]
        assert_info_equal(a[4], b[4])


def test_reseeding_same_env_reproduces_trajectory():
    env = make()
    t1 = _trajectory(env, 9, steps=20)
    t2 = _trajectory(env, 9, steps=20)
    for a, b in zip(t1, t2):
        np.testing.assert_array_equal(a[0], b[0])
        assert a[1:4] == b[1:4]


def test_different_seeds_give_different_initial_volumes():
    firsts = [make().reset(seed=s)[0] for s in range(5)]
    for i in range(5):
        for j in range(i + 1, 5):
            assert not np.array_equal(firsts[i], firsts[j])


def test_reset_without_seed_continues_the_stream_deterministically():
    env, twin = make(), make()
    o1, _ = env.reset(seed=4)
    o2, _ = env.reset()
    assert not np.array_equal(o1, o2)
    t1, _ = twin.reset(seed=4)
    t2, _ = twin.reset()
    np.testing.assert_array_equal(o1, t1)
    np.testing.assert_array_equal(o2, t2)


# ---- rendering ------------------------------------------------------------------------------------
def test_ansi_render_shows_every_container_and_its_volume():
    env = make(render_mode="ansi")
    env.reset(seed=0)
    for action in (None, 1, 0, 4):
        if action is not None:
            env.step(action)
        text = env.render()
        assert isinstance(text, str)
        for name, v in zip(env.config.container_names, env.simulator.state.volumes[0]):
            assert name in text
            assert f"{v:.2f}" in text


def test_render_without_mode_returns_none():
    env = make()
    env.reset(seed=0)
    assert env.render() is None


@pytest.mark.parametrize("mode", ["bogus", "rgb", "depth_array"])
def test_unsupported_render_mode_raises(mode):
    with pytest.raises(ValueError, match="render_mode"):
        make(render_mode=mode)
    # Gymnasium itself warns about the unknown mode before the env rejects it.
    with pytest.warns(UserWarning, match="render_mode"), pytest.raises(ValueError, match="render_mode"):
        gym.make(ENV_ID, config=CFG, render_mode=mode)


# ---- learning smoke tests -------------------------------------------------------------------------
def test_maskable_ppo_learns_end_to_end_and_respects_masks():
    from sb3_contrib import MaskablePPO
    from sb3_contrib.common.maskable.utils import is_masking_supported

    env = gym.make(ENV_ID, config=CFG, num_processing_units=1)
    assert is_masking_supported(env)
    model = MaskablePPO("MlpPolicy", env, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=256)
    assert model.num_timesteps >= 256

    # With the only PU busy every emptying action is masked: sampling must always pick 0.
    base = env.unwrapped
    obs, _ = base.reset(seed=0)
    obs, *_ = base.step(1)
    masks = base.action_masks()
    assert masks.tolist() == [True] + [False] * base.n_containers
    for _ in range(20):
        action, _ = model.predict(obs, action_masks=masks, deterministic=False)
        assert int(action) == 0


def test_ppo_learns_end_to_end():
    from stable_baselines3 import PPO

    env = gym.make(ENV_ID, config=CFG)
    model = PPO("MlpPolicy", env, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=256)
    assert model.num_timesteps >= 256
    obs, _ = env.reset(seed=0)
    action, _ = model.predict(obs, deterministic=True)
    env.step(action)  # SB3's predicted action (0-d array) is a valid action
