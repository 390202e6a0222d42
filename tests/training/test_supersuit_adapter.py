"""The SuperSuit path: each known SuperSuit 3.11 + SB3 2.9 problem, shown on the raw stack and
fixed by the package's adapter; and the adapter equals our native vectorised env."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest
import supersuit
from stable_baselines3 import PPO

from containergym_marl.envs.container_agents_v0 import parallel_env
from containergym_marl.envs.vector import ContainerAgentsVecEnv
from containergym_marl.training.supersuit_adapter import SuperSuitVecEnv

N = 5  # agents of n5_m2_dt120


def raw_stack(par, copies, num_cpus=0, base_class="stable_baselines3"):
    return supersuit.concat_vec_envs_v1(supersuit.pettingzoo_env_to_vec_env_v1(par), copies,
                                        num_cpus=num_cpus, base_class=base_class)


def copy_obs(obs, k):
    return obs[k * N:(k + 1) * N]


# ---- problem 1: no seed() / get_attr / env_method ---------------------------------------------
def test_raw_stack_breaks_ppo_seed():
    venv = raw_stack(parallel_env(config="n5_m2_dt120"), 2)
    with pytest.raises(AttributeError):
        PPO("MlpPolicy", venv, n_steps=32, batch_size=32, seed=1)
    with pytest.raises(AttributeError):
        venv.venv.seed(1)


def test_adapter_accepts_ppo_seed_and_is_reproducible():
    returns = []
    for _ in range(2):
        venv = SuperSuitVecEnv(num_copies=2, config="n5_m2_dt120")
        model = PPO("MlpPolicy", venv, n_steps=32, batch_size=32, seed=1, device="cpu")
        model.learn(64)
        returns.append(model.rollout_buffer.rewards.copy())
        venv.close()
    np.testing.assert_array_equal(returns[0], returns[1])
    assert venv.get_attr("render_mode") == [None] * venv.num_envs


# ---- problem 2: copies share an RNG; worker seeds overlap -------------------------------------
def test_raw_copies_of_a_used_env_replay_the_same_episode():
    par = parallel_env(config="n5_m2_dt120")
    par.reset(seed=0)  # e.g. the user checked the env before wrapping it
    venv = raw_stack(par, 3)
    obs = venv.reset()
    assert np.array_equal(copy_obs(obs, 0), copy_obs(obs, 1)) and np.array_equal(copy_obs(obs, 1), copy_obs(obs, 2))


def test_raw_multiprocess_seeds_overlap():
    venv = raw_stack(parallel_env(config="n5_m2_dt120"), 4, num_cpus=2, base_class="gymnasium")
    try:
        obs, _ = venv.reset(seed=10)
        # worker 0 seeds copies 10, 11; worker 1 seeds 11, 12: copies 1 and 2 coincide
        assert np.array_equal(copy_obs(obs, 1), copy_obs(obs, 2))
    finally:
        venv.close()


@pytest.mark.parametrize("num_cpus", [0, 2])
def test_adapter_seeds_copy_k_with_seed_plus_k(num_cpus):
    venv = SuperSuitVecEnv(num_copies=4, num_cpus=num_cpus, config="n5_m2_dt120")
    try:
        venv.seed(10)
        obs = venv.reset()
        for k in range(4):
            ref, _ = parallel_env(config="n5_m2_dt120").reset(seed=10 + k)
            np.testing.assert_array_equal(copy_obs(obs, k), np.stack(list(ref.values())))
        assert len({copy_obs(obs, k).tobytes() for k in range(4)}) == 4
    finally:
        venv.close()


# ---- problem 3: truncation merged into dones ----------------------------------------------------
def _run_to_end(venv, steps):
    venv.reset()
    for _ in range(steps):
        _, _, dones, infos = venv.step(np.zeros(venv.num_envs, dtype=np.int64))
    return dones, infos


def test_raw_stack_loses_time_limit_truncation():
    par = parallel_env(config="n5_m2_dt120", episode_length_steps=3)
    dones, infos = _run_to_end(raw_stack(par, 1), 3)
    assert dones.all() and not any(i.get("TimeLimit.truncated", False) for i in infos)


def test_adapter_marks_time_limit_cuts_and_not_overflows():
    venv = SuperSuitVecEnv(num_copies=1, seed=0, config="n5_m2_dt120", episode_length_steps=3)
    dones, infos = _run_to_end(venv, 3)
    assert dones.all() and all(i["TimeLimit.truncated"] for i in infos)
    assert all("terminal_observation" in i for i in infos)
    over = SuperSuitVecEnv(num_copies=1, seed=0, config="n5_m2_dt120",
                           initial_volume_min=39.0, initial_volume_max=39.9)
    dones, infos = _run_to_end(over, 1)
    assert dones.all() and not any(i["TimeLimit.truncated"] for i in infos)


# ---- problem 4: hang at exit with worker processes ----------------------------------------------
EXIT_SCRIPT = """
import numpy as np, supersuit
from containergym_marl.envs.container_agents_v0 import parallel_env
{make}
venv.reset()
venv.step(np.zeros(venv.num_envs, dtype=np.int64))
print("done", flush=True)
"""
RAW = ("venv = supersuit.concat_vec_envs_v1(supersuit.pettingzoo_env_to_vec_env_v1("
       "parallel_env(config='n5_m2_dt120')), 2, num_cpus=2, base_class='stable_baselines3')")
ADAPTED = ("from containergym_marl.training.supersuit_adapter import SuperSuitVecEnv\n"
           "venv = SuperSuitVecEnv(num_copies=2, num_cpus=2, seed=0, config='n5_m2_dt120')")


def _exits_within(make: str, seconds: float) -> bool:
    code = textwrap.dedent(EXIT_SCRIPT.format(make=make))
    try:
        subprocess.run([sys.executable, "-c", code], timeout=seconds, capture_output=True, check=True)
        return True
    except subprocess.TimeoutExpired:
        return False


def test_adapter_process_exits_without_close():
    assert _exits_within(ADAPTED, 60)


@pytest.mark.slow
def test_raw_multiprocess_stack_hangs_at_exit_without_close():
    assert not _exits_within(RAW, 30)


# ---- the SuperSuit path equals the native vectorised env ----------------------------------------
@pytest.mark.parametrize("reward_mode", ["individual", "team"])
def test_adapter_equals_native_agents_vec_env(reward_mode):
    # containers that start up to nearly full: some overflow under the random requests
    kwargs = dict(config="n5_m2_dt120", episode_length_steps=30, reward_mode=reward_mode, initial_volume_max=39.0)
    ss = SuperSuitVecEnv(num_copies=3, seed=7, **kwargs)
    native = ContainerAgentsVecEnv(num_sims=3, **kwargs)
    native.seed(7)
    np.testing.assert_array_equal(ss.reset(), native.reset())
    rng = np.random.default_rng(0)
    ends = overflows = 0
    for _ in range(70):  # crosses two automatic resets
        actions = (rng.random(ss.num_envs) < 0.2).astype(np.int64)
        o1, r1, d1, i1 = ss.step(actions)
        o2, r2, d2, i2 = native.step(actions)
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_array_equal(d1, d2)
        np.testing.assert_array_equal(ss.overflow_slots(), native.overflow_slots())  # the slots at r_min
        overflows += int(native.overflow_slots().sum())
        for a, b in zip(i1, i2):
            if "terminal_observation" in b:
                ends += 1
                np.testing.assert_array_equal(a["terminal_observation"], b["terminal_observation"])
                assert a["TimeLimit.truncated"] == b["TimeLimit.truncated"]
    assert ends > 0 and overflows > 0
