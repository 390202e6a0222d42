"""containergym-marl publish: small files, evaluations, best and median models, the table."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from containergym_marl.evaluation import EvalProtocol
from containergym_marl.evaluation.run_policies import evaluate_run
from containergym_marl.training import TrainArgs, train
from containergym_marl.orchestration import publish as publish_results





@pytest.mark.slow  # evaluates three SB3 seeds on 300 full-length episodes, ~35 s
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

    done = publish_results.publish(runs, out, to)

    assert sorted(done["runs"]) == [f"ppo_{config}_s{s}" for s in (1, 2, 3)]
    for s in (1, 2, 3):
        copied = sorted(p.name for p in (to / "runs" / f"ppo_{config}_s{s}").iterdir())
        assert "metrics.csv" in copied and "args.json" in copied and "checkpoints" not in copied
    # every seed on 100 validation episodes; best first by those, the median of three is the middle one
    validation = {s: json.loads((to / "validation" / config / f"ppo_s{s}.json").read_text()) for s in (1, 2, 3)}
    assert all([e["seed"] for e in v["episodes"]] == list(range(20_000, 20_100)) for v in validation.values())
    val_means = {s: np.mean([e["cumulative_reward"] for e in v["episodes"]]) for s, v in validation.items()}
    ranked = sorted(val_means, key=lambda s: -val_means[s])
    meta = json.loads((to / "models" / config / "ppo.json").read_text())
    assert (meta["best_seed"], meta["median_seed"], meta["picked_on"]) == (ranked[0], ranked[1], "validation")
    for which, seed in (("best", ranked[0]), ("median", ranked[1])):
        shipped = (to / "models" / config / f"ppo_{which}.zip").read_bytes()
        assert shipped == (runs / f"ppo_{config}_s{seed}" / "best_model.zip").read_bytes()
    table = (to / "table.md").read_text()
    assert "| n5_m2_dt120 | ppo |" in table
    # every seed's policy again on 200 fresh episodes: the best and median beside their test numbers,
    # the IQM over seeds and the share of overflowing episodes
    assert sorted(done["fresh"]) == sorted(f"{config}/ppo_s{s}" for s in (1, 2, 3))
    row = json.loads((to / "table.json").read_text())["rows"][0]
    fresh = {s: json.loads((to / "fresh" / config / f"ppo_s{s}.json").read_text()) for s in (1, 2, 3)}
    assert all([e["seed"] for e in f["episodes"]] == list(range(30_000, 30_200)) for f in fresh.values())
    for which, seed in (("best", ranked[0]), ("median", ranked[1])):
        returns = [e["cumulative_reward"] for e in fresh[seed]["episodes"]]
        assert row[f"{which}_fresh_mean"] == np.mean(returns)
        assert f"{np.mean(returns):.2f} ± {np.std(returns):.2f}" in table
    fresh_means = sorted(np.mean([e["cumulative_reward"] for e in f["episodes"]]) for f in fresh.values())
    assert row["fresh_iqm"] == pytest.approx(np.mean(fresh_means))  # three seeds: the IQM cuts nothing
    assert row["fresh_overflow_rate"] == pytest.approx(np.mean([e["overflow"] for f in fresh.values()
                                                                for e in f["episodes"]]))
    assert row["selected_on"] == "validation" and "picked on 100 validation episodes (seeds 20000–20099)" in table
    again = publish_results.publish(runs, out, to)
    assert again["fresh"] == again["validation"] == []  # the same models: nothing evaluated again

    # every published model is listed with its sha256; a file changed afterwards is refused, named
    from containergym_marl.orchestration import CompareArgs
    from containergym_marl.orchestration.shipped import shipped_plan
    from containergym_marl.manifest import ManifestError, read_manifest

    listed = read_manifest(to)
    assert f"runs/ppo_{config}_s1/best_model.zip" in listed and f"models/{config}/ppo_best.zip" in listed
    tampered = to / "runs" / f"ppo_{config}_s2" / "best_model.zip"
    tampered.write_bytes(tampered.read_bytes() + b"\0")
    args = CompareArgs(configs=[config], methods=["ppo"], shipped=str(to), episodes=2, seeds=[])
    with pytest.raises(ManifestError, match=f"ppo_{config}_s2/best_model.zip"):
        shipped_plan(args, tmp_path / "cmp2")
    with pytest.raises(ManifestError, match="differs"):
        publish_results.restore(to, tmp_path / "restored", tmp_path / "cmp3")
    assert not (tmp_path / "restored").exists()


def test_an_interrupted_run_published_with_its_checkpoint_resumes_after_restore(tmp_path):
    """--with-checkpoints keeps only the newest checkpoint; --restore brings the run back to a fresh
    runs folder, where training resumes from that checkpoint and finishes."""
    from containergym_marl.rundir import checkpoints, run_status

    runs, out, to = tmp_path / "runs", tmp_path / "cmp", tmp_path / "results"
    run = runs / "ppo_n5_m2_dt120_s1"
    args = TrainArgs(algo="ppo", config="n5_m2_dt120", seed=1, timesteps=1536, n_envs=2, out=str(run),
                     progress_bar=False, checkpoint_every=512, hyperparams={"n_steps": 128},
                     overrides={"episode_length_steps": 40})
    train(args)
    assert len(checkpoints(run)) >= 2
    newest = checkpoints(run)[0][0]
    # Cut short after its last checkpoint: what a kill before the final save leaves.
    (run / "final_model.zip").unlink()
    (run / "run.json").unlink()
    (out / "evaluations").mkdir(parents=True)

    done = publish_results.publish(runs, out, to, with_checkpoints=True)
    assert done["interrupted"] == [run.name] and done["runs"] == []
    published = to / "runs" / run.name
    assert [s for s, _ in checkpoints(published)] == [newest]
    assert not (published / "final_model.zip").exists()

    fresh_runs, fresh_out = tmp_path / "fresh_runs", tmp_path / "fresh_cmp"
    assert publish_results.restore(to, fresh_runs, fresh_out)["runs"] == [run.name]
    resumed = fresh_runs / run.name
    train(dataclasses.replace(args, out=str(resumed), resume=True))
    assert run_status(resumed) == "finished"
    assert json.loads((resumed / "run.json").read_text())["resumed_from"] == newest

    # Published again once finished: the checkpoint goes, the policies come.
    publish_results.publish(fresh_runs, fresh_out, to, with_checkpoints=True)
    assert not (published / "checkpoints").exists()
    assert (published / "final_model.zip").read_bytes() == (resumed / "final_model.zip").read_bytes()
    # A restore never replaces a run that is further trained where it is restored to.
    assert publish_results.restore(to, fresh_runs, fresh_out)["runs"] == []


def _tiny_native_runs(runs, out, config: str, seeds) -> None:
    """fast_shared_ppo runs of 2000 samples on 20-step episodes, evaluated on two episodes into ``out``."""
    for seed in seeds:
        run = train(TrainArgs(algo="fast_shared_ppo", config=config, seed=seed, timesteps=2000, n_envs=2,
                              out=str(runs / f"fast_shared_ppo_{config}_s{seed}"), progress_bar=False,
                              hyperparams={"n_steps": 16, "minibatch_size": 64}, overrides={"episode_length_steps": 20}))
        result = evaluate_run(run, protocol=EvalProtocol(episodes=2, episode_length_steps=30), write=False)
        path = out / "evaluations" / config / f"fast_shared_ppo_s{seed}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(result.to_json())


def test_published_native_ppo_runs_are_shipped_policies_of_the_main_job(tmp_path):
    """The main job (compare on the shipped folder) takes native-PPO runs like SB3 ones: their
    tensor-only best model is what it evaluates, checked against the manifest."""
    from containergym_marl.orchestration import CompareArgs
    from containergym_marl.orchestration.shipped import shipped_plan

    runs, out, to = tmp_path / "runs", tmp_path / "cmp", tmp_path / "results"
    config = "n5_m2_dt120"
    _tiny_native_runs(runs, out, config, (1, 2))
    publish_results.publish(runs, out, to, min_seeds=3)  # two seeds: no models, no fresh evaluations
    assert (to / "runs" / f"fast_shared_ppo_{config}_s1" / "best_model.pt").is_file()
    plan = shipped_plan(CompareArgs(configs=[config], methods=["fast_shared_ppo"], shipped=str(to), episodes=2,
                                     seeds=[]), tmp_path / "main")
    assert plan.seeds[(config, "fast_shared_ppo")] == [1, 2]
    to_evaluate = [(spec, source) for spec, source in plan.to_evaluate]
    assert to_evaluate and all("best_model.pt" in source["files"] for _, source in to_evaluate)


def test_shipped_native_models_get_safetensors_and_a_model_card_of_their_fresh_numbers(tmp_path):
    """Each shipped native model: the same weights as safetensors (read by the same loader, listed in
    the manifest) and a Hugging Face model card whose metric is the mean ± std of its fresh episodes."""
    import torch

    from containergym_marl.manifest import read_manifest
    from containergym_marl.policies.actor_critic import ActorCritic

    runs, out, to = tmp_path / "runs", tmp_path / "cmp", tmp_path / "results"
    config = "n5_m2_dt120"
    _tiny_native_runs(runs, out, config, (1, 2, 3))
    publish_results.publish(runs, out, to)
    folder = to / "models" / config
    meta = json.loads((folder / "fast_shared_ppo.json").read_text())
    listed = read_manifest(to)
    for which in ("best", "median"):
        seed = meta[f"{which}_seed"]
        pt, st = folder / meta["files"][which], folder / meta["safetensors"][which]
        a, b = ActorCritic.load(pt), ActorCritic.load(st)
        assert a.to_dict()["meta"] == b.to_dict()["meta"] and (a.view, a.hidden) == (b.view, b.hidden)
        for name, tensor in a.net.state_dict().items():
            assert torch.equal(tensor, b.net.state_dict()[name])
        assert f"models/{config}/{st.name}" in listed and f"models/{config}/{meta['cards'][which]}" in listed
        text = (folder / meta["cards"][which]).read_text()
        front, body = text.split("---\n")[1], text.split("---\n", 2)[2]
        fresh = json.loads((to / "fresh" / config / f"fast_shared_ppo_s{seed}.json").read_text())["episodes"]
        returns = np.array([e["cumulative_reward"] for e in fresh])
        assert len(returns) == 200
        assert f"      value: {returns.mean():.2f} +/- {returns.std():.2f}\n" in front
        assert "library_name: containergym-marl\n" in front and "- multi-agent\n" in front
        assert "- reinforcement-learning\n" in front and "- containergym_marl.container_agents_v0\n" in front
        overflow = np.mean([e["overflow"] for e in fresh])
        assert f"overflows in {overflow:.1%} of the fresh episodes" in body
        assert f"--seed {seed}" in body and f'load_model("{st.name}", algo="fast_shared_ppo")' in body
        args = json.loads((to / "runs" / f"fast_shared_ppo_{config}_s{seed}" / "args.json").read_text())
        assert json.dumps(args["hyperparams"], sort_keys=True) in body
        assert "on 100 validation episodes (seeds 20000+)" in body
        # the card's code, run in the model's folder (but its 200-episode evaluation): the policy it
        # loads from the safetensors file acts as the .pt's does
        import os

        from containergym_marl.evaluation.run_policies import policy_from_run

        code = body.split("```python\n")[1].split("```")[0]
        assert code.rstrip().splitlines()[-1].startswith("print(evaluate(policy,")
        scope, cwd = {}, os.getcwd()
        os.chdir(folder)
        try:
            exec(code.rstrip().rsplit("\n", 1)[0], scope)
        finally:
            os.chdir(cwd)
        obs = np.random.default_rng(0).normal(size=(32, a.observation_size)).astype(np.float32)
        original = policy_from_run(to / "runs" / f"fast_shared_ppo_{config}_s{seed}")
        np.testing.assert_array_equal(scope["policy"].act_batch(obs, None), original.act_batch(obs, None))


def test_a_run_with_a_validated_model_is_evaluated_shipped_and_carded_with_it(tmp_path):
    """Where a run's curve picked a validated model, that model stands for its seed: the validation and
    fresh evaluations are of it (their model hash), the shipped best and median policies are its bytes,
    the card says which checkpoint it is, and the main job (compare on the shipped folder) evaluates it."""
    import hashlib

    from containergym_marl.evaluation.curves import run_curve
    from containergym_marl.orchestration import CompareArgs
    from containergym_marl.orchestration.shipped import shipped_plan

    runs, out, to = tmp_path / "runs", tmp_path / "cmp", tmp_path / "results"
    config, short = "n5_m2_dt120", EvalProtocol(episodes=2, first_seed=20_000, episode_length_steps=30)
    validated = {}
    for seed in (1, 2, 3):
        run = train(TrainArgs(algo="fast_shared_ppo", config=config, seed=seed, timesteps=2000, n_envs=2,
                              checkpoint_every=500, out=str(runs / f"fast_shared_ppo_{config}_s{seed}"),
                              progress_bar=False, hyperparams={"n_steps": 16, "minibatch_size": 64},
                              overrides={"episode_length_steps": 20}))
        curve = run_curve(run, short)
        validated[seed] = (run / "validated_model.pt").read_bytes()
        assert curve["validated"]["model_sha256"] == hashlib.sha256(validated[seed]).hexdigest()
        result = evaluate_run(run, which="validated", protocol=EvalProtocol(episodes=2, episode_length_steps=30),
                              write=False)
        path = out / "evaluations" / config / f"fast_shared_ppo_s{seed}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(result.to_json())
    publish_results.publish(runs, out, to)
    for seed, data in validated.items():
        assert (to / "runs" / f"fast_shared_ppo_{config}_s{seed}" / "validated_model.pt").read_bytes() == data
        for folder in ("validation", "fresh"):
            evaluated = json.loads((to / folder / config / f"fast_shared_ppo_s{seed}.json").read_text())
            assert evaluated["model_sha256"] == hashlib.sha256(data).hexdigest()
            assert evaluated["policy"] == f"fast_shared_ppo[s{seed},validated]"
    meta = json.loads((to / "models" / config / "fast_shared_ppo.json").read_text())
    for which in ("best", "median"):
        seed = meta[f"{which}_seed"]
        assert (to / "models" / config / meta["files"][which]).read_bytes() == validated[seed]
        samples = json.loads((to / "runs" / f"fast_shared_ppo_{config}_s{seed}" / "curve.json").read_text())
        assert (f"- model: the run's validated model, its policy at {samples['validated']['samples']:,} samples"
                in (to / "models" / config / meta["cards"][which]).read_text())
    plan = shipped_plan(CompareArgs(configs=[config], methods=["fast_shared_ppo"], shipped=str(to), episodes=2,
                                     seeds=[]), tmp_path / "main")
    assert sorted(source["files"]["validated_model.pt"] for _, source in plan.to_evaluate) == sorted(validated.values())


def _tiny_run(runs, algo: str, config: str, seed: int, reward_mode: str | None = None):
    """A finished native run of 2000 samples on 20-step episodes, named as compare names it."""
    from containergym_marl.algorithms import get_algorithm
    from containergym_marl.rundir import run_name

    extra = {} if reward_mode is None else {"reward_mode": reward_mode}
    method = get_algorithm(algo).method_name(reward_mode)
    return train(TrainArgs(algo=algo, config=config, seed=seed, timesteps=2000, n_envs=2,
                           out=str(runs / run_name(method, config, seed)), progress_bar=False,
                           hyperparams={"n_steps": 16, "minibatch_size": 64},
                           overrides={"episode_length_steps": 20}, **extra))


def _compare_evaluation(out, run, method: str, config: str, seed: int, model_sha256: str):
    """An evaluation file as compare writes it: the run's evaluation and compare's record of its model."""
    result = json.loads(evaluate_run(run, protocol=EvalProtocol(episodes=2, episode_length_steps=30),
                                     write=False).to_json())
    result["compare"] = {"run": run.name, "timesteps": 2000, "model_sha256": model_sha256}
    path = out / "evaluations" / config / f"{method}_s{seed}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result))
    return path


def _sha(path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_publish_methods_takes_only_those_methods_runs_and_evaluations(tmp_path):
    """--methods: from a runs folder and a compare folder that hold two methods (a campaign publishing
    one while it trains the other), only the named method's runs and evaluation files are copied."""
    runs, out, to = tmp_path / "runs", tmp_path / "cmp", tmp_path / "results"
    config = "n5_m2_dt120"
    shared = _tiny_run(runs, "fast_shared_ppo", config, 1)
    team = _tiny_run(runs, "fast_shared_ppo", config, 1, reward_mode="team")
    assert (shared.name, team.name) == (f"fast_shared_ppo_{config}_s1", f"fast_shared_ppo_team_{config}_s1")
    for run, method in ((shared, "fast_shared_ppo"), (team, "fast_shared_ppo_team")):
        _compare_evaluation(out, run, method, config, 1, _sha(run / "best_model.pt"))
    done = publish_results.publish(runs, out, to, methods=("fast_shared_ppo_team",))
    assert done["runs"] == [team.name] and done["evaluations"] == 1
    assert sorted(p.name for p in (to / "runs").iterdir()) == [team.name]
    assert sorted(p.name for p in (to / "evaluations" / config).iterdir()) == ["fast_shared_ppo_team_s1.json"]
    with pytest.raises(ValueError, match="methods: unknown method.*'fast_shared_ppo_teams'"):
        publish_results.publish(runs, out, tmp_path / "other", methods=("fast_shared_ppo_teams",))
    assert not (tmp_path / "other").exists()


