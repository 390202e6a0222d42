"""studies/decision_differences.py: the counts of differing decisions by hand, and the script end to end
on one validation episode (the learned model's hash checked, the figure and the JSON written)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import torch

from containergym_marl.manifest import write_manifest
from containergym_marl.policies.actor_critic import ActorCritic
from tests.helpers import ROOT, load_script

load_script("studies/planner_figures.py")  # the sibling study it imports, as running it from studies/ finds it
script = load_script("studies/decision_differences.py")


def test_differences_by_hand():
    # 3 steps, 3 containers; step 1 has no free PU
    learned = np.array([[1, 0, 0], [0, 1, 0], [1, 1, 0]], bool)
    planned = np.array([[1, 0, 0], [0, 0, 0], [0, 0, 1]], bool)
    denied = np.array([[0, 0, 0], [0, 1, 0], [0, 1, 0]], bool)
    episode = {"learned": learned, "planned": planned, "denied": denied, "free_pus": np.array([1, 0, 1]),
               "overflowed": False}
    assert script.differences(episode) == {
        "steps": 3, "differing_steps": 2, "extra": 3, "denied_extra": 2, "missing": 1, "missing_with_a_free_pu": 1,
        "learned_requests": 4, "planned_requests": 2, "denied_requests": 2, "overflowed": False}


def test_the_script_end_to_end_on_one_episode(tmp_path):
    folder = tmp_path / "published"
    (folder / "models").mkdir(parents=True)
    model = folder / "models" / "agents.pt"
    ActorCritic("decentralised", 9, 2, generator=torch.Generator().manual_seed(0)).save(model)
    write_manifest(folder)
    proc = subprocess.run([sys.executable, str(ROOT / "studies" / "decision_differences.py"), "--config", "n11_m2_dt120",
                           "--learned", f"someone={model}", "--episodes", "1", "--out", str(tmp_path / "f0"),
                           "--json", str(tmp_path / "d0.json")], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode != 0 and "observations of shape (9,)" in proc.stderr and not (tmp_path / "d0.json").exists()
    ActorCritic("decentralised", 25, 2, generator=torch.Generator().manual_seed(0)).save(model)
    write_manifest(folder)
    out_json = tmp_path / "decisions.json"
    proc = subprocess.run([sys.executable, str(ROOT / "studies" / "decision_differences.py"), "--config", "n11_m2_dt120",
                           "--learned", f"someone={model}", "--episodes", "1", "--window", "20",
                           "--out", str(tmp_path / "figures"), "--json", str(out_json)],
                          capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = json.loads(out_json.read_text())
    totals, [episode] = result["totals"], result["per_episode"]
    assert episode["seed"] == 20_000 and result["reference"] == "planner_agents_shielded"
    # what both request plus what only one of them requests makes up each side's requests
    assert totals["learned_requests"] - totals["extra"] == totals["planned_requests"] - totals["missing"] >= 0
    assert totals["denied_extra"] <= min(totals["denied_requests"], totals["extra"])
    assert totals["missing_with_a_free_pu"] == totals["missing"]  # the planner never asks for a busy PU
    assert (tmp_path / "figures" / "n11_m2_dt120_decisions_someone.png").stat().st_size > 10_000
    model.write_bytes(model.read_bytes() + b"\0")  # a published file that no longer matches its manifest
    proc = subprocess.run([sys.executable, str(ROOT / "studies" / "decision_differences.py"), "--config", "n11_m2_dt120",
                           "--learned", f"someone={model}", "--episodes", "1", "--out", str(tmp_path / "f2"),
                           "--json", str(tmp_path / "d2.json")], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode != 0 and "sha256" in proc.stderr and not (tmp_path / "d2.json").exists()
