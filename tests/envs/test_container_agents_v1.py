"""Tests of ``container_agents_v1``: PettingZoo's whole test suite, the new defaults and arguments,
and step-for-step agreement with ``container_agents_v0`` (whose own tests cover the physics)."""

from __future__ import annotations

import contextlib
import functools
import sys
import warnings

import numpy as np
import pytest
from pettingzoo.test import (
    api_test,
    max_cycles_test,
    parallel_api_test,
    parallel_seed_test,
    performance_benchmark,
    render_test,
    seed_test,
)

import containergym_marl
from containergym_marl import ConfigError
from containergym_marl.envs import container_agents_v0, container_agents_v1
from containergym_marl.envs.container_agents_v1 import ContainerAgentsV1ParallelEnv, env, parallel_env, raw_env

from tests.helpers import CFG
PLANT_NAMES = ["C1-20", "C1-30", "C1-60", "C1-70", "C1-80"]


#: what ``api_test`` says of every dict observation but those of its own environments (lists of names)
DICT_WARNINGS = ("Observation space for each agent probably should be gymnasium.spaces.box",
                 "Observation is not a NumPy array")


@contextlib.contextmanager
def every_warning_an_error(kwargs=None):
    """v1 needs no exception for PettingZoo's agent-naming recommendation. ``api_test`` warns of
    every Dict observation except its own classic environments' (lists of names), so
    ``observation_mode="dict"``, the classic environments' layout, keeps those two warnings."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        if (kwargs or {}).get("observation_mode") == "dict":
            for message in DICT_WARNINGS:
                warnings.filterwarnings("ignore", message=message, category=UserWarning)
        yield


@pytest.fixture
def headless(monkeypatch):
    """``render_mode="human"`` draws off-screen, without a window (as in tests/envs/test_render.py)."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")


# ---- PettingZoo's test suite --------------------------------------------------------------------
VARIANTS = [
    {},
    {"observation_mode": "dict", "action_masking": True, "state_mode": "normalised"},
    {"arbitration": "random", "reward_mode": "team", "max_cycles": 7},  # several episode ends
    {"initial_volume_min": 39.0, "initial_volume_max": 39.9},  # overflow at once
]


@pytest.mark.parametrize("kwargs", VARIANTS, ids=lambda k: ",".join(k) or "default")
def test_api_test(kwargs):
    with every_warning_an_error(kwargs):
        api_test(env(CFG, **kwargs), num_cycles=30)


@pytest.mark.parametrize("kwargs", VARIANTS, ids=lambda k: ",".join(k) or "default")
def test_parallel_api_test(kwargs):
    with every_warning_an_error(kwargs):
        parallel_api_test(parallel_env(CFG, **kwargs), num_cycles=100)


def test_seed_test():
    with every_warning_an_error():
        seed_test(functools.partial(env, CFG, arbitration="random"), num_cycles=100)


def test_parallel_seed_test():
    with every_warning_an_error():
        parallel_seed_test(functools.partial(parallel_env, CFG, arbitration="random"), num_cycles=100)


@pytest.mark.parametrize("module", [container_agents_v1, containergym_marl.container_agents_v1],
                         ids=["envs", "top-level"])
def test_max_cycles_test(module):
    with every_warning_an_error():
        max_cycles_test(module)  # module.parallel_env(max_cycles=4), module.env(max_cycles=4)


def test_render_test(headless):
    render_test(functools.partial(env, CFG, max_cycles=20))


@pytest.mark.slow  # PettingZoo's benchmark runs for 5 s of wall time
def test_performance_benchmark(capsys):
    performance_benchmark(env(CFG))
    assert "turns per second" in capsys.readouterr().out


