"""studies/shared_check_screen.py: the published networks with one message per container agent and step. The
withdrawal keeps the plant's grants and drops the denied requests; bad settings are refused before anything is
written (the rule itself: tests/policies/test_shared_check.py)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from containergym_marl import load_config
from containergym_marl.core.observations import AgentObservations
from containergym_marl.core.params import PlantParams
from containergym_marl.core.simulator import PlantSimulator

REPO = Path(__file__).resolve().parents[2]
SCRIPT = str(REPO / "studies" / "shared_check_screen.py")
sys.path.insert(0, str(REPO / "studies"))
try:
    from shared_check_screen import SharedCheckPolicy, table
finally:
    sys.path.remove(str(REPO / "studies"))


class _AskEveryone:
    """A stand-in network: every agent whose container is at least a fifth full asks."""

    name, view, observation = "ask", "decentralised", "local"

    def act_batch(self, observations, masks=None):
        return (observations[:, 0] >= 0.2).astype(np.int64)


def test_withdrawing_keeps_the_plants_grants_and_drops_the_denied_requests():
    """On 200 steps of 8 simulations of n16_m2 the withdrawn requests get the plant's arbitration the same
    emptyings as the policy's own (stepped by the simulator itself), without a denied request; with no
    layer the requests are the network's."""
    cfg = load_config("n16_m2_dt120")
    params = PlantParams.from_config(cfg)
    sims = [PlantSimulator(cfg, num_sims=8) for _ in range(2)]
    for sim in sims:
        sim.reset(generators=[np.random.default_rng(10 + b) for b in range(8)])
    observe = AgentObservations(params, "local", 8)
    withdraw, plain = SharedCheckPolicy(_AskEveryone(), params, "withdraw", 1e-6, 24), \
        SharedCheckPolicy(_AskEveryone(), params, "none", 1e-6, 24)
    denied = 0
    for _ in range(200):
        obs = observe(sims[0].state, sims[0].previous_requests, sims[0].previous_granted).reshape(8 * 16, -1)
        mine, theirs = withdraw.act_batch(obs).reshape(8, 16), plain.act_batch(obs).reshape(8, 16)
        np.testing.assert_array_equal(theirs, _AskEveryone().act_batch(obs).reshape(8, 16))
        a, b = sims[0].step(mine.astype(bool)), sims[1].step(theirs.astype(bool))
        np.testing.assert_array_equal(a.granted, b.granted)
        assert not a.denied.any()
        denied += int(b.denied.sum())
        for sim in sims:
            done = np.flatnonzero(a.terminated | a.truncated)
            if done.size:
                sim.reset(done)
        if done.size:
            observe.reset(done)
    assert denied > 0 and withdraw.withdrawn == denied


@pytest.mark.slow  # the reference planner on 2 episodes and the screen: 15-45 s
def test_the_smoke_screen_writes_its_table_and_bad_settings_are_refused(tmp_path):
    subprocess.run([sys.executable, SCRIPT, "--smoke", "--layers", "none", "both", "--out", str(tmp_path / "out")],
                   check=True, capture_output=True, text=True, timeout=900)
    data = json.loads((tmp_path / "out" / "screen.json").read_text())
    got = data["results"]["dagger_checked_agents"]["n11_m2_dt120"]["s1"]
    assert set(got) == {"model", "none", "both"} and len(got["none"]["returns"]) == len(data["reference"]["n11_m2_dt120"]) == 2
    assert (tmp_path / "out" / "screen.md").read_text() == table(data)
    assert data["first_seed"] == 20_000 and "validation episodes (seeds 20000+" in table(data)
    subprocess.run([sys.executable, SCRIPT, "--smoke", "--fresh", "--layers", "none", "--out", str(tmp_path / "fresh")],
                   check=True, capture_output=True, text=True, timeout=900)
    fresh = json.loads((tmp_path / "fresh" / "screen.json").read_text())
    assert fresh["first_seed"] == 30_000 and "2 fresh episodes (seeds 30000+" in table(fresh)
    assert fresh["reference"]["n11_m2_dt120"] != data["reference"]["n11_m2_dt120"]
    for bad, match in ((["--epsilon", "2"], "--epsilon"), (["--window", "0"], "--window"),
                       (["--rows", "n5_m2_dt120", "--runs", str(tmp_path)], "--runs")):
        done = subprocess.run([sys.executable, SCRIPT, *bad, "--out", str(tmp_path / "bad")],
                              capture_output=True, text=True, timeout=300)
        assert done.returncode == 2 and match in done.stderr and not (tmp_path / "bad").exists()


@pytest.mark.skipif(not (REPO / "results" / "shared_check").is_dir(), reason="no committed screen")
def test_the_committed_tables_are_what_the_script_writes_from_their_json():
    for screen in (REPO / "results" / "shared_check").glob("*/screen.json"):
        assert (screen.parent / "screen.md").read_text() == table(json.loads(screen.read_text()))
