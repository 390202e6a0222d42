"""Info dicts keep one layout: the same keys, with values of the same types (and dtypes), at reset
and at every step, never None, in both views and the Gymnasium vector envs.

Libraries build their info specs or arrays from the first info they see: TorchRL's
``PettingZooWrapper`` from the reset infos, Gymnasium's vector envs from the first value of each
key (an ``int`` array stays int, ``None`` breaks ``int()``).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import containergym_marl  # noqa: F401  (registers the Gymnasium id)
from containergym_marl import ENV_ID, ContainerGymEnv
from containergym_marl.core.dynamics import ARBITRATION_RULES
from containergym_marl.envs import container_agents_v0
from containergym_marl.envs.vector import ContainerGymVectorEnv

from tests.helpers import CFG
# both kinds of ends within a few dozen steps: time limits and overflows (full starting volumes)
ENDS = dict(episode_length_steps=20, initial_volume_min=25.0, initial_volume_max=39.5)


def layout(info: dict) -> dict[str, object]:
    """Key -> type of the value (with dtype and shape for arrays)."""
    out = {}
    for key, value in info.items():
        assert value is not None, f"info[{key!r}] is None"
        out[key] = (type(value), value.dtype, value.shape) if isinstance(value, np.ndarray) else type(value)
    return out


# ---- centralised view ---------------------------------------------------------------------------
@pytest.mark.parametrize("config,overrides", [(CFG, ENDS), ("n11_m2_dt60", dict(episode_length_steps=40))])
def test_centralised_infos_have_the_reset_layout_at_every_step(config, overrides):
    env = ContainerGymEnv(config, **overrides)
    n = env.n_containers
    rng = np.random.default_rng(0)
    _, info = env.reset(seed=0)
    expected = layout(info)
    assert info == {"step": 0, "emptied_container": "", "emptied_index": -1, "emptied_volume": 0.0,
                    "emptying_reward": 0.0, "pu_index": -1, "no_free_pu": False,
                    "overflowed_containers": (), "free_pus": env.n_pus}
    seen = {"emptied": 0, "denied": 0, "idle": 0, "overflow": 0, "time_limit": 0}
    for _ in range(600):
        action = int(rng.integers(1, n + 1)) if rng.random() < 0.6 else 0
        _, _, terminated, truncated, info = env.step(action)
        assert layout(info) == expected
        if info["pu_index"] >= 0:
            seen["emptied"] += 1
            assert info["emptied_container"] == env.config.container_names[action - 1]
            assert info["emptied_index"] == action - 1
        else:
            assert (info["emptied_container"], info["emptied_index"], info["emptied_volume"]) == ("", -1, 0.0)
            seen["denied" if info["no_free_pu"] else "idle"] += 1
        if terminated or truncated:
            seen["overflow" if terminated else "time_limit"] += 1
            assert bool(info["overflowed_containers"]) == terminated
            _, info = env.reset()
            assert layout(info) == expected
    assert all(seen.values()), seen  # every kind of step and end was checked


# ---- decentralised view -------------------------------------------------------------------------
@pytest.mark.parametrize("masking", [False, True])
@pytest.mark.parametrize("reward_mode", ["individual", "team"])
@pytest.mark.parametrize("arbitration", ARBITRATION_RULES)
def test_agent_infos_have_the_reset_layout_at_every_step(arbitration, reward_mode, masking):
    env = container_agents_v0.parallel_env(config=CFG, arbitration=arbitration, reward_mode=reward_mode,
                                           action_masking=masking, **ENDS)
    rng = np.random.default_rng(1)
    _, infos = env.reset(seed=1)
    assert set(infos) == set(env.possible_agents)
    expected = layout(infos[env.possible_agents[0]])
    assert {"requested", "granted", "denied", "pu_index", "emptied_volume", "emptying_reward",
            "overflowed", "plant_reward", "free_pus", "step"} <= set(expected)
    assert ("action_mask" in expected) == masking
    seen = {"granted": 0, "denied": 0, "ends": 0}
    for _ in range(300):
        if not env.agents:
            seen["ends"] += 1
            _, infos = env.reset()
            assert all(layout(i) == expected for i in infos.values())
        _, _, _, _, infos = env.step({a: int(rng.random() < 0.5) for a in env.agents})
        for info in infos.values():
            assert layout(info) == expected
            seen["granted"] += info["granted"]
            seen["denied"] += info["denied"]
            if not info["granted"]:
                assert (info["pu_index"], info["emptied_volume"]) == (-1, 0.0)
    assert all(seen.values()), seen


def test_agent_reset_infos_are_neutral():
    env = container_agents_v0.parallel_env(config=CFG, action_masking=True)
    _, infos = env.reset(seed=0)
    for info in infos.values():
        mask = info.pop("action_mask")
        assert mask.dtype == np.int8 and mask.tolist() == [1, 1]
        assert info == {"requested": False, "granted": False, "denied": False, "pu_index": -1,
                        "emptied_volume": 0.0, "emptying_reward": 0.0, "overflowed": False,
                        "plant_reward": 0.0, "free_pus": 2, "step": 0}


# ---- Gymnasium vector envs ----------------------------------------------------------------------
def _run_vector(venv, steps=50, seed=3):
    """Random steps; returns the infos and checks that the batched keys keep their dtypes."""
    n = 5
    rng = np.random.default_rng(seed)
    _, info = venv.reset(seed=seed)
    dtypes = {k: v.dtype for k, v in info.items()}
    ends = 0
    history = [info]
    for _ in range(steps):
        actions = np.where(rng.random(venv.num_envs) < 0.5, rng.integers(1, n + 1, venv.num_envs), 0)
        _, _, term, trunc, info = venv.step(actions)
        ends += int(term.sum() + trunc.sum())
        for key, dtype in dtypes.items():
            assert info[key].dtype == dtype, key
        history.append(info)
    assert ends > 0  # autoreset and the reset infos of restarted simulations were exercised
    return history


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_make_vec_sync_and_async_run(mode):
    venv = gym.make_vec(ENV_ID, num_envs=3, vectorization_mode=mode, config=CFG, **ENDS)
    try:
        history = _run_vector(venv)
    except BaseException:
        # a failed step leaves the async workers' pipes unread; a plain close() would wait on them
        venv.close(**({"terminate": True} if mode == "async" else {}))
        raise
    venv.close()
    first = history[0]
    assert first["pu_index"].dtype == np.int64 and first["emptied_volume"].dtype == np.float64
    assert first["no_free_pu"].dtype == np.bool_ and first["_pu_index"].all()


def test_make_vec_vector_entry_point_runs_with_the_same_info_keys():
    venv = gym.make_vec(ENV_ID, num_envs=3, vectorization_mode="vector_entry_point", config=CFG, **ENDS)
    assert isinstance(venv.unwrapped, ContainerGymVectorEnv)
    history = _run_vector(venv)
    single_keys = set(ContainerGymEnv(CFG).reset(seed=0)[1])
    for info in history:
        assert single_keys | {f"_{k}" for k in single_keys} <= set(info)


def _assert_batched_equal(native: dict, sync: dict, where: str) -> None:
    assert set(native) == set(sync), where
    for key, s in sync.items():
        v = native[key]
        if isinstance(s, dict):
            _assert_batched_equal(v, s, f"{where}/{key}")
        elif key == "final_obs":  # a float array in the native env, an object array in Gymnasium's
            for b in np.flatnonzero(sync["_final_obs"]):
                np.testing.assert_array_equal(v[b], s[b])
        else:
            assert v.dtype == s.dtype, f"{where}/{key}"
            assert v.tolist() == s.tolist(), f"{where}/{key}"


@pytest.mark.parametrize("B", [1, 4])
def test_native_vector_env_infos_equal_the_sync_vector_env(B):
    """The native env computes, for all simulations at once, the infos that Gymnasium's sync
    vector env (same autoreset mode) assembles from the single envs: keys, dtypes and values."""
    kwargs = dict(config=CFG, **ENDS)
    native = ContainerGymVectorEnv(num_envs=B, **kwargs)
    sync = gym.make_vec(ENV_ID, num_envs=B, vectorization_mode="sync",
                        vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP}, **kwargs)
    _, ni = native.reset(seed=5)
    _, si = sync.reset(seed=5)
    _assert_batched_equal(ni, si, "reset")
    rng = np.random.default_rng(5)
    ends = 0
    for t in range(80):
        actions = np.where(rng.random(B) < 0.6, rng.integers(1, 6, B), 0)
        nobs, nr, nte, ntr, ni = native.step(actions)
        sobs, sr, ste, str_, si = sync.step(actions)
        np.testing.assert_array_equal(nobs, sobs)
        np.testing.assert_array_equal(nr, sr)
        ends += int(nte.sum() + ntr.sum())
        _assert_batched_equal(ni, si, f"step {t}")
    assert ends >= 2
    sync.close()