# ---- the v1 defaults ------------------------------------------------------------------------------
def test_agents_are_indexed_and_plant_names_kept():
    e = parallel_env(CFG)
    agents = [f"container_{i}" for i in range(5)]
    assert e.possible_agents == agents
    assert list(e.container_names) == PLANT_NAMES == list(e.config.container_names)
    assert e.agent_container == dict(zip(agents, PLANT_NAMES, strict=True))
    e.reset(seed=0)
    assert e.agents == agents
    assert parallel_env(CFG, agent_names="containers").possible_agents == PLANT_NAMES


def test_metadata_and_exports():
    assert parallel_env(CFG).metadata["name"] == env(CFG).metadata["name"] == "container_agents_v1"
    assert container_agents_v0.parallel_env(CFG).metadata["name"] == "container_agents_v0"  # unchanged
    assert containergym_marl.container_agents_v1.parallel_env is parallel_env
    assert containergym_marl.ContainerAgentsV1ParallelEnv is ContainerAgentsV1ParallelEnv
    assert raw_env(CFG).possible_agents == env(CFG).possible_agents == parallel_env(CFG).possible_agents
    assert container_agents_v0.parallel_env(CFG).possible_agents == PLANT_NAMES  # v0's default unchanged


# ---- max_cycles -----------------------------------------------------------------------------------
def test_max_cycles_is_the_episode_length():
    assert parallel_env(CFG).max_cycles == parallel_env(CFG).config.episode_length_steps
    e = parallel_env(CFG, max_cycles=3, protocol="paper_test")  # overrides the protocol's T = 600
    assert e.max_cycles == e.config.episode_length_steps == 3
    e.reset(seed=0)
    for t in range(3):
        _, _, terms, truncs, _ = e.step({a: 0 for a in e.agents})
        assert not any(terms.values()) and all(v is (t == 2) for v in truncs.values())
    assert e.agents == []
    assert parallel_env(CFG, episode_length_steps=9).max_cycles == 9
    assert parallel_env(CFG, max_cycles=np.int64(5), episode_length_steps=5).max_cycles == 5


@pytest.mark.parametrize("value", [0, -1, 2.5, "4", True])
def test_bad_max_cycles_is_refused(value):
    with pytest.raises(ValueError, match="max_cycles"):
        parallel_env(CFG, max_cycles=value)


def test_max_cycles_and_episode_length_must_agree():
    with pytest.raises(ValueError, match="disagree"):
        parallel_env(CFG, max_cycles=4, episode_length_steps=5)
    with pytest.raises(ConfigError):
        parallel_env(CFG, max_cycles=10**12)  # the config's own bound on T still applies


# ---- v1 is v0 under other names -------------------------------------------------------------------
@pytest.mark.parametrize("kwargs", [{}, {"observation_mode": "dict", "action_masking": True,
                                         "arbitration": "random", "reward_mode": "team"}],
                         ids=["default", "dict,masks,random,team"])
def test_v1_steps_as_v0(kwargs):
    v0 = container_agents_v0.parallel_env(CFG, **kwargs)
    v1 = parallel_env(CFG, **kwargs)
    rename = dict(zip(v0.possible_agents, v1.possible_agents, strict=True))
    renamed = lambda d: {rename[a]: v for a, v in d.items()}  # noqa: E731
    out0, out1 = v0.reset(seed=3), v1.reset(seed=3)
    rng = np.random.default_rng(0)
    steps = 0
    while True:
        for d0, d1 in zip(out0, out1, strict=True):
            d0 = renamed(d0)
            assert d0.keys() == d1.keys()
            for a in d0:
                if isinstance(d0[a], dict):  # infos, dict observations
                    assert d0[a].keys() == d1[a].keys()
                    for k in d0[a]:
                        np.testing.assert_array_equal(d0[a][k], d1[a][k])
                else:
                    np.testing.assert_array_equal(d0[a], d1[a])
        np.testing.assert_array_equal(v0.state(), v1.state())
        if not v1.agents or steps == 150:
            break
        actions = {a: int(rng.random() < 0.3) for a in v0.agents}
        out0, out1 = v0.step(actions), v1.step(renamed(actions))
        steps += 1
    assert steps >= 20
