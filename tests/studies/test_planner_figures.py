"""studies/planner_figures.py: the learned policies it shows are loaded safely (a published file only
while it matches its manifest, container-agent models only), by default the published ones that exist."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from containergym_marl.manifest import write_manifest
from containergym_marl.policies.actor_critic import ActorCritic
from tests.helpers import load_script

script = load_script("studies/planner_figures.py")


def _model(view: str, path):
    ActorCritic(view, 8, 2 if view == "decentralised" else 12, generator=torch.Generator().manual_seed(0)).save(path)
    return path


def test_a_published_model_loads_only_while_it_matches_its_manifest(tmp_path):
    folder = tmp_path / "published"
    (folder / "models" / "n11_m2_dt120").mkdir(parents=True)
    path = _model("decentralised", folder / "models" / "n11_m2_dt120" / "dagger_agents_best.pt")
    write_manifest(folder)
    [(policy, found)] = script.learned_policies([f"dagger_agents={path}"], "n11_m2_dt120")
    assert policy.name == "dagger_agents" and found == path
    path.write_bytes(path.read_bytes() + b"\0")
    with pytest.raises(Exception, match="sha256 differs"):
        script.learned_policies([f"dagger_agents={path}"], "n11_m2_dt120")


def test_bad_learned_specs_are_refused_with_the_offending_name(tmp_path):
    centralised = _model("centralised", tmp_path / "ppo.pt")
    with pytest.raises(SystemExit, match="--learned ppo: .* centralised model"):
        script.learned_policies([f"ppo={centralised}"], "n11_m2_dt120")
    with pytest.raises(SystemExit, match="expected NAME=PATH"):
        script.learned_policies([str(centralised)], "n11_m2_dt120")
    with pytest.raises(SystemExit, match="--learned x: no model file"):
        script.learned_policies([f"x={tmp_path / 'missing.pt'}"], "n11_m2_dt120")


def test_default_learned_policies_are_the_published_best_models_that_exist(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for name, folder in script.PUBLISHED[:1]:
        (folder / "models" / "n11_m2_dt120").mkdir(parents=True)
        _model("decentralised", folder / "models" / "n11_m2_dt120" / f"{name}_best.pt")
        write_manifest(folder)
    found = script.learned_policies(None, "n11_m2_dt120")
    assert [p.name for p, _ in found] == [script.PUBLISHED[0][0]]
    assert script.learned_policies(None, "n16_m2_dt120") == []


def test_a_short_run_writes_the_figures_and_the_behaviour_of_every_method(tmp_path):
    """One test episode of n5_m2_dt120: the rule, the planner and an untrained shared policy."""
    from containergym_marl.config import load_config
    from containergym_marl.core.observations import agent_feature_names
    from containergym_marl.core.params import PlantParams

    features = len(agent_feature_names(PlantParams.from_config(load_config("n5_m2_dt120"))))
    model = tmp_path / "untrained.pt"
    ActorCritic("decentralised", features, 2, generator=torch.Generator().manual_seed(0)).save(model)
    out, summary = tmp_path / "figures", tmp_path / "behaviour.json"
    script.main(["--config", "n5_m2_dt120", "--episodes", "1", "--window", "20", "--out", str(out),
                 "--json", str(summary), "--learned", f"untrained={model}"])
    saved = json.loads(summary.read_text())
    assert list(saved) == ["rule_based_agents", "planner_agents", "untrained", "meta"]
    assert saved["meta"]["learned"] == {"untrained": str(model)}
    assert saved["planner_agents"]["denied_requests_per_episode"] == 0
    for name in ("behaviour", "emptying_volume_ecdfs", "reward_ecdf", "pu_timeline_untrained", "episode_planner_agents"):
        assert (out / f"n5_m2_dt120_planner_{name}.png").stat().st_size > 0


def _overflowing_episode(denied: bool, pu_busy: bool):
    """Two containers (v* = 10 and 20, v_max = 12 and 40), one PU, three steps; container 0 is ready
    from the start and overflows at the last step."""
    from containergym_marl.evaluation import EpisodeRecord

    steps, n = 3, 2
    volumes = np.array([[9.5, 5.0], [10.5, 5.0], [11.5, 5.0], [12.5, 5.0]])
    timers = np.full((steps + 1, 1), 100.0 if pu_busy else 0.0)
    requested = np.zeros((steps, n), bool)
    deny = np.zeros((steps, n), bool)
    if denied:
        requested[1, 0] = deny[1, 0] = True
    zeros = np.zeros((steps, n))
    return EpisodeRecord("toy", ("a", "b"), "decentralised", "p", 0, 120.0, volumes, timers, requested,
                         np.zeros((steps, n), bool), deny, np.full((steps, n), -1), zeros, zeros, np.zeros(steps),
                         np.zeros(steps), True, False, overflowed_containers=("a",))


def test_overflow_causes_tell_a_denied_request_from_a_missed_one_and_from_no_free_pu():
    from types import SimpleNamespace

    params = SimpleNamespace(target_volume=np.array([10.0, 20.0]))
    cases = {"denied": _overflowing_episode(denied=True, pu_busy=False),
             "not_requested": _overflowing_episode(denied=False, pu_busy=False),
             "no_free_pu": _overflowing_episode(denied=False, pu_busy=True)}
    for cause, record in cases.items():
        counts = script.overflow_causes([record], params)
        assert counts == {k: int(k == cause) for k in ("denied", "not_requested", "no_free_pu")}, cause
    assert script.overflow_causes(list(cases.values()), params) == {"denied": 1, "not_requested": 1, "no_free_pu": 1}
