"""Tests of the plant configurations (containergym_marl.config).

Expected figures come from outside the package: the reference JSON files (read here with ``json``
directly, not through the package's own reference loader), the paper's naming scheme
``n{n}_m{m}_dt{δ}``, and small hand-written configs in ``tmp_path``.

The checks against ``shared/reference-configs`` skip when that folder is absent; point
``CONTAINERGYM_REFERENCE_CONFIGS`` at it to run them from elsewhere.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import os
import re
import shutil
import statistics
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from containergym_marl.core.params import PlantParams
from containergym_marl.config import (
    PAPER_TEST_PROTOCOL,
    ConfigError,
    ContainerSpec,
    PlantConfig,
    list_configs,
    load_config,
)

from tests.helpers import PAPER_CONFIGS

REPO_ROOT = Path(__file__).resolve().parents[2]

#: the plants built from the 16-container plant by configs/scaled.py: PUs in proportion, and scarce
SCALED = ["n32_m4_dt120", "n64_m8_dt120", "n128_m16_dt120", "n32_m3_dt120", "n64_m6_dt120", "n128_m12_dt120"]
BUILTINS = [*PAPER_CONFIGS, "n16_m2_dt120", *SCALED]

#: The paper's eight Table 1 rows and the reference file each one takes its figures from.
PAPER_FILES = {
    "n5_m2_dt60": "5containers_2presses_3.json",
    "n5_m2_dt120": "5containers_2presses_2.json",
    "n5_m5_dt60": "5containers_5presses_3.json",
    "n5_m5_dt120": "5containers_5presses_2.json",
    "n11_m2_dt60": "11containers_2presses_4.json",
    "n11_m2_dt120": "11containers_2presses_3.json",
    "n11_m11_dt60": "11containers_11presses_6.json",
    "n11_m11_dt120": "11containers_11presses_5.json",
}

#: Reference-format per-container key -> our ContainerSpec field.
REF_TO_FIELD = {
    "RW_MUS": "fill_rate_per_s",
    "RW_SIGMAS": "fill_noise_per_sqrt_s",
    "MAX_VOLUMES": "max_volume",
    "BALE_SIZES": "product_size",
    "PRESS_OFFSETS": "pu_offset_s",
    "PRESS_SLOPES": "pu_time_per_product_s",
}


# ---- helpers -------------------------------------------------------------------------------
def _reference_dir() -> Path | None:
    """The shared reference-config folder: $CONTAINERGYM_REFERENCE_CONFIGS, else ../shared/…"""
    candidates = []
    if os.environ.get("CONTAINERGYM_REFERENCE_CONFIGS"):
        candidates.append(Path(os.environ["CONTAINERGYM_REFERENCE_CONFIGS"]))
    candidates.append(REPO_ROOT.parent / "shared" / "reference-configs")
    for c in candidates:
        if c.is_dir():
            return c
    return None


@pytest.fixture
def ref_dir() -> Path:
    d = _reference_dir()
    if d is None:
        pytest.skip(
            "reference configs not found (no shared/reference-configs beside the clone and "
            "CONTAINERGYM_REFERENCE_CONFIGS unset)"
        )
    return d


def _read_json(path: Path) -> dict:
    with open(path, encoding="utf-8") as f:
        return json.load(f)


def _plant_figures(cfg: PlantConfig) -> tuple:
    """Everything that defines the plant, i.e. all fields but the name and description."""
    return (
        cfg.containers,
        cfg.num_processing_units,
        cfg.timestep_s,
        cfg.episode_length_steps,
        cfg.initial_volume_min,
        cfg.initial_volume_max,
        cfg.overflow_reward,
        cfg.penalty_reward,
    )


def _assert_containers_match_reference(cfg: PlantConfig, data: dict, *, pu_optional=False, skip=()) -> None:
    """Every container figure of ``cfg`` equals the reference-format mapping ``data``.

    Handles both reference layouts: ENABLED_CONTAINERS as names (tables keyed by name) or as a
    count (tables are lists in container order). With ``pu_optional``, PU figures are only
    compared for containers the file has them for.
    """
    enabled = data["ENABLED_CONTAINERS"]
    keyed = isinstance(enabled, list)
    n = len(enabled) if keyed else enabled
    assert cfg.n_containers == n
    if keyed:
        assert list(cfg.container_names) == enabled

    for i, c in enumerate(cfg.containers):
        key_i = enabled[i] if keyed else i
        for ref_key, ours in REF_TO_FIELD.items():
            table = data[ref_key]
            if (pu_optional and ref_key.startswith("PRESS_") and key_i not in table) or ours in skip:
                continue
            assert getattr(c, ours) == table[key_i], f"{c.name}: {ours} vs {ref_key}"
        rp = data["REWARD_PARAMS"][key_i]
        assert list(c.reward_peaks) == rp["peaks"], f"{c.name}: peaks"
        assert list(c.reward_heights) == rp["heights"], f"{c.name}: heights"
        assert list(c.reward_widths) == rp["widths"], f"{c.name}: widths"


def _assert_matches_reference(cfg: PlantConfig, data: dict) -> None:
    """Containers and every plant-level figure equal the reference-format mapping ``data``."""
    _assert_containers_match_reference(cfg, data)
    assert cfg.num_processing_units == data["N_PRESSES"]
    assert cfg.timestep_s == data["TIMESTEP"]
    assert cfg.episode_length_steps == data["MAX_EPISODE_LENGTH"]
    assert cfg.initial_volume_min == data["MIN_STARTING_VOLUME"]
    assert cfg.initial_volume_max == data["MAX_STARTING_VOLUME"]
    assert cfg.overflow_reward == data["FAILURE_PENALTY"]
    assert cfg.penalty_reward == data["MIN_REWARD"]


def _toml_value(v) -> str:
    if isinstance(v, str):
        return json.dumps(v)  # test strings are ASCII: a JSON string is then a TOML basic string
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return repr(v)
    raise TypeError(v)


def _dump_toml(d: dict) -> str:
    """A minimal TOML writer for our format (flat keys and an array of container tables)."""
    lines = [f"{k} = {_toml_value(v)}" for k, v in d.items() if k != "containers"]
    for c in d.get("containers", []):
        lines += ["", "[[containers]]"] + [f"{k} = {_toml_value(v)}" for k, v in c.items()]
    return "\n".join(lines) + "\n"


def _plant_dict() -> dict:
    """A small valid plant in our format. Container B has the smaller v_max (35)."""
    return {
        "name": "tiny",
        "description": "two-container test plant",
        "num_processing_units": 1,
        "timestep_s": 60.0,
        "episode_length_steps": 100,
        "initial_volume_min": 0.0,
        "initial_volume_max": 20.0,
        "overflow_reward": -1.0,
        "penalty_reward": -0.1,
        "containers": [
            {
                "name": "A",
                "fill_rate_per_s": 0.004,
                "fill_noise_per_sqrt_s": 0.03,
                "max_volume": 40.0,
                "product_size": 10.0,
                "pu_offset_s": 50.0,
                "pu_time_per_product_s": 150.0,
                "reward_peaks": [30.0, 20.0],
                "reward_heights": [1.0, 0.5],
                "reward_widths": [2.0, 0.5],
            },
            {
                "name": "B",
                "fill_rate_per_s": 0.002,
                "fill_noise_per_sqrt_s": 0.05,
                "max_volume": 35.0,
                "product_size": 12.5,
                "pu_offset_s": 70.0,
                "pu_time_per_product_s": 200.0,
                "reward_peaks": [25.0],
                "reward_heights": [1.0],
                "reward_widths": [2.5],
            },
        ],
    }


def _reference_dict() -> dict:
    """A small valid plant in the reference JSON format, keyed by container name."""
    return {
        "MAX_EPISODE_LENGTH": 200,
        "TIMESTEP": 120,
        "ENABLED_CONTAINERS": ["P-1", "P-2", "P-3"],
        "N_PRESSES": 2,
        "MIN_STARTING_VOLUME": 1,
        "MAX_STARTING_VOLUME": 25,
        "FAILURE_PENALTY": -2,
        "RW_MUS": {"P-1": 0.001, "P-2": 0.0025, "P-3": 0.004},
        "RW_SIGMAS": {"P-1": 0.02, "P-2": 0.03, "P-3": 0.04},
        "MAX_VOLUMES": {"P-1": 32, "P-2": 37.5, "P-3": 30},
        "BALE_SIZES": {"P-1": 11, "P-2": 27, "P-3": 6.5},
        "PRESS_OFFSETS": {"P-1": 100.5, "P-2": 90, "P-3": 60.25},
        "PRESS_SLOPES": {"P-1": 260, "P-2": 150.5, "P-3": 180},
        "REWARD_PARAMS": {
            "P-1": {"peaks": [20], "heights": [1], "widths": [2]},
            "P-2": {"peaks": [27, 18], "heights": [1, 0.3], "widths": [2.5, 0.5]},
            "P-3": {"peaks": [26, 19.5, 13], "heights": [0.9, 0.4, 0.1], "widths": [1, 0.5, 0.25]},
        },
        "MIN_REWARD": -0.2,
    }


def _to_list_form(data: dict) -> dict:
    """The same plant in the reference list form: ENABLED_CONTAINERS a count, tables lists."""
    names = data["ENABLED_CONTAINERS"]
    out = dict(data, ENABLED_CONTAINERS=len(names))
    for key in (*REF_TO_FIELD, "REWARD_PARAMS"):
        out[key] = [data[key][n] for n in names]
    return out


def _write(tmp_path: Path, filename: str, content: str | dict) -> Path:
    path = tmp_path / filename
    if isinstance(content, dict):
        content = json.dumps(content) if filename.endswith(".json") else _dump_toml(content)
    path.write_text(content, encoding="utf-8")
    return path


# ---- 1. the built-ins ----------------------------------------------------------------------
def test_list_configs_is_exactly_the_builtins_in_size_order():
    """The paper's eight Table 1 rows, the 16-container plant and the six larger plants, nothing more
    or less, by containers, then PUs, then δ."""
    names = list_configs()
    assert sorted(names) == sorted(BUILTINS)
    assert len(names) == len(set(names)) == 15
    sizes = [tuple(map(int, re.fullmatch(r"n(\d+)_m(\d+)_dt(\d+)", name).groups())) for name in names]
    assert sizes == sorted(sizes)


def test_the_larger_plants_are_the_16_container_plant_copied_with_their_pus():
    """configs/scaled.py's rule, checked entry by entry: k copies of every container (names C.1..C.k),
    every plant setting the 16-container plant's, m = n/8 or 3n/32; the files are what the rule writes."""
    base = load_config("n16_m2_dt120")
    for name in SCALED:
        n, m, _ = map(int, re.fullmatch(r"n(\d+)_m(\d+)_dt(\d+)", name).groups())
        cfg, copies = load_config(name), n // 16
        assert m in (n // 8, 3 * n // 32)
        assert [c.name for c in cfg.containers] == [f"{c.name}.{j}" for j in range(1, copies + 1) for c in base.containers]
        for k, c in enumerate(cfg.containers):
            assert dataclasses.replace(c, name=base.containers[k % 16].name) == base.containers[k % 16]
        for field in ("timestep_s", "episode_length_steps", "initial_volume_min", "initial_volume_max",
                      "overflow_reward", "penalty_reward"):
            assert getattr(cfg, field) == getattr(base, field), field
        assert "not in the paper" in cfg.description
    from containergym_marl.configs import scaled

    assert scaled.main(["--check"]) == 0


def _pu_load(cfg) -> float:
    """Average share of each PU's time that emptying every container at its main optimum takes:
    Σ_i g_i(v*_i) · μ_i / v*_i / m (paper eq. 2 for g), as docs/configurations.md states it."""
    busy = 0.0
    for c in cfg.containers:
        target = c.reward_peaks[int(np.argmax(c.reward_heights))]
        g = c.pu_offset_s + c.pu_time_per_product_s * math.floor(target / c.product_size)
        busy += g * c.fill_rate_per_s / target
    return busy / cfg.num_processing_units


def test_the_larger_plants_pu_loads_are_the_ones_the_docs_state():
    # docs/configurations.md and configs/scaled.py: 0.45 in proportion (the 16-container plant's), 0.59 scarce
    assert round(_pu_load(load_config("n16_m2_dt120")), 2) == 0.45
    for name in SCALED:
        cfg = load_config(name)
        proportional = cfg.num_processing_units * 8 == cfg.n_containers
        assert round(_pu_load(cfg), 2) == (0.45 if proportional else 0.59), name
    assert "0.45 of each PU's time" in (REPO_ROOT / "docs" / "configurations.md").read_text()
    assert "load 0.59" in (REPO_ROOT / "docs" / "configurations.md").read_text()


@pytest.mark.parametrize("name", BUILTINS)
def test_builtin_loads_and_matches_its_name(name):
    """Each built-in loads, and n (containers), m (PUs) and δ in its name agree with its figures."""
    n, m, dt = map(int, re.fullmatch(r"n(\d+)_m(\d+)_dt(\d+)", name).groups())
    cfg = load_config(name)
    assert isinstance(cfg, PlantConfig)
    assert cfg.name == name
    assert cfg.n_containers == n == len(set(cfg.container_names))
    assert cfg.num_processing_units == m
    assert cfg.timestep_s == dt


# ---- 2. figures against the reference files ------------------------------------------------
@pytest.mark.parametrize("name", sorted(PAPER_FILES))
def test_paper_config_matches_reference_json(name, ref_dir):
    """The eight paper configs equal their reference JSON figure for figure (read with json)."""
    data = _read_json(ref_dir / PAPER_FILES[name])
    _assert_matches_reference(load_config(name), data)


def test_n16_matches_all_sutco_constants(ref_dir):
    """The 16-container plant takes its figures from all_sutco_constants.json, with δ=120, m=2
    and the paper's T=1500, r_min=-1 (the file itself has δ=60, T=300, r_min=-10), and the paper's
    rows' v_max = 40 (the file's 32–37.5 leave three optima within 0.5 units of v_max)."""
    data = _read_json(ref_dir / "all_sutco_constants.json")
    cfg = load_config("n16_m2_dt120")
    _assert_containers_match_reference(cfg, data, pu_optional=True, skip=("max_volume",))
    assert {c.max_volume for c in cfg.containers} == {40.0}
    assert max(data["MAX_VOLUMES"].values()) < 40.0
    assert cfg.timestep_s == 120
    assert cfg.num_processing_units == 2
    assert cfg.episode_length_steps == 1500
    assert cfg.overflow_reward == -1
    assert cfg.penalty_reward == data["MIN_REWARD"]
    assert cfg.initial_volume_min == data["MIN_STARTING_VOLUME"]
    assert cfg.initial_volume_max == data["MAX_STARTING_VOLUME"]


def test_n16_missing_pu_parameters_are_filled_as_documented(ref_dir):
    """The six containers without PU figures in all_sutco_constants.json: C2-10 and C2-60 take
    theirs from 11containers_2presses_3.json, the other four the median of the 12 measured ones."""
    sutco = _read_json(ref_dir / "all_sutco_constants.json")
    eleven = _read_json(ref_dir / "11containers_2presses_3.json")
    cfg = {c.name: c for c in load_config("n16_m2_dt120").containers}
    lacking = sorted(set(sutco["ENABLED_CONTAINERS"]) - set(sutco["PRESS_OFFSETS"]))
    assert lacking == ["C1-10", "C1-50", "C2-10", "C2-40", "C2-60", "C2-90"]

    offsets, slopes = dict(sutco["PRESS_OFFSETS"]), dict(sutco["PRESS_SLOPES"])
    for name in ("C2-10", "C2-60"):
        assert cfg[name].pu_offset_s == eleven["PRESS_OFFSETS"][name]
        assert cfg[name].pu_time_per_product_s == eleven["PRESS_SLOPES"][name]
        offsets[name], slopes[name] = eleven["PRESS_OFFSETS"][name], eleven["PRESS_SLOPES"][name]
    assert len(offsets) == len(slopes) == 12
    for name in ("C1-10", "C1-50", "C2-40", "C2-90"):
        assert cfg[name].pu_offset_s == pytest.approx(statistics.median(offsets.values()), rel=1e-12)
        assert cfg[name].pu_time_per_product_s == pytest.approx(statistics.median(slopes.values()), rel=1e-12)


# ---- 3. loading reference-format files -----------------------------------------------------
def test_reference_json_path_loads_like_the_builtin(ref_dir):
    """A path to a paper reference file gives the same figures as the matching built-in."""
    for name in ("n5_m2_dt120", "n11_m11_dt60"):
        path = ref_dir / PAPER_FILES[name]
        builtin = load_config(name)
        assert _plant_figures(load_config(path)) == _plant_figures(builtin)
        assert _plant_figures(load_config(str(path))) == _plant_figures(builtin)


def test_shared_list_form_example_loads(ref_dir):
    """list_constants_example.json (ENABLED_CONTAINERS = 3, per-container lists) loads as 3
    containers with the listed figures."""
    data = _read_json(ref_dir / "list_constants_example.json")
    assert data["ENABLED_CONTAINERS"] == 3
    cfg = load_config(ref_dir / "list_constants_example.json")
    assert cfg.n_containers == 3
    _assert_matches_reference(cfg, data)


def test_own_reference_json_keyed_form(tmp_path):
    """A hand-written keyed reference-format file loads figure for figure."""
    data = _reference_dict()
    cfg = load_config(_write(tmp_path, "mine.json", data))
    _assert_matches_reference(cfg, data)
    assert cfg.container_names == ("P-1", "P-2", "P-3")


def test_own_reference_json_list_form(tmp_path):
    """The same plant in list form (ENABLED_CONTAINERS a count) gives the same figures."""
    data = _reference_dict()
    keyed = load_config(_write(tmp_path, "keyed.json", data))
    listed = load_config(_write(tmp_path, "listed.json", _to_list_form(data)))
    assert listed.n_containers == 3
    _assert_matches_reference(listed, _to_list_form(data))
    # Names differ (the list form has none), every other figure is the same.
    strip = lambda cfg: [dataclasses.replace(c, name="") for c in cfg.containers]  # noqa: E731
    assert strip(listed) == strip(keyed)
    assert _plant_figures(listed)[1:] == _plant_figures(keyed)[1:]


def test_own_toml_and_json_in_our_format(tmp_path, monkeypatch):
    """Our format loads from TOML and JSON alike, figure for figure; a bare file name is looked
    up in the working directory."""
    d = _plant_dict()
    from_toml = load_config(_write(tmp_path, "plant.toml", d))
    from_json = load_config(_write(tmp_path, "plant.json", d))
    assert from_toml == from_json
    assert from_toml.name == "tiny"
    assert from_toml.description == d["description"]
    for key in ("num_processing_units", "timestep_s", "episode_length_steps", "initial_volume_min",
                "initial_volume_max", "overflow_reward", "penalty_reward"):
        assert getattr(from_toml, key) == d[key], key
    for c, rc in zip(from_toml.containers, d["containers"], strict=True):
        for key, value in rc.items():
            got = getattr(c, key)
            assert (list(got) if isinstance(got, tuple) else got) == value, (c.name, key)
    monkeypatch.chdir(tmp_path)
    assert load_config("plant.toml") == from_toml


# ---- 4. overrides, protocol, immutability --------------------------------------------------
def test_paper_test_protocol():
    """protocol='paper_test' sets δ=120 s and T=600 and leaves the plant itself alone."""
    base = load_config("n5_m2_dt60")
    cfg = load_config("n5_m2_dt60", protocol="paper_test")
    assert cfg.timestep_s == 120
    assert cfg.episode_length_steps == 600
    assert cfg.containers == base.containers
    assert cfg.num_processing_units == base.num_processing_units
    assert (cfg.overflow_reward, cfg.penalty_reward) == (base.overflow_reward, base.penalty_reward)
    assert dict(PAPER_TEST_PROTOCOL) == {"timestep_s": 120, "episode_length_steps": 600}
    # The base config is untouched.
    assert (base.timestep_s, base.episode_length_steps) == (60, 1500)


def test_overrides_apply_after_protocol_and_cast():
    """Keyword overrides replace plant fields (after the protocol) with the field's type."""
    cfg = load_config("n5_m2_dt120", timestep_s=60)
    assert cfg.timestep_s == 60.0 and isinstance(cfg.timestep_s, float)
    assert cfg.containers == load_config("n5_m2_dt120").containers
    both = load_config("n5_m2_dt60", protocol="paper_test", timestep_s=30)
    assert (both.timestep_s, both.episode_length_steps) == (30, 600)
    cast = load_config("n5_m2_dt120", episode_length_steps=250.0, num_processing_units=3)
    assert cast.episode_length_steps == 250 and isinstance(cast.episode_length_steps, int)
    assert cast.num_processing_units == 3
    # A PlantConfig is accepted as the source too.
    assert load_config(cfg, timestep_s=90).timestep_s == 90


def test_unknown_override_names_the_key():
    with pytest.raises(ConfigError, match="timestep_seconds"):
        load_config("n5_m2_dt120", timestep_seconds=60)
    with pytest.raises(ConfigError, match="bogus"):
        load_config("n5_m2_dt120").replace(bogus=1)


def test_config_is_immutable():
    """Neither the plant nor its containers can be changed in place."""
    cfg = load_config("n5_m2_dt120")
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.timestep_s = 60.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.containers[0].max_volume = 1.0
    assert isinstance(cfg.containers, tuple)
    assert isinstance(cfg.containers[0].reward_peaks, tuple)
    assert cfg.timestep_s == 120


def test_replace_revalidates():
    """replace() builds a new config through the same validation as loading."""
    cfg = load_config("n5_m2_dt120")
    with pytest.raises(ConfigError, match="timestep_s"):
        cfg.replace(timestep_s=0)
    with pytest.raises(ConfigError, match="num_processing_units"):
        cfg.replace(num_processing_units=0)
    with pytest.raises(ConfigError, match="initial_volume_max"):
        cfg.replace(initial_volume_max=40)  # every container of this plant has v_max = 40
    bad = dataclasses.replace(cfg.containers[1], reward_heights=(1.5, 0.3))
    with pytest.raises(ConfigError, match=f"{cfg.containers[1].name}.*reward_heights"):
        cfg.replace(containers=(cfg.containers[0], bad, *cfg.containers[2:]))
    two = cfg.replace(containers=cfg.containers[:2])
    assert two.n_containers == 2 and PlantParams.from_config(two).n_containers == 2


def test_params_arrays_are_read_only():
    """The physics core's arrays cannot be written through PlantParams."""
    p = PlantParams.from_config(load_config("n5_m2_dt120"))
    arrays = {name: value for name, value in p._asdict().items() if isinstance(value, np.ndarray)}
    assert {"fill_mean_per_step", "max_volume", "reward_peaks"} <= set(arrays)
    for name, a in arrays.items():
        assert not a.flags.writeable, name
        with pytest.raises(ValueError):
            a[...] = 0


def test_derived_params_follow_overrides():
    """PlantParams follow an overridden config: μ·δ and σ·√δ use the new δ, and the
    original config's params are unchanged."""
    base = load_config("n5_m2_dt120")
    base_mean = PlantParams.from_config(base).fill_mean_per_step.copy()
    cfg = load_config("n5_m2_dt120", timestep_s=60)
    mu = np.array([c.fill_rate_per_s for c in cfg.containers])
    sigma = np.array([c.fill_noise_per_sqrt_s for c in cfg.containers])
    p = PlantParams.from_config(cfg)
    assert p.timestep_s == 60
    np.testing.assert_allclose(p.fill_mean_per_step, mu * 60, rtol=1e-12)
    np.testing.assert_allclose(p.fill_std_per_step, sigma * math.sqrt(60), rtol=1e-12)
    np.testing.assert_allclose(PlantParams.from_config(base).fill_mean_per_step, mu * 120, rtol=1e-12)
    np.testing.assert_array_equal(PlantParams.from_config(base).fill_mean_per_step, base_mean)
    paper = PlantParams.from_config(load_config("n5_m2_dt60", protocol="paper_test"))
    assert (paper.timestep_s, paper.episode_length_steps) == (120, 600)


# ---- 5. validation errors ------------------------------------------------------------------
def test_valid_plant_dict_loads(tmp_path):
    """Positive control for the cases below: the unmodified test plant is valid."""
    cfg = load_config(_write(tmp_path, "ok.toml", _plant_dict()))
    assert cfg.container_names == ("A", "B")


def _set(path: str, value):
    """A mutator setting ``key`` or ``containers.<i>.key`` of a plant dict."""
    def mutate(d):
        parts = path.split(".")
        target = d
        for p in parts[:-1]:
            target = target[int(p)] if p.isdigit() else target[p]
        target[parts[-1]] = value
    return mutate


def _delete(path: str):
    def mutate(d):
        parts = path.split(".")
        target = d
        for p in parts[:-1]:
            target = target[int(p)] if p.isdigit() else target[p]
        del target[parts[-1]]
    return mutate


# Container index 1 is "B" (v_max 35): per-container errors must name it.
OUR_FORMAT_ERRORS = {
    "max_volume_zero": (_set("containers.1.max_volume", 0.0), r"'B'.*max_volume"),
    "max_volume_negative": (_set("containers.1.max_volume", -5.0), r"'B'.*max_volume"),
    "product_size_zero": (_set("containers.1.product_size", 0.0), r"'B'.*product_size"),
    "product_size_negative": (_set("containers.1.product_size", -1.0), r"'B'.*product_size"),
    "reward_width_zero": (_set("containers.1.reward_widths", [0.0]), r"'B'.*reward_widths"),
    "reward_width_negative": (_set("containers.0.reward_widths", [2.0, -0.5]), r"'A'.*reward_widths"),
    "timestep_zero": (_set("timestep_s", 0.0), r"timestep_s"),
    "timestep_negative": (_set("timestep_s", -60.0), r"timestep_s"),
    "no_processing_units": (_set("num_processing_units", 0), r"num_processing_units"),
    "reward_height_zero": (_set("containers.1.reward_heights", [0.0]), r"'B'.*reward_heights"),
    "reward_height_above_one": (_set("containers.1.reward_heights", [1.5]), r"'B'.*reward_heights"),
    "r_min_equal_r_pen": (_set("overflow_reward", -0.1), r"overflow_reward"),
    "r_min_above_r_pen": (_set("overflow_reward", -0.05), r"overflow_reward"),
    "r_pen_zero": (_set("penalty_reward", 0.0), r"penalty_reward"),
    "r_pen_positive": (_set("penalty_reward", 0.5), r"penalty_reward"),
    "initial_min_negative": (_set("initial_volume_min", -1.0), r"initial_volume_min"),
    "initial_max_equals_a_vmax": (_set("initial_volume_max", 35.0), r"initial_volume_max.*'B'"),
    "initial_max_above_a_vmax": (_set("initial_volume_max", 36.0), r"initial_volume_max.*'B'"),
    "initial_min_above_max": (_set("initial_volume_min", 25.0), r"initial_volume_min"),
    "unknown_top_level_key": (_set("timestep_seconds", 60.0), r"unknown config key.*timestep_seconds"),
    "unknown_container_key": (_set("containers.1.capacity", 30.0), r"'B'.*unknown key.*capacity"),
    "missing_top_level_key": (_delete("penalty_reward"), r"missing.*penalty_reward"),
    "missing_container_key": (_delete("containers.1.product_size"), r"'B'.*missing.*product_size"),
    "duplicate_names": (_set("containers.1.name", "A"), r"duplicate.*'A'"),
    "peaks_longer_than_heights": (_set("containers.0.reward_peaks", [30.0, 20.0, 10.0]), r"'A'.*equal lengths"),
    "widths_shorter": (_set("containers.0.reward_widths", [2.0]), r"'A'.*equal lengths"),
    "string_for_container_number": (_set("containers.1.fill_rate_per_s", "fast"), r"'B'.*fill_rate_per_s.*number"),
    "string_for_plant_number": (_set("timestep_s", "60"), r"timestep_s.*number"),
    "string_in_peak_list": (_set("containers.1.reward_peaks", ["25"]), r"'B'.*reward_peaks.*number"),
    "string_for_int": (_set("episode_length_steps", "100"), r"episode_length_steps.*integer"),
    "fractional_int": (_set("num_processing_units", 1.5), r"num_processing_units.*integer"),
}


@pytest.mark.parametrize("suffix", [".toml", ".json"])
@pytest.mark.parametrize("case", sorted(OUR_FORMAT_ERRORS))
def test_our_format_validation_errors(case, suffix, tmp_path):
    """Each invalid plant raises ConfigError naming the field (and container where per-container)."""
    mutate, pattern = OUR_FORMAT_ERRORS[case]
    d = copy.deepcopy(_plant_dict())
    mutate(d)
    path = _write(tmp_path, f"bad{suffix}", d)
    with pytest.raises(ConfigError, match=pattern):
        load_config(path)


REFERENCE_ERRORS = {
    "missing_container_in_table": (_delete("PRESS_OFFSETS.P-2"), r"PRESS_OFFSETS.*'P-2'"),
    "missing_reward_widths": (_delete("REWARD_PARAMS.P-3.widths"), r"REWARD_PARAMS.*'P-3'.*widths"),
    "mismatched_reward_lengths": (_set("REWARD_PARAMS.P-2.heights", [1]), r"'P-2'.*equal lengths"),
    "missing_top_level_key": (_delete("MIN_REWARD"), r"MIN_REWARD"),
    "unknown_top_level_key": (_set("MAX_VOLUME", 40), r"MAX_VOLUME"),
    "string_for_number": (_set("RW_MUS.P-3", "0.004"), r"'P-3'.*fill_rate_per_s.*number"),
    "non_positive_bale_size": (_set("BALE_SIZES.P-1", 0), r"'P-1'.*product_size"),
    "bad_enabled_containers": (_set("ENABLED_CONTAINERS", 0), r"ENABLED_CONTAINERS"),
}


@pytest.mark.parametrize("case", sorted(REFERENCE_ERRORS))
def test_reference_format_validation_errors(case, tmp_path):
    """Errors in a keyed reference-format file name the key (or our field) and the container."""
    mutate, pattern = REFERENCE_ERRORS[case]
    d = _reference_dict()
    mutate(d)
    with pytest.raises(ConfigError, match=pattern):
        load_config(_write(tmp_path, "bad.json", d))


def test_reference_missing_container_in_shared_file(ref_dir, tmp_path):
    """Deleting one container from PRESS_OFFSETS of a paper file names PRESS_OFFSETS and it."""
    d = _read_json(ref_dir / "5containers_2presses_2.json")
    del d["PRESS_OFFSETS"]["C1-60"]
    with pytest.raises(ConfigError, match=r"PRESS_OFFSETS.*'C1-60'"):
        load_config(_write(tmp_path, "bad.json", d))


@pytest.mark.parametrize("key", [*REF_TO_FIELD, "REWARD_PARAMS"])
def test_reference_list_form_length_mismatch(key, tmp_path):
    """In the list form every per-container list must have one entry per container."""
    d = _to_list_form(_reference_dict())
    d[key] = d[key][:-1]
    with pytest.raises(ConfigError, match=key):
        load_config(_write(tmp_path, "bad.json", d))
    d[key] = d[key] + d[key][:2]  # too long
    with pytest.raises(ConfigError, match=key):
        load_config(_write(tmp_path, "bad.json", d))


def test_unreadable_files(tmp_path):
    """Missing files, directories, malformed TOML/JSON and unknown suffixes raise ConfigError
    naming the file."""
    with pytest.raises(ConfigError, match=r"nope\.toml.*no such file"):
        load_config(tmp_path / "nope.toml")
    (tmp_path / "adir.toml").mkdir()
    with pytest.raises(ConfigError, match=r"cannot read.*adir\.toml"):
        load_config(tmp_path / "adir.toml")
    with pytest.raises(ConfigError, match=r"broken\.toml.*not valid TOML"):
        load_config(_write(tmp_path, "broken.toml", "timestep_s = = 60\n"))
    with pytest.raises(ConfigError, match=r"broken\.json.*not valid JSON"):
        load_config(_write(tmp_path, "broken.json", '{"TIMESTEP": 60,'))
    with pytest.raises(ConfigError, match=r"plant\.yaml.*\.toml or \.json"):
        load_config(_write(tmp_path, "plant.yaml", "timestep_s: 60\n"))
    with pytest.raises(ConfigError, match=r"mapping"):
        load_config(_write(tmp_path, "list.json", "[1, 2, 3]"))


def test_unknown_builtin_and_protocol():
    with pytest.raises(ConfigError, match=r"unknown config 'n7_m3_dt90'"):
        load_config("n7_m3_dt90")
    with pytest.raises(ConfigError, match=r"protocol.*paper_train"):
        load_config("n5_m2_dt120", protocol="paper_train")


def test_config_error_is_a_value_error():
    """Callers that catch ValueError also catch configuration errors."""
    assert issubclass(ConfigError, ValueError)
    with pytest.raises(ValueError):
        load_config("n5_m2_dt120", timestep_s=-1)


def test_direct_construction_is_validated():
    """Building a ContainerSpec/PlantConfig by hand goes through the same checks."""
    base = load_config("n5_m2_dt120")
    spec = dataclasses.replace(base.containers[0], name="X", max_volume=0.0)
    with pytest.raises(ConfigError, match=r"'X'.*max_volume"):
        PlantConfig(**{**{f.name: getattr(base, f.name) for f in dataclasses.fields(base) if f.init},
                       "containers": (spec,)})
    with pytest.raises(ConfigError, match="containers"):
        dataclasses.replace(base, containers=())
    assert isinstance(base.containers[0], ContainerSpec)


# ---- 6. TOML round trip --------------------------------------------------------------------
@pytest.mark.parametrize("name", BUILTINS)
def test_to_toml_round_trip(name, tmp_path):
    """to_toml() output, written to a file and loaded again, is an equal config."""
    cfg = load_config(name)
    again = load_config(_write(tmp_path, f"{name}_copy.toml", cfg.to_toml()))
    assert again == cfg
    assert again.description == cfg.description


def test_to_toml_round_trip_awkward_strings(tmp_path):
    """Descriptions with quotes, backslashes, newlines and non-ASCII text survive; names use every
    character a safe name may hold."""
    base = load_config(_write(tmp_path, "ok.toml", _plant_dict()))
    cfg = base.replace(
        name="plant_2.b+c-d",
        description='line one\nline two: "Süd" \\ ü, 🙂, tab\there\r\nend\x7f',
        containers=(dataclasses.replace(base.containers[0], name="C1-20.a+b_c"), base.containers[1]),
    )
    again = load_config(_write(tmp_path, "awkward.toml", cfg.to_toml()))
    assert again == cfg
    assert again.description == cfg.description


@pytest.mark.parametrize("name", ["x/../../somewhere/name", "../up", "a/b", "with space", "nul\x00", "new\nline",
                                  "", ".hidden", "a..b", "é", "x" * 65])
def test_unsafe_container_and_plant_names_are_refused(tmp_path, name):
    """Names become agent names and parts of file names (figures, records): nothing that could
    leave an output folder or break a line."""
    base = load_config(_write(tmp_path, "ok.toml", _plant_dict()))
    with pytest.raises(ConfigError, match="containers: name|container names must be"):
        base.replace(containers=(dataclasses.replace(base.containers[0], name=name), base.containers[1]))
    with pytest.raises(ConfigError, match="^name"):
        base.replace(name=name)


def test_reward_peaks_are_bounded(tmp_path):
    base = load_config(_write(tmp_path, "ok.toml", _plant_dict()))
    c = base.containers[0]
    many = dataclasses.replace(c, reward_peaks=(10.0,) * 1000, reward_heights=(1.0,) * 1000,
                               reward_widths=(1.0,) * 1000)
    with pytest.raises(ConfigError, match="at most 16 peaks"):
        base.replace(containers=(many, base.containers[1]))


# ---- 7. non-editable install ---------------------------------------------------------------
def test_wheel_install_loads_builtin_configs(tmp_path):
    """A built wheel, used without the source tree, still finds the built-in configs and the rule that wrote the larger ones."""
    # Build from a copy so the build does not leave build/ or *.egg-info in the working tree; the copy
    # leaves out what no wheel holds (environments, published results, runs: copying and deleting
    # those took most of this test's two minutes)
    src = tmp_path / "src"
    shutil.copytree(
        REPO_ROOT, src,
        ignore=shutil.ignore_patterns(".git", ".venv*", "build", "dist", "*.egg-info", "__pycache__",
                                      ".pytest_cache", ".hypothesis", "runs*", "results"),
    )
    wheel_dir = tmp_path / "wheels"
    base_cmd = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(wheel_dir), str(src)]
    has_setuptools = subprocess.run([sys.executable, "-c", "import setuptools"]).returncode == 0
    build = None
    if has_setuptools:
        build = subprocess.run(base_cmd[:5] + ["--no-build-isolation"] + base_cmd[5:],
                               capture_output=True, text=True)
    if build is None or build.returncode != 0:
        build = subprocess.run(base_cmd, capture_output=True, text=True)
    assert build.returncode == 0, build.stdout + build.stderr
    (wheel,) = wheel_dir.glob("containergym_marl-*.whl")

    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as zf:
        zf.extractall(site)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    # The venv's editable install must not fill gaps in the wheel: drop its import hook, then
    # check that every containergym_marl module (the configs package too) comes from the wheel.
    script = (
        "import json, pathlib, sys\n"
        "sys.meta_path[:] = [f for f in sys.meta_path if 'editable' not in repr(f).lower()]\n"
        "site = pathlib.Path(sys.argv[1]).resolve()\n"
        "import containergym_marl, containergym_marl.configs\n"
        "from containergym_marl import list_configs, load_config\n"
        "where = pathlib.Path(containergym_marl.__file__).resolve()\n"
        "cfg = load_config('n5_m2_dt120')\n"
        "for name, mod in list(sys.modules.items()):\n"
        "    if name.split('.')[0] == 'containergym_marl':\n"
        "        assert site in pathlib.Path(mod.__file__).resolve().parents, (name, mod.__file__)\n"
        "from containergym_marl.config.hyperparams import method_settings\n"
        "lr = method_settings('fast_shared_ppo')['learning_rate']\n"
        "from containergym_marl.configs import scaled\n"
        "assert scaled.main(['--check']) == 0  # the rule ships beside the files it wrote\n"
        "print(json.dumps({'count': len(list_configs()), 'names': list_configs(), 'n': cfg.n_containers, 'file': str(where), 'lr': lr}))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(site)}
    env.pop("CONTAINERGYM_REFERENCE_CONFIGS", None)
    run = subprocess.run([sys.executable, "-c", script, str(site)], cwd=elsewhere, env=env,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    out = json.loads(run.stdout.strip().splitlines()[-1])
    assert out["count"] == len(BUILTINS) == 15
    assert sorted(out["names"]) == sorted(BUILTINS)
    assert out["n"] == 5
    assert not Path(out["file"]).is_relative_to(REPO_ROOT)
    assert out["lr"] > 0  # the methods' settings files (configs/hyperparams/) ship in the wheel


# ---- direct construction is validated as strictly as the loaders ------------------------------
def test_direct_construction_rejects_non_finite_and_non_numeric_values():
    base = load_config("n5_m2_dt120")
    with pytest.raises(ConfigError, match="timestep_s"):
        dataclasses.replace(base, timestep_s=float("inf"))
    c0 = base.containers[0]
    with pytest.raises(ConfigError, match=r"container 'C1-20': fill_rate_per_s"):
        dataclasses.replace(base, containers=(dataclasses.replace(c0, fill_rate_per_s="fast"), *base.containers[1:]))
    with pytest.raises(ConfigError, match=r"container 'C1-20': fill_rate_per_s must be >= 0"):
        dataclasses.replace(base, containers=(dataclasses.replace(c0, fill_rate_per_s=-0.01), *base.containers[1:]))
    with pytest.raises(ConfigError, match=r"container 'C1-20': reward_peaks"):
        dataclasses.replace(base, containers=(dataclasses.replace(c0, reward_peaks=(float("nan"),)), *base.containers[1:]))


def test_reference_reward_params_must_be_triples():
    from containergym_marl.config.reference_format import config_from_reference_json

    data = {
        "MAX_EPISODE_LENGTH": 10, "TIMESTEP": 60, "ENABLED_CONTAINERS": 1, "N_PRESSES": 1,
        "MIN_STARTING_VOLUME": 0, "MAX_STARTING_VOLUME": 10, "FAILURE_PENALTY": -1,
        "RW_MUS": [0.01], "RW_SIGMAS": [0.1], "MAX_VOLUMES": [40], "BALE_SIZES": [10],
        "PRESS_OFFSETS": [50], "PRESS_SLOPES": [100], "REWARD_PARAMS": [[25, 1, 2]], "MIN_REWARD": -0.1,
    }
    with pytest.raises(ConfigError, match=r"REWARD_PARAMS: container 'C1'.*triples"):
        config_from_reference_json(data)
    data["REWARD_PARAMS"] = [[[25, 1, 2]]]
    assert config_from_reference_json(data).containers[0].reward_peaks == (25.0,)


# ---- reading is bounded: size, depth, duplicate keys, huge numbers, devices ---------------------------
def _json_plant(tmp_path, name: str, text: str):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_deep_nesting_is_refused_before_the_parser_recurses(tmp_path):
    path = _json_plant(tmp_path, "deep.json", "[" * 100_000 + "]" * 100_000)
    with pytest.raises(ConfigError, match="nested deeper than 16"):
        load_config(path)


def test_a_duplicate_json_key_is_refused_not_silently_overwritten(tmp_path):
    text = json.dumps(_plant_dict()).replace('"num_processing_units": ', '"num_processing_units": 3, "num_processing_units": ', 1)
    with pytest.raises(ConfigError, match=r"duplicate key\(s\) \['num_processing_units'\]"):
        load_config(_json_plant(tmp_path, "dup.json", text))


def test_a_5000_digit_integer_is_refused_naming_its_field(tmp_path):
    plant = _plant_dict()
    text = json.dumps({**plant, "num_processing_units": 7}).replace(": 7", ": " + "9" * 5000, 1)
    with pytest.raises(ConfigError, match=r"num_processing_units: expected an integer, got <an integer of 5000 digits>"):
        load_config(_json_plant(tmp_path, "huge.json", text))


def test_devices_and_huge_files_are_never_read(tmp_path):
    link = tmp_path / "zero.json"
    link.symlink_to("/dev/zero")
    with pytest.raises(ConfigError, match="not a regular file"):
        load_config(link)
    with pytest.raises(ConfigError, match="expected a .toml or .json file"):
        load_config("/dev/zero")
    big = tmp_path / "big.json"
    big.write_text(" " * 1_000_001)
    with pytest.raises(ConfigError, match="more than the 1000000"):
        load_config(big)
