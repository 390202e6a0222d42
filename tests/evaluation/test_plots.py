"""Figures (``containergym_marl.evaluation.plots``) checked by content.

Records come from the rule-based controller run through both views for 100 steps. Each figure is
checked twice: the returned Figure's artists hold exactly the record's data (volume lines equal
``record.volumes[:, i]``, one marker per emptying or denied request, one ECDF vertex per value plus
one, one bar per emptying…), and the written SVG holds the same number of markers / bars in the
groups named by the artists' ids; the PNG is a readable image.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from matplotlib.collections import PolyCollection
from matplotlib.image import imread

from containergym_marl import load_config
from containergym_marl.envs.centralised import ContainerGymEnv
from containergym_marl.envs.container_agents_v0 import parallel_env
from containergym_marl.evaluation import plots
from containergym_marl.evaluation.records import EpisodeRecorder
from containergym_marl.policies import RuleBasedAgents, RuleBasedController

from tests.helpers import CFG
T = 100
SVG = "{http://www.w3.org/2000/svg}"


# ---- records ---------------------------------------------------------------------------------
def centralised_record(seed: int, **kw):
    env = ContainerGymEnv(CFG, episode_length_steps=T, **kw)
    policy = RuleBasedController(env.simulator.params)
    obs, _ = env.reset(seed=seed)
    rec = EpisodeRecorder(env.simulator, view="centralised", policy="rule-based", seed=seed)
    rec.start()
    done = False
    while not done:
        obs, _, terminated, truncated, _ = env.step(policy.act(obs))
        rec.add()
        done = terminated or truncated
    return rec.finish(), env.config


def decentralised_record(seed: int, **kw):
    env = parallel_env(config=CFG, episode_length_steps=T, **kw)
    policy = RuleBasedAgents(env.simulator.params)
    obs, _ = env.reset(seed=seed)
    rec = EpisodeRecorder(env.simulator, view="decentralised", policy="rule-based agents", seed=seed)
    rec.start()
    while env.agents:
        obs, *_ = env.step(policy.act(obs))
        rec.add()
    return rec.finish(), env.config


@pytest.fixture(scope="module")
def central():
    records = [centralised_record(s)[0] for s in (0, 1)]
    assert all(r.granted.any() for r in records) and records[0].denied.any()
    return records


@pytest.fixture(scope="module")
def decentral():
    """A one-PU plant, so that requests compete and are denied; its config differs from the
    built-in one (1 PU, T = 100), so it is passed to the plot functions."""
    pairs = [decentralised_record(s, num_processing_units=1) for s in (0, 1, 2)]
    records = [r for r, _ in pairs]
    assert all(r.granted.any() and r.denied.any() for r in records)
    return records, pairs[0][1]


@pytest.fixture(scope="module")
def overflow():
    rec, cfg = decentralised_record(0, initial_volume_min=39.0, initial_volume_max=39.9)
    assert rec.terminated
    return rec, cfg


# ---- helpers ---------------------------------------------------------------------------------
def by_gid(fig, prefix: str, kind: str = "lines") -> dict:
    """Artists of the figure whose gid starts with ``prefix``, by gid."""
    out = {}
    for ax in fig.axes:
        for artist in getattr(ax, kind):
            gid = artist.get_gid()
            if gid and gid.startswith(prefix):
                out[gid] = artist
    return out


def svg_groups(path) -> dict:
    return {g.get("id"): g for g in ET.parse(path).getroot().iter(f"{SVG}g") if g.get("id")}


def svg_count(path, prefix: str, *tags: str) -> int:
    """Number of ``tags`` elements (``use``: a marker, ``path``: a shape) in groups ``prefix*``."""
    return sum(len(list(g.iter(f"{SVG}{tag}"))) for gid, g in svg_groups(path).items()
               if gid.startswith(prefix) for tag in tags)


def check_files(stem) -> tuple:
    png, svg = plots.figure_paths(stem)
    assert png.stat().st_size > 0 and svg.stat().st_size > 0
    image = imread(png)
    assert image.ndim == 3 and image.shape[2] in (3, 4) and min(image.shape[:2]) > 100
    assert image[..., :3].std() > 0  # not a blank image
    ET.parse(svg)  # well-formed XML
    return png, svg


def paper_reward(spec, v: float, r_pen: float) -> float:
    """Paper eq. 5, written out here: r_pen + Σ (h − r_pen)·exp(−(v − v*)² / (2 w²))."""
    return r_pen + sum((h - r_pen) * math.exp(-((v - p) ** 2) / (2 * w * w))
                       for p, h, w in zip(spec.reward_peaks, spec.reward_heights, spec.reward_widths))


# ---- paths -----------------------------------------------------------------------------------
def test_figure_paths(tmp_path):
    assert plots.figure_paths(tmp_path / "fig") == [tmp_path / "fig.png", tmp_path / "fig.svg"]
    assert plots.figure_paths(tmp_path / "fig.png") == [tmp_path / "fig.png", tmp_path / "fig.svg"]
    assert plots.figure_paths(tmp_path / "run.1") == [tmp_path / "run.1.png", tmp_path / "run.1.svg"]
    assert plots.figure_paths("a/b", ("svg",)) == [plots.Path("a/b.svg")]


def test_ecdf_points():
    x, y = plots.ecdf_points([3.0, 1.0, 2.0, 2.0])
    np.testing.assert_array_equal(x, [1, 1, 2, 2, 3])
    np.testing.assert_array_equal(y, [0, 0.25, 0.5, 0.75, 1.0])
    x, y = plots.ecdf_points([])
    assert x.size == y.size == 0


# ---- Fig. 1 ----------------------------------------------------------------------------------
@pytest.mark.parametrize("container", ["C1-60", 2])
def test_reward_function_is_the_paper_formula_over_0_vmax(tmp_path, container):
    cfg = load_config(CFG)
    spec = cfg.containers[2]
    fig = plots.plot_reward_function(cfg, container, tmp_path / "reward")
    assert len(fig.axes) == 1
    line = by_gid(fig, "reward")["reward"]
    x, y = line.get_xdata(), line.get_ydata()
    assert x[0] == 0.0 and x.max() < spec.max_volume and np.all(np.diff(x) > 0)
    assert x.size >= 2000
    expected = [cfg.penalty_reward if v == 0 else paper_reward(spec, v, cfg.penalty_reward) for v in x]
    np.testing.assert_allclose(y, expected, rtol=0, atol=1e-12)
    assert y.max() == pytest.approx(1.0)  # the global peak is sampled
    assert x[np.argmax(y)] == pytest.approx(spec.target_volume)
    optima = by_gid(fig, "optimum") | by_gid(fig, "local-optimum")
    assert sorted(line.get_xdata()[0] for line in optima.values()) == sorted(spec.reward_peaks)
    assert fig.axes[0].get_xlim() == (0.0, spec.max_volume)
    assert "volume units" in fig.axes[0].get_xlabel()
    _, svg = check_files(tmp_path / "reward")
    assert "reward" in svg_groups(svg)


def test_reward_function_resolves_narrow_peaks_and_rejects_unknown_containers(tmp_path):
    cfg = load_config("n16_m2_dt120")
    c = cfg.container_names.index("C2-50")  # peak widths down to 0.0025 volume units
    fig = plots.plot_reward_function("n16_m2_dt120", c, tmp_path / "r", formats=("png",))
    y = by_gid(fig, "reward")["reward"].get_ydata()
    spec = cfg.containers[c]
    for p, h in zip(spec.reward_peaks, spec.reward_heights):
        assert y.max(initial=-1) >= h - 1e-9
    assert not (tmp_path / "r.svg").exists()
    with pytest.raises(ValueError, match="container"):
        plots.plot_reward_function(cfg, "C9-99", tmp_path / "x")
    with pytest.raises(ValueError, match="container"):
        plots.plot_reward_function(cfg, 16, tmp_path / "x")


# ---- Fig. 2 ----------------------------------------------------------------------------------
def check_episode_figure(fig, rec, cfg, svg):
    assert len(fig.axes) == 2
    ax, rax = fig.axes
    n = cfg.n_containers
    volumes = by_gid(fig, "volume-")
    assert len(volumes) == n
    for i, name in enumerate(cfg.container_names):
        np.testing.assert_array_equal(volumes[f"volume-{name}"].get_ydata(), rec.volumes[:, i])
        np.testing.assert_array_equal(volumes[f"volume-{name}"].get_xdata(), np.arange(rec.steps + 1))
        assert by_gid(fig, f"target-{name}")[f"target-{name}"].get_ydata()[0] == cfg.containers[i].target_volume
        emptied = by_gid(fig, f"emptied-{name}")[f"emptied-{name}"]
        t = np.flatnonzero(rec.granted[:, i])
        np.testing.assert_array_equal(emptied.get_xdata(), t)
        np.testing.assert_array_equal(emptied.get_ydata(), rec.emptied_volume[t, i])
        denied = by_gid(fig, f"denied-{name}")[f"denied-{name}"]
        np.testing.assert_array_equal(denied.get_xdata(), np.flatnonzero(rec.denied[:, i]))
    assert sum(len(a.get_xdata()) for a in by_gid(fig, "emptied-").values()) == rec.granted.sum()
    assert sum(len(a.get_xdata()) for a in by_gid(fig, "denied-").values()) == rec.denied.sum()
    # rewards: one point per emptying action, with its reward
    rewards = [a for gid, a in by_gid(fig, "reward-").items() if gid != "reward-overflow"]
    assert all(a.axes is rax for a in rewards)
    assert sum(len(a.get_ydata()) for a in rewards) == rec.requested.sum()
    np.testing.assert_allclose(np.sort(np.concatenate([a.get_ydata() for a in rewards])),
                               np.sort(rec.container_reward[rec.requested]))
    # the SVG holds the same markers
    assert svg_count(svg, "emptied-", "use") == rec.granted.sum()
    assert svg_count(svg, "denied-", "use") == rec.denied.sum()
    assert {f"volume-{name}" for name in cfg.container_names} <= set(svg_groups(svg))
    # labels with units
    assert "volume units" in ax.get_ylabel() and "δ = 120 s" in rax.get_xlabel()
    assert ax.get_title()


def test_episode_plot_centralised(tmp_path, central):
    rec = central[0]
    fig = plots.plot_episode(rec, tmp_path / "episode")
    _, svg = check_files(tmp_path / "episode")
    check_episode_figure(fig, rec, load_config(CFG), svg)
    assert "reward-overflow" not in by_gid(fig, "reward-")


def test_episode_plot_decentralised_marks_denied_requests(tmp_path, decentral):
    records, cfg = decentral
    rec = records[0]
    fig = plots.plot_episode(rec, tmp_path / "episode", config=cfg)
    _, svg = check_files(tmp_path / "episode")
    check_episode_figure(fig, rec, cfg, svg)
    assert rec.denied.sum() > 0 and svg_count(svg, "denied-", "use") == rec.denied.sum()


def test_episode_plot_marks_the_overflow(tmp_path, overflow):
    rec, cfg = overflow
    fig = plots.plot_episode(rec, tmp_path / "episode", config=cfg)
    star = by_gid(fig, "overflow")["overflow"]
    over = np.flatnonzero(rec.volumes[-1] >= 40.0)
    np.testing.assert_array_equal(star.get_xdata(), np.full(over.size, rec.steps))
    r = by_gid(fig, "reward-overflow")["reward-overflow"]
    assert list(r.get_ydata()) == [cfg.overflow_reward]
    assert "overflow" in fig.axes[0].get_title()


def test_episode_plot_rejects_a_config_of_other_containers(tmp_path, central):
    with pytest.raises(ValueError, match="containers"):
        plots.plot_episode(central[0], tmp_path / "e", config="n11_m2_dt120")


# ---- Fig. 3 ----------------------------------------------------------------------------------
def test_emptying_volume_ecdfs_one_panel_per_container_one_line_per_method(tmp_path, central, decentral):
    methods = {"rule-based": central, "rule-based agents": decentral[0]}
    cfg = load_config(CFG)
    fig = plots.plot_emptying_volume_ecdfs(methods, tmp_path / "ecdf")
    _, svg = check_files(tmp_path / "ecdf")
    assert len(fig.axes) == cfg.n_containers
    groups = svg_groups(svg)
    for ax, spec in zip(fig.axes, cfg.containers):
        assert ax.get_title().startswith(spec.name)
        for method, recs in methods.items():
            gid = plots._gid("ecdf", spec.name, method)
            line = by_gid(fig, gid)[gid]
            assert line.axes is ax and gid in groups
            vols = np.concatenate([r.emptying_volumes(cfg.container_names.index(spec.name)) for r in recs])
            x, y = line.get_xdata(), line.get_ydata()
            assert len(x) == len(y) == vols.size + 1
            np.testing.assert_array_equal(x[1:], np.sort(vols))
            assert y[0] == 0 and y[-1] == 1 and np.all(np.diff(y) > 0)
            assert line.get_drawstyle() == "steps-post"
        glob = by_gid(fig, f"optimum-{spec.name}")[f"optimum-{spec.name}"]
        assert glob.axes is ax and glob.get_xdata()[0] == spec.target_volume
        local = by_gid(fig, f"local-optimum-{spec.name}-")
        assert sorted(a.get_xdata()[0] for a in local.values()) == sorted(
            p for p in spec.reward_peaks if p != spec.target_volume)
        assert "volume units" in ax.get_xlabel()


def test_emptying_volume_ecdfs_of_chosen_containers(tmp_path, central):
    fig = plots.plot_emptying_volume_ecdfs({"rb": central}, tmp_path / "e", containers=["C1-60", 0],
                                           formats=("svg",))
    assert [ax.get_title().split()[0] for ax in fig.axes] == ["C1-60", "C1-20"]
    assert not (tmp_path / "e.png").exists() and (tmp_path / "e.svg").exists()
    with pytest.raises(ValueError, match="C9-99"):
        plots.plot_emptying_volume_ecdfs({"rb": central}, tmp_path / "e", containers=["C9-99"])
    with pytest.raises(ValueError, match="records_by_method"):
        plots.plot_emptying_volume_ecdfs({}, tmp_path / "e")


# ---- Fig. 4 ----------------------------------------------------------------------------------
@pytest.mark.parametrize("include_denied", [True, False])
def test_reward_ecdf_one_line_per_method_with_every_emptying_action(tmp_path, central, decentral,
                                                                    include_denied):
    methods = {"rule-based": central, "rule-based agents (1 PU)": decentral[0]}
    fig = plots.plot_reward_ecdf(methods, tmp_path / "rewards", include_denied=include_denied)
    _, svg = check_files(tmp_path / "rewards")
    assert len(fig.axes) == 1
    groups = svg_groups(svg)
    for method, recs in methods.items():
        gid = plots._gid("reward-ecdf", method)
        line = by_gid(fig, gid)[gid]
        mask = "requested" if include_denied else "granted"
        values = np.concatenate([r.container_reward[getattr(r, mask)] for r in recs])
        assert len(line.get_xdata()) == values.size + 1
        np.testing.assert_array_equal(line.get_xdata()[1:], np.sort(values))
        assert line.get_ydata()[-1] == 1.0 and gid in groups
    assert fig.axes[0].get_xlabel() == "reward per emptying action"


def test_reward_ecdf_counts_denied_requests_as_r_pen(tmp_path, decentral):
    records, _ = decentral
    fig = plots.plot_reward_ecdf({"agents": records}, tmp_path / "r", formats=())
    x = by_gid(fig, "reward-ecdf-agents")["reward-ecdf-agents"].get_xdata()[1:]
    assert np.sum(x == -0.1) >= sum(int(r.denied.sum()) for r in records)
    assert not list(tmp_path.iterdir())  # no formats, no files


# ---- PU timeline -----------------------------------------------------------------------------
def bars(fig) -> dict[int, list[tuple[float, float]]]:
    """(start, width) of every bar per PU row."""
    out = {}
    for gid, coll in by_gid(fig, "pu-", "collections").items():
        assert isinstance(coll, PolyCollection)
        spans = []
        for path in coll.get_paths():
            xs = path.vertices[:, 0]
            spans.append((xs.min(), xs.max() - xs.min()))
        out[int(gid.split("-")[1])] = sorted(spans)
    return out


@pytest.mark.parametrize("which", ["central", "decentral"])
def test_pu_timeline_one_bar_per_emptying_on_its_pu(tmp_path, central, decentral, which):
    rec, cfg = (central[0], load_config(CFG)) if which == "central" else (decentral[0][0], decentral[1])
    fig = plots.plot_pu_timeline(rec, tmp_path / "pu", config=cfg)
    _, svg = check_files(tmp_path / "pu")
    assert len(fig.axes) == 1
    spans = bars(fig)
    assert sorted(spans) == list(range(cfg.num_processing_units))
    assert sum(len(s) for s in spans.values()) == rec.granted.sum()
    for j, row in spans.items():
        t, i = np.nonzero(rec.granted & (rec.pu_index == j))
        assert [s for s, _ in row] == sorted(t.tolist())
        for (s, w), nxt in zip(row, row[1:] + [(rec.steps + 1, 0)]):
            assert s + w <= nxt[0]  # a PU serves one container at a time
            end = int(s + w)
            assert np.all(rec.pu_timers_s[int(s) + 1:end, j] > 0)  # busy during the bar
            assert end == rec.steps or rec.pu_timers_s[end, j] == 0  # free when it ends
    denied = by_gid(fig, "denied-requests", "collections")["denied-requests"]
    assert len(denied.get_offsets()) == rec.denied.sum()
    assert svg_count(svg, "pu-", "path") == rec.granted.sum()
    # a scatter is written as <use> markers or, with one colour per point, one <path> each
    assert svg_count(svg, "denied-requests", "use", "path") == rec.denied.sum()


def test_pu_timeline_needs_the_records_plant(tmp_path, decentral):
    with pytest.raises(ValueError, match="PUs"):
        plots.plot_pu_timeline(decentral[0][0], tmp_path / "pu")  # built-in n5_m2 has 2 PUs


# ---- files and global state ------------------------------------------------------------------
def test_svg_output_is_reproducible_and_no_pyplot_figures_are_left(tmp_path, central):
    import matplotlib.pyplot as plt

    before = plt.get_fignums()
    plots.plot_episode(central[0], tmp_path / "a")
    plots.plot_episode(central[0], tmp_path / "b")
    assert (tmp_path / "a.svg").read_bytes() == (tmp_path / "b.svg").read_bytes()
    assert plt.get_fignums() == before


def test_records_loaded_from_npz_plot_the_same(tmp_path, central):
    central[0].save_npz(tmp_path / "rec.npz")
    again = plots.EpisodeRecord.load_npz(tmp_path / "rec.npz")
    fig = plots.plot_episode(again, tmp_path / "e", formats=("svg",))
    np.testing.assert_array_equal(by_gid(fig, "volume-C1-20")["volume-C1-20"].get_ydata(),
                                  central[0].volumes[:, 0])


def test_compare_figures_of_a_config_given_as_a_path(tmp_path):
    """A plant given as a file (named like no built-in) draws its figures from that file; the
    reward ECDF used to look the plant up by name and fail after the evaluations."""
    from pathlib import Path

    from containergym_marl.orchestration.figures import draw_figures
    from containergym_marl.core.params import PlantParams
    from containergym_marl.evaluation import EvalProtocol, evaluate
    from containergym_marl.policies import RuleBasedController

    cfg = load_config("n5_m2_dt120").replace(name="my_plant")
    path = tmp_path / "my_plant.toml"
    path.write_text(cfg.to_toml())
    records = evaluate(RuleBasedController(PlantParams.from_config(cfg)), str(path),
                       EvalProtocol(episodes=1, episode_length_steps=30)).records
    written = draw_figures({str(path): {"rule_based": records}}, tmp_path / "out")
    assert Path(f"{written[1]}.svg").is_file() and "my_plant_reward_ecdf" in str(written[1])
