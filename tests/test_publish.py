"""baselines/publish_results.py: small files, evaluations, best and median models, the table."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np

from containergym_marl.evaluation import EvalProtocol
from containergym_marl.evaluation.runs import evaluate_run
from containergym_marl.training import TrainArgs, train

ROOT = Path(__file__).resolve().parents[1]


def _publish_module():
    spec = importlib.util.spec_from_file_location("publish_results", ROOT / "baselines" / "publish_results.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_publish_copies_small_files_evaluations_and_the_best_and_median_models(tmp_path):
    runs, out, to = tmp_path / "runs", tmp_path / "cmp", tmp_path / "results"
    config = "n5_m2_dt120"
    means = {}
    for seed in (1, 2, 3):
        run = train(TrainArgs(algo="ppo", config=config, seed=seed, timesteps=1536, n_envs=2,
                              out=str(runs / f"ppo_{config}_s{seed}"), progress_bar=False,
                              overrides={"episode_length_steps": 40}))
        result = evaluate_run(run, protocol=EvalProtocol(episodes=2, episode_length_steps=50), write=False)
        path = out / "evaluations" / config / f"ppo_s{seed}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(result.to_json())
        means[seed] = float(np.mean(result.returns))
    (runs / f"ppo_{config}_s4").mkdir()  # an unfinished run is not published

    done = _publish_module().publish(runs, out, to)

    assert sorted(done["runs"]) == [f"ppo_{config}_s{s}" for s in (1, 2, 3)]
    for s in (1, 2, 3):
        copied = sorted(p.name for p in (to / "runs" / f"ppo_{config}_s{s}").iterdir())
        assert "metrics.csv" in copied and "args.json" in copied and "checkpoints" not in copied
    ranked = sorted(means, key=lambda s: -means[s])  # best first; the median of three is the middle one
    meta = json.loads((to / "models" / config / "ppo.json").read_text())
    assert (meta["best_seed"], meta["median_seed"]) == (ranked[0], ranked[1])
    for which, seed in (("best", ranked[0]), ("median", ranked[1])):
        shipped = (to / "models" / config / f"ppo_{which}.zip").read_bytes()
        assert shipped == (runs / f"ppo_{config}_s{seed}" / "best_model.zip").read_bytes()
    table = (to / "table.md").read_text()
    assert "| n5_m2_dt120 | ppo |" in table
