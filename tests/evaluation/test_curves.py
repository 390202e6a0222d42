"""Sample-efficiency curves: a run's checkpoints evaluated on validation episodes, and the IQM over
seeds at each tenth of the budget."""

from __future__ import annotations

import json

import numpy as np
import pytest

from containergym_marl.evaluation import EvalProtocol
from containergym_marl.evaluation.batched import evaluate_batched
from containergym_marl.evaluation.curves import curve_at, iqm_curve, read_curve, run_curve
from containergym_marl.evaluation.run_policies import policy_from_run
from containergym_marl.rundir import checkpoints
from containergym_marl.training import TrainArgs, train

SHORT = EvalProtocol(episodes=3, first_seed=20_000, episode_length_steps=50)


def test_a_runs_curve_evaluates_each_checkpoint_and_the_final_model(tmp_path):
    run = train(TrainArgs(algo="fast_shared_ppo", out=str(tmp_path / "r"), timesteps=6000, n_envs=2,
                          checkpoint_every=1500, progress_bar=False,
                          hyperparams={"n_steps": 16, "minibatch_size": 80}, overrides={"episode_length_steps": 20}))
    curve = run_curve(run, SHORT)
    steps = [s for s, _ in checkpoints(run)]
    assert [p["samples"] for p in curve["points"]] == [s for s in steps if s < 6000] + [6080]
    assert read_curve(run) == json.loads(json.dumps(curve)) and curve["protocol"]["first_seed"] == 20_000
    final = evaluate_batched(policy_from_run(run, "final"), "n5_m2_dt120", SHORT).summary()
    assert curve["points"][-1]["return_mean"] == pytest.approx(final["return_mean"])


def test_curve_at_takes_the_last_policy_at_or_before_each_fraction():
    curve = {"budget": 1000, "points": [{"samples": 250, "return_mean": 1.0}, {"samples": 500, "return_mean": 2.0},
                                        {"samples": 1000, "return_mean": 3.0}]}
    got = curve_at(curve, (0.1, 0.25, 0.4, 0.5, 0.99, 1.0))
    assert np.isnan(got[0]) and got[1:].tolist() == [1.0, 1.0, 2.0, 2.0, 3.0]


def test_iqm_curve_over_seeds():
    curves = [{"budget": 100, "points": [{"samples": 50, "return_mean": r}, {"samples": 100, "return_mean": 2 * r}]}
              for r in (1.0, 2.0, 3.0, 4.0)]
    out = iqm_curve(curves, fractions=(0.25, 0.5, 1.0), reps=200)
    assert np.isnan(out["iqm"][0]) and out["iqm"][1:] == [2.5, 5.0]  # the middle two of four seeds
    assert out["low"][1] <= 2.5 <= out["high"][1] and out["runs"] == 4
