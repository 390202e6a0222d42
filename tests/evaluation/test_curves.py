"""Sample-efficiency curves: a run's checkpoints evaluated on validation episodes, and the IQM over
seeds at each tenth of the budget."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

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
    assert [p["samples"] for p in curve["points"]] == sorted(s for s in steps if s < 6000) + [6080]  # by samples
    assert read_curve(run) == json.loads(json.dumps(curve)) and curve["protocol"]["first_seed"] == 20_000
    final = evaluate_batched(policy_from_run(run, "final"), "n5_m2_dt120", SHORT).summary()
    assert curve["points"][-1]["return_mean"] == pytest.approx(final["return_mean"])


@pytest.mark.parametrize("algo, hp", [("fast_shared_ppo", {"n_steps": 16, "minibatch_size": 80}),
                                      ("shared_ppo", {"n_steps": 16, "batch_size": 80})])
def test_the_curve_picks_the_validated_model_of_the_highest_validation_return(tmp_path, algo, hp):
    """The validated model is the policy of the curve's highest return (the earliest of equals), copied
    from its checkpoint (a native one: the model alone, tensors only; an SB3 one: the file) or the final
    model; evaluated anew it scores that return, and curve.json names it with its hash. (Seed 2 picks a
    checkpoint of the native run and the end of the SB3 run; a hand-made curve picks the other.)"""
    import hashlib
    import io

    from containergym_marl.evaluation.curves import validated_point, write_validated_model

    run = train(TrainArgs(algo=algo, out=str(tmp_path / "r"), timesteps=4000, n_envs=2, seed=2,
                          checkpoint_every=800, progress_bar=False, hyperparams=hp,
                          overrides={"episode_length_steps": 20}))
    curve = run_curve(run, SHORT)
    point = validated_point(curve)
    returns = [p["return_mean"] for p in curve["points"]]
    assert point["return_mean"] == max(returns) and point is curve["points"][returns.index(max(returns))]
    suffix = ".pt" if algo.startswith("fast") else ".zip"
    data = validated_bytes = (run / f"validated_model{suffix}").read_bytes()
    assert curve["validated"] == {"samples": point["samples"], "return_mean": point["return_mean"],
                                  "model_sha256": hashlib.sha256(data).hexdigest()} == read_curve(run)["validated"]
    again = evaluate_batched(policy_from_run(run, "validated"), "n5_m2_dt120", SHORT).summary()
    assert again["return_mean"] == pytest.approx(point["return_mean"])
    # a comparison's evaluation task gets the run's files and evaluates the validated model
    from containergym_marl.orchestration.plan import run_files
    from containergym_marl.orchestration.tasks import EvalSpec, evaluate_policy

    result, sha = evaluate_policy(EvalSpec("k", algo, "n5_m2_dt120", SHORT), run_files(run))
    assert sha == hashlib.sha256(data).hexdigest() and result.policy.endswith(",validated]")
    assert result.returns.mean() == pytest.approx(point["return_mean"])
    # the other kind of source than this seed's pick: a checkpoint for SB3 (its file), the end for native
    steps = [s for s, _ in checkpoints(run)]
    other = steps[1] if point["samples"] == curve["points"][-1]["samples"] else curve["points"][-1]["samples"]
    picked = write_validated_model(run, {"points": [{"samples": other, "return_mean": 9.0},
                                                    *({"samples": s, "return_mean": 0.0} for s in steps if s != other)]})
    data = (run / f"validated_model{suffix}").read_bytes()
    assert picked["validated"]["samples"] == other and picked["validated"]["model_sha256"] == hashlib.sha256(data).hexdigest()
    for samples in (point["samples"], other):
        path = dict(checkpoints(run)).get(samples)
        if path is None:  # the run's end
            continue
        if suffix == ".zip":
            assert path.read_bytes() == data
        else:
            saved = torch.load(path, weights_only=True)["model"]["state_dict"]
            kept = torch.load(run / "validated_model.pt", weights_only=True) if samples == other else \
                torch.load(io.BytesIO(validated_bytes), weights_only=True)
            assert "optimizer" not in kept and all(torch.equal(kept["state_dict"][k], saved[k]) for k in saved)


def test_validated_point_takes_the_earliest_of_equal_returns_and_a_run_without_one_says_so(tmp_path):
    from containergym_marl.evaluation.curves import validated_point

    curve = {"points": [{"samples": 300, "return_mean": 5.0}, {"samples": 100, "return_mean": 5.0},
                        {"samples": 200, "return_mean": 4.0}]}
    assert validated_point(curve)["samples"] == 100
    run = train(TrainArgs(algo="fast_shared_ppo", out=str(tmp_path / "r"), timesteps=800, n_envs=2,
                          progress_bar=False, hyperparams={"n_steps": 16, "minibatch_size": 80}))
    with pytest.raises(ValueError, match=r"has no validated_model\.pt: the run's sample-efficiency curve picks it"):
        policy_from_run(run, "validated")


def test_a_runs_curve_reads_one_checkpoint_per_tenth_of_the_budget(tmp_path):
    """Checkpoints denser than tenths of the budget: the curve evaluates only the newest one at or
    before each tenth (what curve_at reads), not all of them."""
    run = train(TrainArgs(algo="fast_shared_ppo", out=str(tmp_path / "r"), timesteps=3200, n_envs=2,
                          checkpoint_every=160, progress_bar=False,
                          hyperparams={"n_steps": 16, "minibatch_size": 80}, overrides={"episode_length_steps": 20}))
    steps = [s for s, _ in checkpoints(run) if s < 3200]
    assert len(steps) > 10
    expected = sorted({max(s for s in steps if s <= f * 3200) for f in np.linspace(0.1, 1.0, 10)
                       if any(s <= f * 3200 for s in steps)})
    curve = run_curve(run, SHORT, write=False)
    assert [p["samples"] for p in curve["points"]] == expected + [3200]


def test_a_sweep_task_returns_the_runs_curve_with_its_small_files(tmp_path):
    from containergym_marl.orchestration.tasks import RunSpec, train_run

    spec = RunSpec("fast_shared_ppo_n5_m2_dt120_s1", "fast_shared_ppo", "fast_shared_ppo", "n5_m2_dt120", 1, 3200,
                   str(tmp_path / "runs" / "r"), {"n_envs": 2, "checkpoint_every": 1600,
                                                  "hyperparams": {"n_steps": 16, "minibatch_size": 80}}, curve=True)
    result = train_run(spec)
    curve = json.loads(result["files"]["curve.json"])
    assert curve["protocol"]["first_seed"] == 20_000 and curve["points"][-1]["samples"] == 3200
    assert train_run(spec)["files"]["curve.json"] == result["files"]["curve.json"]  # made once


def test_curve_at_takes_the_last_policy_at_or_before_each_fraction():
    curve = {"budget": 1000, "points": [{"samples": 250, "return_mean": 1.0}, {"samples": 500, "return_mean": 2.0},
                                        {"samples": 1000, "return_mean": 3.0}]}
    got = curve_at(curve, (0.1, 0.25, 0.4, 0.5, 0.99, 1.0))
    assert np.isnan(got[0]) and got[1:].tolist() == [1.0, 1.0, 2.0, 2.0, 3.0]
    # the points in another order (newest checkpoint first, as the run directory lists them) read the same
    shuffled = {**curve, "points": curve["points"][1::-1] + curve["points"][2:]}
    assert np.array_equal(curve_at(shuffled, (0.1, 0.25, 0.4, 0.5, 0.99, 1.0)), got, equal_nan=True)


def test_iqm_curve_over_seeds():
    curves = [{"budget": 100, "points": [{"samples": 50, "return_mean": r}, {"samples": 100, "return_mean": 2 * r}]}
              for r in (1.0, 2.0, 3.0, 4.0)]
    out = iqm_curve(curves, fractions=(0.25, 0.5, 1.0), reps=200)
    assert np.isnan(out["iqm"][0]) and out["iqm"][1:] == [2.5, 5.0]  # the middle two of four seeds
    assert out["low"][1] <= 2.5 <= out["high"][1] and out["runs"] == 4
