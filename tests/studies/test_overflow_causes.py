"""studies/overflow_causes.py on a short run: every overflowing episode gets exactly one cause, and
the report names the method as the registry does."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from containergym_marl.training import TrainArgs, train

REPO = Path(__file__).resolve().parents[2]


def test_each_overflowing_episode_gets_one_cause(tmp_path):
    run = train(TrainArgs(algo="fast_shared_ppo", reward_mode="team", out=str(tmp_path / "r"), timesteps=4_000,
                          n_envs=2, seed=1, progress_bar=False, overrides={"episode_length_steps": 40}))
    out = tmp_path / "out"
    subprocess.run([sys.executable, str(REPO / "studies" / "overflow_causes.py"), str(run), "--episodes", "3",
                    "--workers", "1", "--out", str(out)], capture_output=True, text=True, timeout=300, check=True)
    [entry] = json.loads((out / "causes.json").read_text())["entries"]
    assert (entry["method"], entry["row"], entry["episodes"], entry["first_seed"]) == (
        "fast_shared_ppo_team", "n5_m2_dt120", 3, 20_000)
    assert sum(entry["causes"].values()) == entry["overflowing_episodes"]
    assert "| `fast_shared_ppo_team` | `n5_m2_dt120` | 1 | 3 |" in (out / "causes.md").read_text()


def test_a_run_without_a_best_model_is_refused_before_anything_runs(tmp_path):
    done = subprocess.run([sys.executable, str(REPO / "studies" / "overflow_causes.py"), str(tmp_path / "nothing"),
                           "--out", str(tmp_path / "out")], capture_output=True, text=True, timeout=120)
    assert done.returncode != 0 and "no best_model.pt in" in done.stderr and not (tmp_path / "out").exists()
