"""Rendering of both views (``containergym_marl.render``): ansi text, rgb_array frames, "human".

Frames are checked by content: the pixel in the middle of a container's bar has the fill colour
while the container holds material and loses it once the container is emptied; denied requests
put a red cross where the container's bar ends.
"""

from __future__ import annotations

import contextlib
import functools
import sys
import time
import warnings

import gymnasium as gym
import numpy as np
import pytest
from matplotlib.colors import to_rgb
from pettingzoo.test import api_test, parallel_api_test, render_test

import containergym_marl.render as render_mod
from containergym_marl import load_config
from containergym_marl.core.simulator import PlantSimulator
from containergym_marl.envs.centralised import ContainerGymEnv
from containergym_marl.envs.container_agents_v0 import env as aec_env
from containergym_marl.envs.container_agents_v0 import parallel_env
from containergym_marl.render import RENDER_MODES, PlantRenderer, render_ansi

from tests.helpers import CFG
ENV_ID = "containergym_marl/ContainerGym-v0"
AGENT_NAME_WARNING = "We recommend agents to be named"
FILL = {name: np.array(to_rgb(name)) * 255 for name in ("tab:blue", "tab:orange", "tab:red")}


# ---- helpers ---------------------------------------------------------------------------------
def diagram(env):
    return env.unwrapped._renderer.diagram if hasattr(env, "unwrapped") else env._renderer.diagram


def pixel(frame: np.ndarray, ax, x: float, y: float) -> np.ndarray:
    """RGB of the frame at data point (x, y) of axis ``ax`` (display origin is bottom left)."""
    px, py = ax.transData.transform((x, y))
    return frame[frame.shape[0] - 1 - int(py), int(px)].astype(float)


def is_colour(rgb: np.ndarray, name: str, tol: float = 12.0) -> bool:
    return bool(np.abs(rgb - FILL[name]).max() <= tol)


def bar_pixel(frame, env, i: int, v: float) -> np.ndarray:
    """A point inside bar i at half its height, clear of the optimum marks drawn over the bar."""
    return pixel(frame, diagram(env)._container_ax, i + 0.3, v / 2)


def make_views(render_mode, **kw):
    """(centralised env, decentralised parallel env), same plant."""
    return (ContainerGymEnv(CFG, render_mode=render_mode, **kw),
            parallel_env(config=CFG, render_mode=render_mode, **kw))


def step_requests(env, containers: set[int]):
    """Request emptying of ``containers`` (centralised: at most one) in either view."""
    if isinstance(env, ContainerGymEnv):
        assert len(containers) <= 1
        return env.step(next(iter(containers)) + 1 if containers else 0)
    return env.step({a: int(i in containers) for i, a in enumerate(env.possible_agents)})


