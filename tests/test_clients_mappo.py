"""baselines/train_mappo.py, the CTDE baseline, end to end at a tiny budget: BenchMARL MAPPO trains,
its final policy is evaluated with the test protocol into the evaluation file every method has,
the table reads it, and a rerun of the same command reuses the finished run.

Needs benchmarl (the ``clients`` extra).
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

pytest.importorskip("benchmarl")

from containergym_marl.evaluation import table as tables  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _script():
    spec = importlib.util.spec_from_file_location("train_mappo", ROOT / "baselines" / "train_mappo.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_mappo_trains_evaluates_and_lands_in_the_table(tmp_path, capsys):
    script = _script()
    out, evaluations = tmp_path / "run", tmp_path / "evaluations"
    argv = ["--config", "n5_m2_dt120", "--seed", "3", "--frames", "1200", "--frames-per-batch", "600",
            "--n-envs", "4", "--episodes", "2", "--out", str(out), "--evaluations", str(evaluations)]
    assert script.main(argv) == 0
    evaluation = json.loads((evaluations / "n5_m2_dt120" / "mappo_s3.json").read_text())
    assert evaluation == json.loads((out / "evaluation.json").read_text())
    assert (evaluation["policy"], evaluation["view"], len(evaluation["episodes"])) == ("mappo", "decentralised", 2)
    assert evaluation["protocol"]["timestep_s"] == 120.0 and evaluation["protocol"]["episode_length_steps"] == 600
    assert evaluation["training"] == {"frames": 1200, "plant_steps": 1200, "agent_steps": 6000, "library": "benchmarl"}
    assert (out / "policy.pt").is_file() and list(out.glob("*/checkpoints/checkpoint_*.pt"))

    (row,) = [r for r in tables.build_table(tables.load_evaluations(evaluations), ()).rows if r["method"] == "mappo"]
    assert (row["config"], row["view"], row["seeds"], row["samples"]) == ("n5_m2_dt120", "decentralised", 1, 1200)

    # the same command again: the finished run is reused (no iteration), the evaluation is the same
    capsys.readouterr()
    assert script.main(argv) == 0
    again = json.loads((out / "evaluation.json").read_text())
    assert again["episodes"] == evaluation["episodes"]

    with pytest.raises(SystemExit, match="other arguments"):
        script.main([*argv[:5], "2400", *argv[6:]])  # another budget in the same folder