def test_publish_refuses_an_evaluation_of_another_model_than_the_run_ships(tmp_path):
    """An evaluation that compare made of a run before the run's shipped model changed (e.g. before its
    curve picked a validated model) would put another model's numbers in the table: an error naming
    the file, before anything is written; with the model's own hash it publishes."""
    runs, out, to = tmp_path / "runs", tmp_path / "cmp", tmp_path / "results"
    config = "n5_m2_dt120"
    run = _tiny_run(runs, "fast_shared_ppo", config, 1)
    path = _compare_evaluation(out, run, "fast_shared_ppo", config, 1, _sha(run / "final_model.pt"))
    assert _sha(run / "final_model.pt") != _sha(run / "best_model.pt")
    with pytest.raises(ValueError, match=r"fast_shared_ppo_s1\.json.*evaluates a model of fast_shared_ppo_n5_m2_dt120_s1"
                       r".*best_model\.pt.*nothing was written"):
        publish_results.publish(runs, out, to)
    assert not to.exists()
    data = json.loads(path.read_text())
    for crafted in ("../runs/fast_shared_ppo_n5_m2_dt120_s1", ".."):  # a run named outside --runs: not read
        data["compare"]["run"] = crafted
        path.write_text(json.dumps(data))
        with pytest.raises(ValueError, match=r"names the run .*not a folder's name"):
            publish_results.publish(runs, out, to)
        assert not to.exists()
    data["compare"]["run"] = run.name
    data["compare"]["model_sha256"] = _sha(run / "best_model.pt")
    path.write_text(json.dumps(data))
    assert publish_results.publish(runs, out, to)["evaluations"] == 1