@contextlib.contextmanager
def headless(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    yield


# ---- metadata and modes ----------------------------------------------------------------------
@pytest.mark.parametrize("cls", [ContainerGymEnv, lambda **kw: parallel_env(config=CFG, **kw)])
def test_both_views_declare_the_three_modes_and_an_fps(cls):
    env = cls() if cls is not ContainerGymEnv else cls(CFG)
    assert env.metadata["render_modes"] == ["human", "rgb_array", "ansi"] == list(RENDER_MODES)
    assert env.metadata["render_fps"] > 0


@pytest.mark.parametrize("mode", ["bogus", "rgb", "ANSI"])
def test_unknown_modes_still_raise(mode):
    with pytest.raises(ValueError, match="render_mode"):
        ContainerGymEnv(CFG, render_mode=mode)
    with pytest.raises(ValueError, match="render_mode"):
        parallel_env(config=CFG, render_mode=mode)


# ---- ansi ------------------------------------------------------------------------------------
@pytest.mark.parametrize("view", [0, 1])
def test_ansi_contains_every_volume_to_two_decimals_after_each_step(view):
    env = make_views("ansi")[view]
    env.reset(seed=3)
    for containers in (set(), {0}, set(), {2}):
        step_requests(env, containers)
        text = env.render()
        assert isinstance(text, str)
        for name, v in zip(env.config.container_names, env.simulator.state.volumes[0]):
            assert name in text and f"{v:.2f}" in text


def test_ansi_reports_the_last_steps_granted_and_denied_requests():
    env = parallel_env(config=CFG, render_mode="ansi", num_processing_units=1)
    env.reset(seed=0)
    _, _, _, _, infos = env.step({a: 1 for a in env.agents})
    granted = [a for a in infos if infos[a]["granted"]]
    denied = [a for a in infos if infos[a]["denied"]]
    assert len(granted) == 1 and len(denied) == 4
    last = env.render().splitlines()[-1]
    assert last.startswith("last step:")
    assert repr(granted) in last and all(repr(a) in last for a in denied)


def test_ansi_of_one_simulation_of_a_batch():
    sim = PlantSimulator(load_config(CFG), num_sims=2)
    sim.reset(generators=[np.random.default_rng(1), np.random.default_rng(2)])
    for b in range(2):
        text = render_ansi(sim, b)
        for v in sim.state.volumes[b]:
            assert f"{v:.2f}" in text


# ---- rgb_array -------------------------------------------------------------------------------
@pytest.mark.parametrize("view", [0, 1])
def test_rgb_array_frame_shape_dtype_and_reuse(view):
    env = make_views("rgb_array")[view]
    frame = env.render()  # before reset: the empty plant (Gymnasium's checker does this)
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    h, w = frame.shape[:2]
    assert (h, w) == (520, 900)
    env.reset(seed=0)
    fig = diagram(env).fig
    for _ in range(3):
        step_requests(env, set())
        f = env.render()
        assert f.shape == (h, w, 3) and f.dtype == np.uint8
        assert f.flags.c_contiguous and f.flags.writeable
    assert diagram(env).fig is fig  # one figure for every frame


@pytest.mark.parametrize("view", [0, 1])
def test_rgb_array_pixels_follow_the_volumes(view):
    env = make_views("rgb_array")[view]
    env.reset(seed=0)
    v0 = env.simulator.state.volumes[0].copy()
    i = int(np.argmax(v0))
    assert v0[i] > 4  # a bar tall enough to sample
    before = env.render()
    again = env.render()
    np.testing.assert_array_equal(before, again)  # same state, same frame
    kept = before.copy()

    step_requests(env, {i})
    assert env.simulator.state.volumes[0, i] == 0.0  # granted: emptied
    after = env.render()
    np.testing.assert_array_equal(before, kept)  # earlier frames are not overwritten
    assert not np.array_equal(before, after)
    fill = "tab:orange" if v0[i] > env.simulator.params.target_volume[i] else "tab:blue"
    assert is_colour(bar_pixel(before, env, i, v0[i]), fill)
    assert not any(is_colour(bar_pixel(after, env, i, v0[i]), c) for c in FILL)

    # Another container's bar grows or shrinks with its volume: its pixels track the new level.
    j = (i + 1) % len(v0)
    v1 = env.simulator.state.volumes[0, j]
    assert v1 > 0.5
    assert any(is_colour(bar_pixel(after, env, j, v1), c) for c in ("tab:blue", "tab:orange"))
    top = env.simulator.params.max_volume[j] * 1.05  # above every bar: background
    assert np.all(pixel(after, diagram(env)._container_ax, j + 0.3, top) > 240)


def test_rgb_array_marks_denied_requests_in_the_decentralised_view():
    env = parallel_env(config=CFG, render_mode="rgb_array", num_processing_units=1)
    env.reset(seed=0)
    _, _, _, _, infos = env.step({a: 1 for a in env.agents})
    denied = [k for k, a in enumerate(env.possible_agents) if infos[a]["denied"]]
    assert len(denied) == 4
    frame = env.render()
    d = diagram(env)
    np.testing.assert_array_equal(d._denied.get_offsets()[:, 0], denied)
    v = env.simulator.state.volumes[0]
    for k in denied:
        assert is_colour(pixel(frame, d._container_ax, k, v[k]), "tab:red", tol=30)
        assert d._reward_texts[k].get_text() == f"{env.config.penalty_reward:+.2f}"
    # the next step without requests clears the marks
    env.step({a: 0 for a in env.agents})
    env.render()
    assert len(d._denied.get_offsets()) == 0


def test_rgb_array_shows_an_overflow_in_red():
    env = parallel_env(config=CFG, render_mode="rgb_array", initial_volume_min=39.0,
                       initial_volume_max=39.9)
    env.reset(seed=0)
    while env.agents:
        _, _, terms, _, _ = env.step({a: 0 for a in env.agents})
    assert all(terms.values())
    frame = env.render()
    v = env.simulator.state.volumes[0]
    over = int(np.argmax(v >= env.simulator.params.max_volume))
    assert is_colour(bar_pixel(frame, env, over, 20.0), "tab:red")
    assert "OVERFLOW" in diagram(env)._subtitle.get_text()


def test_pu_panel_shows_busy_time_and_the_served_container():
    env = ContainerGymEnv(CFG, render_mode="rgb_array")
    env.reset(seed=0)
    _, _, _, _, info = env.step(1)
    env.render()
    d = diagram(env)
    j = info["pu_index"]
    t = env.simulator.state.pu_timers_s[0, j]
    assert t > 0
    assert d._pu_bars[j].get_width() == pytest.approx(t)
    assert d._pu_texts[j].get_text() == f"{t:.0f} s ({env.config.container_names[0]})"
    free = [k for k in range(env.n_pus) if k != j]
    assert all(d._pu_texts[k].get_text() == "free" for k in free)


def test_frames_take_a_reasonable_time():
    env = parallel_env(config="n16_m2_dt120", render_mode="rgb_array")
    env.reset(seed=0)
    env.render()
    start = time.perf_counter()
    for _ in range(10):
        if not env.agents:
            env.reset()
        env.step({a: 1 for a in env.agents})  # busy frames: emptyings and denials
        env.render()
    assert (time.perf_counter() - start) / 10 < 0.5  # ~0.03-0.07 s on a laptop; generous bound


# ---- human -----------------------------------------------------------------------------------
def test_display_available_is_false_without_a_display(monkeypatch):
    with headless(monkeypatch):
        assert render_mod.display_available() is False


@pytest.mark.parametrize("view", [0, 1])
def test_human_mode_headless_draws_off_screen_and_returns_none(monkeypatch, view):
    import matplotlib.pyplot as plt

    open_before = plt.get_fignums()
    with headless(monkeypatch):
        env = make_views("human")[view]
        env.reset(seed=0)
        start = time.perf_counter()
        for _ in range(5):
            step_requests(env, set())
            assert env.render() is None
        assert time.perf_counter() - start < 10
        d = diagram(env)
        assert d.window is False and d.fig is not None  # drawn with Agg
        assert d.fig.canvas.get_width_height() == (900, 520)
        assert plt.get_fignums() == open_before  # no pyplot window was made
        env.close()
        assert env._renderer._diagram is None


def test_human_mode_with_a_display_uses_a_window_and_close_closes_it(monkeypatch):
    """The window path, exercised with the Agg backend standing in for a GUI backend."""
    import matplotlib.pyplot as plt

    monkeypatch.setattr(render_mod, "display_available", lambda: True)
    env = ContainerGymEnv(CFG, render_mode="human")
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*non-interactive.*")
        env.reset(seed=0)
        env.step(0)
    d = env._renderer.diagram
    assert d.window is True and d.fig.number in plt.get_fignums()
    number = d.fig.number
    env.close()
    assert number not in plt.get_fignums()


@pytest.mark.parametrize("view", [0, 1])
def test_close_releases_the_figure_and_rendering_can_resume(view):
    env = make_views("rgb_array")[view]
    env.reset(seed=0)
    first = env.render()
    env.close()
    assert env._renderer._diagram is None
    np.testing.assert_array_equal(env.render(), first)
    env.close()
    env.close()  # idempotent


def test_a_renderer_draws_the_simulation_it_is_given():
    sim = PlantSimulator(load_config(CFG), num_sims=2)
    sim.reset(generators=[np.random.default_rng(1), np.random.default_rng(2)])
    frames = [PlantRenderer(sim, index=b).rgb_array() for b in range(2)]
    assert not np.array_equal(*frames)


# ---- library checkers with a render mode -----------------------------------------------------
@pytest.mark.parametrize("mode", RENDER_MODES)
def test_gymnasium_check_env_with_render_mode(mode, monkeypatch):
    from gymnasium.utils.env_checker import check_env

    with headless(monkeypatch), warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(gym.make(ENV_ID, config=CFG, render_mode=mode).unwrapped)


@pytest.mark.parametrize("mode", RENDER_MODES)
def test_pettingzoo_api_tests_with_render_mode(mode, monkeypatch):
    with headless(monkeypatch), warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", message=AGENT_NAME_WARNING)
        parallel_api_test(parallel_env(config=CFG, render_mode=mode, episode_length_steps=20),
                          num_cycles=30)
        api_test(aec_env(config=CFG, render_mode=mode, episode_length_steps=20), num_cycles=10)


def test_pettingzoo_render_test(monkeypatch):
    with headless(monkeypatch):
        render_test(functools.partial(aec_env, config=CFG))
