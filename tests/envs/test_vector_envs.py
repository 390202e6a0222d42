"""The native vectorised environments (``containergym_marl.envs.vector``).

* SB3's VecEnv contract: shapes and dtypes, autoreset with ``terminal_observation`` and
  ``TimeLimit.truncated``, seeding, ``env_method("action_masks")``; PPO and MaskablePPO learn on them.
* B simulations equal B single environments (Gymnasium / PettingZoo) with seeds ``seed + b``,
  also for B >= 64, where the core switches to its large-batch code paths.
* The Gymnasium VectorEnv registered as the id's ``vector_entry_point``.
* The core's fast paths equal the plain numpy forms they replace.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import textwrap

import gymnasium as gym
import numpy as np
import pytest

from containergym_marl.core.params import PlantParams
import containergym_marl  # noqa: F401  (registers the Gymnasium id)
from containergym_marl import ContainerGymEnv, load_config
from containergym_marl.core import BLOCK_ROWS, NoiseStreams, dynamics
from containergym_marl.envs import container_agents_v0
from containergym_marl.envs.vector import (
    NO_INFO,
    ContainerAgentsVecEnv,
    ContainerGymVecEnv,
    ContainerGymVectorEnv,
)
from tests.helpers import CFG, ROOT

SHORT = dict(episode_length_steps=25)  # many time-limit ends in few steps
# both kinds of ends within a few dozen steps: time limits and overflows (full starting volumes)
ENDS = dict(episode_length_steps=20, initial_volume_min=25.0, initial_volume_max=39.5)


def central_actions(rng, num, n, p_empty=0.4):
    return np.where(rng.random(num) < p_empty, rng.integers(1, n + 1, num), 0).astype(np.int64)


# ---- SB3 VecEnv contract ----------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["central", "agents"])
def test_sb3_shapes_dtypes_and_infos(kind):
    B = 3
    venv = ContainerGymVecEnv(CFG, num_envs=B) if kind == "central" else ContainerAgentsVecEnv(CFG, num_sims=B)
    n = venv.config.n_containers
    slots = B if kind == "central" else B * n
    assert venv.num_envs == slots
    venv.seed(0)
    obs = venv.reset()
    assert obs.shape == (slots, *venv.observation_space.shape) and obs.dtype == np.float32
    assert venv.observation_space.contains(obs[0])
    rng = np.random.default_rng(0)
    for _ in range(30):
        if kind == "central":
            actions = central_actions(rng, slots, n)
        else:
            actions = rng.integers(0, 2, slots)
        obs, rewards, dones, infos = venv.step(actions)
        assert obs.shape == (slots, *venv.observation_space.shape) and obs.dtype == np.float32
        assert rewards.shape == (slots,) and rewards.dtype == np.float32
        assert dones.shape == (slots,) and dones.dtype == np.bool_
        assert isinstance(infos, list) and len(infos) == slots and all(isinstance(i, dict) for i in infos)
        assert all(venv.observation_space.contains(o) for o in obs)
    masks = venv.env_method("action_masks")
    assert len(masks) == slots and masks[0].dtype == np.bool_
    assert np.array_equal(np.stack(masks), venv.action_masks())
    assert venv.get_attr("render_mode") == [None] * slots
    assert venv.env_is_wrapped(gym.Wrapper) == [False] * slots
    venv.close()


def test_infos_of_unfinished_slots_are_the_shared_read_only_dict():
    venv = ContainerGymVecEnv(CFG, num_envs=2)
    venv.seed(0)
    venv.reset()
    _, _, dones, infos = venv.step(np.zeros(2, dtype=np.int64))
    assert not dones.any() and all(i is NO_INFO for i in infos)
    with pytest.raises(TypeError, match="read-only"):
        infos[0]["episode"] = {}
    with pytest.raises(TypeError):
        infos[0].update(a=1)
    copy = infos[0].copy()
    copy["episode"] = 1  # SB3's VecMonitor copies before writing
    assert type(copy) is dict and NO_INFO == {}
    assert pickle.loads(pickle.dumps(NO_INFO)) == {}


def test_time_limit_ends_are_marked_truncated_with_terminal_observation():
    B, T = 4, 5
    venv = ContainerGymVecEnv(CFG, num_envs=B, episode_length_steps=T)
    venv.seed(1)
    venv.reset()
    for t in range(T):
        obs, _, dones, infos = venv.step(np.zeros(B, dtype=np.int64))
    assert dones.all()
    for b in range(B):
        assert infos[b]["TimeLimit.truncated"] is True
        assert infos[b]["terminal_observation"].shape == venv.observation_space.shape
    # the returned observation is the first of the next episode: all PUs free, new volumes
    assert (obs[:, 5:] == 0).all() and not np.array_equal(obs, np.stack([i["terminal_observation"] for i in infos]))


def test_overflow_ends_are_not_truncated():
    venv = ContainerAgentsVecEnv(CFG, num_sims=2, initial_volume_min=39.5, initial_volume_max=39.9)
    venv.seed(0)
    venv.reset()
    _, rewards, dones, infos = venv.step(np.zeros(venv.num_envs, dtype=np.int64))
    assert dones.all()
    assert all(i["TimeLimit.truncated"] is False for i in infos)
    assert (rewards[[i for i in range(venv.num_envs) if infos[i]["terminal_observation"][0] >= 1.0]] == -1.0).all()


# ---- batch = B single environments ------------------------------------------------------------
@pytest.mark.parametrize("B", [3, 66])  # 66: the large-batch paths of the core (tiles, column loops)
def test_centralised_vec_env_equals_single_envs(B):
    seed, steps = 100, 60
    overrides = ENDS
    venv = ContainerGymVecEnv(CFG, num_envs=B, **overrides)
    venv.seed(seed)
    obs = venv.reset()
    singles = [ContainerGymEnv(CFG, **overrides) for _ in range(B)]
    first = [e.reset(seed=seed + b)[0] for b, e in enumerate(singles)]
    np.testing.assert_array_equal(obs, np.stack(first))
    rng = np.random.default_rng(7)
    ends = {"terminated": 0, "truncated": 0}
    n = venv.config.n_containers
    for _ in range(steps):
        actions = central_actions(rng, B, n)
        obs, rewards, dones, infos = venv.step(actions)
        for b, env in enumerate(singles):
            o, r, term, trunc, _ = env.step(int(actions[b]))
            assert rewards[b] == np.float32(r)
            assert dones[b] == (term or trunc)
            if term or trunc:
                ends["terminated" if term else "truncated"] += 1
                np.testing.assert_array_equal(infos[b]["terminal_observation"], o)
                assert infos[b]["TimeLimit.truncated"] == trunc
                o, _ = env.reset()
            else:
                assert "terminal_observation" not in infos[b]
            np.testing.assert_array_equal(obs[b], o)
    assert ends["truncated"] > 0 and ends["terminated"] > 0


@pytest.mark.parametrize("B,rule,mode", [(3, "fullest", "individual"), (3, "random", "team"),
                                         (65, "best_reward", "individual")])
def test_agents_vec_env_equals_parallel_envs(B, rule, mode):
    seed, steps = 20, 40 if B > 3 else 60
    kw = dict(config=CFG, arbitration=rule, reward_mode=mode, **ENDS)
    venv = ContainerAgentsVecEnv(num_sims=B, **kw)
    n = venv.n_agents
    venv.seed(seed)
    obs = venv.reset()
    pars = [container_agents_v0.parallel_env(**kw) for _ in range(B)]
    for b, par in enumerate(pars):
        o, _ = par.reset(seed=seed + b)
        np.testing.assert_array_equal(obs[b * n:(b + 1) * n], np.stack([o[a] for a in par.possible_agents]))
    rng = np.random.default_rng(3)
    ends = {"terminated": 0, "truncated": 0}
    for _ in range(steps):
        actions = (rng.random(B * n) < 0.35).astype(np.int64)
        obs, rewards, dones, infos = venv.step(actions)
        for b, par in enumerate(pars):
            agents = par.possible_agents
            o, r, term, trunc, _ = par.step({a: int(actions[b * n + i]) for i, a in enumerate(agents)})
            sl = slice(b * n, (b + 1) * n)
            np.testing.assert_array_equal(rewards[sl], np.array([r[a] for a in agents], dtype=np.float32))
            end = term[agents[0]] or trunc[agents[0]]
            assert (dones[sl] == end).all()
            if end:
                ends["terminated" if term[agents[0]] else "truncated"] += 1
                for i, a in enumerate(agents):
                    np.testing.assert_array_equal(infos[b * n + i]["terminal_observation"], o[a])
                    assert infos[b * n + i]["TimeLimit.truncated"] == trunc[a]
                o, _ = par.reset()
            np.testing.assert_array_equal(obs[sl], np.stack([o[a] for a in agents]))
    assert ends["truncated"] > 0 and ends["terminated"] > 0


# ---- seeding ------------------------------------------------------------------------------------
@pytest.mark.parametrize("cls", [ContainerGymVecEnv, ContainerAgentsVecEnv])
def test_seeding_is_reproducible_and_simulations_are_independent(cls):
    def rollout(seed):
        venv = cls(CFG, 8, **SHORT)
        venv.seed(seed)
        frames = [venv.reset()]
        for _ in range(40):
            frames.append(venv.step(np.zeros(venv.num_envs, dtype=np.int64))[0])
        return np.stack(frames), venv

    a, venv = rollout(5)
    b, _ = rollout(5)
    c, _ = rollout(6)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    per_sim = a.reshape(a.shape[0], 8, -1)  # (time, simulation, features of all its slots)
    assert len({per_sim[:, s].tobytes() for s in range(8)}) == 8
    # seed(s) gives simulation b the stream of seed s + b: seed 6 is seed 5 shifted by one sim
    np.testing.assert_array_equal(per_sim[:, 1:], c.reshape(c.shape[0], 8, -1)[:, :-1])


def test_unseeded_vec_envs_differ():
    a, b = ContainerGymVecEnv(CFG, 4), ContainerGymVecEnv(CFG, 4)
    assert not np.array_equal(a.reset(), b.reset())


# ---- invalid actions ----------------------------------------------------------------------------
def test_invalid_actions_raise_naming_the_slot():
    venv = ContainerAgentsVecEnv(CFG, num_sims=2)
    venv.seed(0)
    venv.reset()
    bad = np.zeros(10, dtype=np.int64)
    bad[7] = 2
    with pytest.raises(ValueError, match=r"slot 7 \(simulation 1, agent 2\)"):
        venv.step(bad)
    with pytest.raises(ValueError, match="10 integer actions"):
        venv.step(np.zeros(9, dtype=np.int64))
    with pytest.raises(ValueError, match="integer"):
        venv.step(np.zeros(10))
    cvenv = ContainerGymVecEnv(CFG, num_envs=3)
    cvenv.seed(0)
    cvenv.reset()
    with pytest.raises(ValueError, match=r"env 1 has action 6 outside \[0, 5\]"):
        cvenv.step(np.array([0, 6, 0]))
    with pytest.raises(ValueError, match=r"env 2 has action -1"):
        cvenv.step(np.array([0, 0, -1]))


# ---- Gymnasium VectorEnv (vector_entry_point) ---------------------------------------------------
def test_make_vec_uses_the_native_vector_env_and_equals_single_envs():
    B, seed = 4, 9
    venv = gym.make_vec("containergym_marl/ContainerGym-v0", num_envs=B,
                        vectorization_mode="vector_entry_point", config=CFG, **SHORT)
    assert isinstance(venv.unwrapped, ContainerGymVectorEnv)
    obs, info = venv.reset(seed=seed)
    assert obs.shape == (B, 7) and obs.dtype == np.float32
    singles = [ContainerGymEnv(CFG, **SHORT) for _ in range(B)]
    np.testing.assert_array_equal(obs, np.stack([e.reset(seed=seed + b)[0] for b, e in enumerate(singles)]))
    rng = np.random.default_rng(0)
    saw_final = False
    for _ in range(60):
        actions = central_actions(rng, B, 5)
        obs, rewards, term, trunc, infos = venv.step(actions)
        assert rewards.shape == (B,) and term.dtype == np.bool_ and trunc.dtype == np.bool_
        for b, env in enumerate(singles):
            o, r, te, tr, _ = env.step(int(actions[b]))
            assert rewards[b] == r and term[b] == te and trunc[b] == tr
            if te or tr:
                saw_final = True
                assert infos["_final_obs"][b]
                np.testing.assert_array_equal(infos["final_obs"][b], o)
                o, _ = env.reset()
            elif "_final_obs" in infos:
                assert not infos["_final_obs"][b]
            np.testing.assert_array_equal(obs[b], o)
    assert saw_final
    venv.close()


def test_gymnasium_vector_env_requires_reset_and_rejects_bad_actions():
    venv = ContainerGymVectorEnv(num_envs=2, config=CFG)
    with pytest.raises(RuntimeError, match="reset"):
        venv.step(np.zeros(2, dtype=np.int64))
    venv.reset(seed=0)
    with pytest.raises(ValueError, match="env 0 has action 9"):
        venv.step(np.array([9, 0]))


# ---- without the training extra ------------------------------------------------------------------
def test_sb3_vec_envs_without_sb3_raise_an_import_error_naming_the_extra():
    """With stable-baselines3 missing, the module imports, the Gymnasium vector env works, and the
    SB3 VecEnvs raise an ImportError naming the extra (not a TypeError from object.__init__)."""
    code = textwrap.dedent("""
        import sys
        sys.modules["stable_baselines3"] = None  # makes `import stable_baselines3...` fail
        import numpy as np
        from containergym_marl.envs.vector import (
            ContainerAgentsVecEnv, ContainerGymVecEnv, ContainerGymVectorEnv)
        venv = ContainerGymVectorEnv(num_envs=2, config="n5_m2_dt120")
        venv.reset(seed=0)
        venv.step(np.zeros(2, dtype=np.int64))
        for cls, kwargs in ((ContainerAgentsVecEnv, {"num_sims": 2}), (ContainerGymVecEnv, {"num_envs": 2})):
            try:
                cls("n5_m2_dt120", **kwargs)
            except ImportError as e:
                print(cls.__name__, "|", e)
            else:
                print(cls.__name__, "| no error")
    """)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert [line.split(" | ")[0] for line in lines] == ["ContainerAgentsVecEnv", "ContainerGymVecEnv"]
    for line in lines:
        assert "pip install 'containergym-marl[train]'" in line and "stable-baselines3" in line, line


# ---- learning on the native vec envs -------------------------------------------------------------
def test_ppo_and_maskable_ppo_learn_on_the_native_vec_envs():
    from sb3_contrib import MaskablePPO
    from stable_baselines3 import PPO

    agents = ContainerAgentsVecEnv(CFG, num_sims=4)
    model = PPO("MlpPolicy", agents, n_steps=16, batch_size=40, n_epochs=1, seed=0, device="cpu")
    model.learn(320)
    assert model.num_timesteps >= 320
    central = ContainerGymVecEnv(CFG, num_envs=4)
    masked = MaskablePPO("MlpPolicy", central, n_steps=32, batch_size=64, n_epochs=1, seed=0, device="cpu")
    masked.learn(256)
    assert masked.num_timesteps >= 256


# ---- arbitration and random streams ------------------------------------------------------------
@pytest.mark.parametrize("B", [dynamics.PARALLEL_MIN_BATCH - 100, dynamics.PARALLEL_MIN_BATCH + 100])  # threaded above
def test_arbitration_equals_a_stable_sort_of_the_priorities(B):
    """The "random" rule's priorities are the step's uniforms: with many ties (rounded), the grants
    are the first `free` requests of a stable sort by decreasing priority, whatever the batch."""
    cfg = load_config("n11_m11_dt120")
    params = PlantParams.from_config(cfg)
    rng = np.random.default_rng(0)
    n, m = cfg.n_containers, cfg.num_processing_units
    requests = rng.random((B, n)) < 0.5
    keys = np.round(rng.random((B, n)), 1)  # many ties
    timers = np.where(rng.random((B, m)) < 0.3, 0.0, 100.0)
    free = (timers == 0.0).sum(axis=1)
    state = dynamics.PlantState(np.full((B, n), 5.0), timers, np.zeros(B, dtype=np.int64))
    _, out = dynamics.step(state, requests, params, np.zeros((B, n)), keys, "random")
    order = np.argsort(np.where(requests, -keys, np.inf), axis=1, kind="stable")
    rank = np.empty_like(order)
    np.put_along_axis(rank, order, np.broadcast_to(np.arange(n), (B, n)), axis=1)
    np.testing.assert_array_equal(out.granted, requests & (rank < free[:, None]))
    np.testing.assert_array_equal(out.denied, requests & ~out.granted)


def test_refill_in_place_draws_the_documented_stream():
    """A simulation's rows are its generator's standard_normal((BLOCK_ROWS, n)) then
    random((BLOCK_ROWS, n)), block after block, whatever the batch."""
    n = 4
    streams = NoiseStreams([np.random.default_rng(s) for s in (1, 2, 3)], n)
    got = [streams.next_rows(np.array([1]))] + [streams.next_rows() for _ in range(2 * BLOCK_ROWS)]
    ref = np.random.default_rng(2)
    blocks = [(ref.standard_normal((BLOCK_ROWS, n)), ref.random((BLOCK_ROWS, n))) for _ in range(3)]
    normals = np.concatenate([bn for bn, _ in blocks])
    uniforms = np.concatenate([bu for _, bu in blocks])
    rows_of_sim1 = [got[0][0][0]] + [g[0][1] for g in got[1:]]
    np.testing.assert_array_equal(np.stack(rows_of_sim1), normals[:2 * BLOCK_ROWS + 1])
    np.testing.assert_array_equal(np.stack([got[0][1][0]] + [g[1][1] for g in got[1:]]), uniforms[:2 * BLOCK_ROWS + 1])
    nrm, uni = streams.next_rows(normals=False)
    assert nrm is None and uni.shape == (3, n)
