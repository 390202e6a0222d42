"""benchmarks/stress.py: the smoke run breaks no invariant, and its checks do catch broken physics."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from containergym_marl import list_configs
from containergym_marl.core import params as params_module

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "stress.py"


@pytest.fixture(scope="module")
def stress():
    spec = importlib.util.spec_from_file_location("containergym_stress", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    yield module
    sys.modules.pop(spec.name, None)


def test_smoke_run_checks_every_config_and_view_without_violations(stress, tmp_path, capsys):
    out = tmp_path / "stress.json"
    assert stress.main(["--smoke", "--quiet", "--json", str(out)]) == 0
    report = json.loads(out.read_text(encoding="utf-8"))
    assert report["violations"] == 0, report["violation_examples"]
    assert sorted(report["core"]) == sorted(list_configs())
    assert all(r["steps"] >= stress.SMOKE["core_steps"] for r in report["core"].values())
    assert set(report["views"]) == set(stress.VIEWS)
    assert all(r["steps"] >= stress.SMOKE["view_steps"] for r in report["views"].values())
    assert report["invariants"] >= 40
    assert report["fill_noise_z"]["count"] > 10_000
    printed = capsys.readouterr().out
    assert "**violations: 0**" in printed


@pytest.mark.parametrize("field, factor, invariant", [
    ("penalty_reward", 1.5, "container reward = eq. 5 / r_pen / 0"),
    ("pu_time_per_product_s", 1.0000001, "timers: g(v) on granted PUs, max(0, p − δ) elsewhere"),
    ("episode_length_steps", None, "truncated iff T reached without overflow"),
])
def test_checks_catch_a_core_that_breaks_the_physics(stress, monkeypatch, field, factor, invariant):
    """Mutated physics (the core's parameters no longer those of the config) is reported."""
    original = params_module.PlantParams.from_config.__func__

    def mutated(cls, cfg):  # the core's parameters from a slightly different (still valid) plant
        if field in ("penalty_reward", "episode_length_steps"):
            value = getattr(cfg, field)
            cfg = cfg.replace(**{field: value + 1 if factor is None else value * factor})
        else:
            c0 = cfg.containers[0]
            c0 = dataclasses.replace(c0, **{field: getattr(c0, field) * factor})
            cfg = cfg.replace(containers=(c0, *cfg.containers[1:]))
        return original(cls, cfg)

    monkeypatch.setattr(params_module.PlantParams, "from_config", classmethod(mutated))
    report = stress.run(["n5_m2_dt120"], core_steps=20_000, view_steps=20, batch=256, vec_batch=4, seed=0,
                        log=lambda msg: None)
    assert report["violations"] > 0
    assert any(invariant in e for e in report["violation_examples"])


def test_refused_invalid_action_is_checked(stress, monkeypatch):
    """An env that accepted an invalid action would be reported."""
    from containergym_marl.envs import centralised, edge

    def lenient(action, n, who):  # valid actions as before; anything else silently waits
        if isinstance(action, (int, np.integer)) and not isinstance(action, bool) and 0 <= action < n:
            return edge.discrete_action(action, n, who)
        return 0

    monkeypatch.setattr(centralised, "discrete_action", lenient)
    chk = stress.Checker()
    plant = stress.Plant(stress.load_config("n5_m2_dt120"))
    stress.stress_centralised(plant, 1000, 0, chk)
    assert chk.violations > 0
    assert all("invalid action refused" in e or "refused action changes nothing" in e for e in chk.examples)


def test_short_episodes_exercise_every_end_without_violations(stress):
    """With T = 7 every view truncates (and overflows) many episodes; ends and resets hold too."""
    report = stress.run(["n5_m2_dt120", "n16_m2_dt120"], core_steps=4096, view_steps=300, batch=128,
                        vec_batch=8, seed=1, log=lambda msg: None, episode_length_steps=7)
    assert report["violations"] == 0, report["violation_examples"]
    assert report["episode_ends"] > 1000
