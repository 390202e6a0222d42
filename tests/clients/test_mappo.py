"""baselines/train_mappo.py, the CTDE baseline, end to end at a tiny budget: BenchMARL MAPPO trains,
the run directory has the package's files, its actor is saved as plain torch and gives BenchMARL's
logits, ``containergym-marl evaluate RUN`` evaluates it with the test protocol into the evaluation
file every method has, the table reads it as method ``mappo`` with its budget, the saved policy
loads without BenchMARL or TorchRL, and an interrupted run resumes from its checkpoint.

Needs benchmarl (the ``clients`` extra). Tiny settings: 600 plant steps per iteration from 4
simulations, 2 passes in minibatches of 400, MLPs 16 × 16, training episodes of T = 50 (so that
some end and a best model is kept).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("benchmarl")
from benchmarl.experiment import Experiment  # noqa: E402

from containergym_marl.cli import main as cli  # noqa: E402
from containergym_marl.envs.torchrl_env import GROUP, ContainerAgentsTorchRLEnv  # noqa: E402
from containergym_marl.evaluation import EvalProtocol, evaluate  # noqa: E402
from containergym_marl.evaluation import table as tables  # noqa: E402
from containergym_marl.evaluation.run_policies import policy_from_run  # noqa: E402
from containergym_marl.policies.shared_actor import SharedActor, SharedActorPolicy  # noqa: E402
from containergym_marl.policies.torchrl_policy import TorchRLAgentsPolicy  # noqa: E402
from containergym_marl.rundir import METRIC_FIELDS, read_metrics  # noqa: E402
from tests.helpers import load_script  # noqa: E402

TINY = ["--frames-per-batch", "600", "--n-envs", "4", "--episodes", "2", "--override", "episode_length_steps=50",
        "--hp", "on_policy_n_minibatch_iters=2", "num_cells=[16,16]"]


def _script():
    return load_script("baselines/train_mappo.py")


@pytest.fixture(scope="module")
def script():
    threads = torch.get_num_threads()
    yield _script()
    torch.set_num_threads(threads)  # the script sets one thread


@pytest.fixture(scope="module")
def trained(script, tmp_path_factory):
    """One tiny run (2 iterations, 1200 plant steps), its evaluation also written for the table."""
    tmp = tmp_path_factory.mktemp("mappo")
    run, evaluations = tmp / "run", tmp / "evaluations"
    argv = ["--config", "n5_m2_dt120", "--seed", "3", "--timesteps", "1200", "--out", str(run),
            "--evaluations", str(evaluations), *TINY]
    evaluation = script.main(script.parse_args(script.Args, argv))
    return run, evaluations, evaluation, argv


def test_run_directory_budget_and_evaluation(trained):
    run, evaluations, evaluation, _ = trained
    for name in ("args.json", "config.toml", "metrics.csv", "best_model.pt", "final_model.pt", "run.json",
                 "evaluation_best.json"):
        assert (run / name).is_file(), name
    args = json.loads((run / "args.json").read_text())
    assert (args["algo"], args["timesteps"], args["budget_unit"], args["reward_mode"]) == \
        ("mappo", 1200, "plant steps", "team")
    rows = read_metrics(run)  # the package's metrics.csv: one row per iteration, plant steps
    assert [r["timesteps"] for r in rows] == [600, 1200]
    assert rows[-1]["episodes"] == 24  # 4 simulations x 150 steps / T=50, twice
    assert (run / "metrics.csv").read_text().splitlines()[0] == ",".join(METRIC_FIELDS)
    summary = json.loads((run / "run.json").read_text())
    assert summary["timesteps"] == 1200 and summary["best_model"] == "best_model.pt"
    assert summary["training"] == {"library": summary["training"]["library"], "algorithm": "mappo",
                                   "budget_plant_steps": 1200, "budget_agent_steps": 6000,
                                   "plant_steps": 1200, "agent_steps": 6000, "samples": 6000,
                                   "samples_unit": "agent steps", "reward_mode": "team"}
    # the paper's protocol, the evaluation file every method has, with the budget for the table
    saved = json.loads((evaluations / "n5_m2_dt120" / "mappo_s3.json").read_text())
    assert saved == evaluation == json.loads((run / "evaluation_best.json").read_text())
    assert (saved["policy"], saved["view"], len(saved["episodes"])) == ("mappo[s3,best]", "decentralised", 2)
    assert saved["protocol"]["timestep_s"] == 120.0 and saved["protocol"]["episode_length_steps"] == 600
    assert saved["training"]["samples"] == 6000
    (row,) = [r for r in tables.build_table(tables.load_evaluations(evaluations), (), reps=50).rows
              if r["method"] == "mappo"]
    assert (row["config"], row["view"], row["seeds"], row["samples"]) == ("n5_m2_dt120", "decentralised", 1, 6000)


def test_cli_evaluates_the_run_like_any_other(trained, tmp_path, capsys):
    run, _, evaluation, _ = trained
    out = tmp_path / "n5_m2_dt120" / "mappo_s3.json"
    assert cli(["evaluate", str(run), "--episodes", "2", "--json", str(out)]) == 0
    assert json.loads(out.read_text()) == evaluation  # the same file as the script's
    assert "mappo[s3,best] on n5_m2_dt120 (decentralised view)" in capsys.readouterr().out
    assert cli(["evaluate", str(run), "--episodes", "1", "--model", "final"]) == 0


def test_saved_actor_is_benchmarls_actor(trained):
    """final_model.pt (plain torch) gives the logits and the test episodes of BenchMARL's final
    policy, reloaded from its last checkpoint."""
    run = trained[0]
    (checkpoint,) = run.glob("benchmarl/*/checkpoints/checkpoint_1200.pt")
    reloaded = Experiment.reload_from_file(str(checkpoint))
    actor = SharedActor.load(run / "final_model.pt")
    env = reloaded.task.get_env_fun(num_envs=8, continuous_actions=False, seed=7, device="cpu")()
    with torch.no_grad():
        rollout = env.rollout(60, policy=reloaded.policy, break_when_any_done=False)
    assert torch.allclose(actor.logits(rollout[GROUP, "observation"]), rollout[GROUP, "logits"], atol=1e-5)
    protocol = EvalProtocol(episodes=2)
    ours = evaluate(policy_from_run(run, "final"), "n5_m2_dt120", protocol, keep_records=False)
    theirs = evaluate(TorchRLAgentsPolicy(reloaded.policy), "n5_m2_dt120", protocol, keep_records=False)
    assert [e.cumulative_reward for e in ours.episodes] == [e.cumulative_reward for e in theirs.episodes]
    assert [e.steps for e in ours.episodes] == [e.steps for e in theirs.episodes]
    assert isinstance(policy_from_run(run, "best"), SharedActorPolicy)


def test_policy_loads_and_evaluates_without_benchmarl_or_torchrl(trained):
    code = ("import sys\n"
            "for name in ('benchmarl', 'torchrl', 'tensordict'): sys.modules[name] = None  # unimportable\n"
            "from containergym_marl.evaluation import EvalProtocol\n"
            "from containergym_marl.evaluation.run_policies import evaluate_run\n"
            f"r = evaluate_run({str(trained[0])!r}, protocol=EvalProtocol(episodes=1), write=False)\n"
            "assert r.view == 'decentralised' and r.training['samples'] == 6000\n"
            "print('ok', r.policy)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert done.returncode == 0, done.stderr[-2000:]
    assert "ok mappo[s3,best]" in done.stdout


def test_reruns_refuse_or_reuse(script, trained, capsys):
    run, _, evaluation, argv = trained
    with pytest.raises(SystemExit, match="already holds results"):
        script.main(script.parse_args(script.Args, argv))
    with pytest.raises(SystemExit, match="timesteps=2400"):
        script.main(script.parse_args(script.Args, [*argv, "--resume", "--timesteps", "2400"]))
    mtime = (run / "final_model.pt").stat().st_mtime_ns
    again = script.main(script.parse_args(script.Args, [*argv, "--resume"]))  # finished: evaluated, not trained
    assert "finished already" in capsys.readouterr().err
    assert (run / "final_model.pt").stat().st_mtime_ns == mtime and again["episodes"] == evaluation["episodes"]


def test_interrupted_run_resumes_from_its_checkpoint(script, tmp_path, monkeypatch, capsys):
    run = tmp_path / "run"
    argv = ["--config", "n5_m2_dt120", "--seed", "4", "--timesteps", "2400", "--out", str(run), "--episodes", "1",
            *TINY[:4], *TINY[6:]]
    collected = script.RunTracker.on_batch_collected

    def interrupted(self, batch):  # the third iteration's row is written, then the process "dies"
        collected(self, batch)
        if self.experiment.total_frames == 1800:
            raise KeyboardInterrupt

    monkeypatch.setattr(script.RunTracker, "on_batch_collected", interrupted)
    with pytest.raises(KeyboardInterrupt):
        script.main(script.parse_args(script.Args, argv))
    assert [r["timesteps"] for r in read_metrics(run)] == [600, 1200, 1800]
    assert not (run / "final_model.pt").exists()
    assert [s for s, _ in script.checkpoints(run)] == [1200, 600]
    monkeypatch.setattr(script.RunTracker, "on_batch_collected", collected)
    loaded, restored = script.RunTracker.on_load_state_dict, {}

    def on_load(self, state_dict):  # what the restored experiment holds
        loaded(self, state_dict)
        restored["adam_steps"] = {int(s["step"]) for by_loss in self.experiment.optimizers.values()
                                  for opt in by_loss.values() for s in opt.state.values()}
        restored["first_observation"] = self.experiment.collector._carrier.get((GROUP, "observation")).clone()

    monkeypatch.setattr(script.RunTracker, "on_load_state_dict", on_load)
    capsys.readouterr()
    script.main(script.parse_args(script.Args, [*argv, "--resume"]))
    assert "resuming from the checkpoint at 1,200 plant steps" in capsys.readouterr().err
    # Adam's state came back with the checkpoint: 2 iterations x 2 passes x 2 minibatches (600 / 400)
    assert restored["adam_steps"] == {8}
    # the simulations start again with seeds seed + plant steps (4 + 1200 + b), not the run's own
    fresh = {seed: ContainerAgentsTorchRLEnv("n5_m2_dt120", num_envs=4, seed=seed, reward_mode="team",
                                             episode_length_steps=50).reset()[GROUP, "observation"]
             for seed in (4, 1204)}
    assert torch.equal(restored["first_observation"], fresh[1204])
    assert not torch.equal(fresh[4], fresh[1204])
    assert [r["timesteps"] for r in read_metrics(run)] == [600, 1200, 1800, 2400]  # the row after it: redone
    summary = json.loads((run / "run.json").read_text())
    assert (summary["timesteps"], summary["resumed_from"], summary["training"]["agent_steps"]) == (2400, 1200, 12000)
    assert summary["episodes"] == read_metrics(run)[-1]["episodes"]
    assert [s for s, _ in script.checkpoints(run)] == [2400]  # the earlier ones are removed at the end


def test_a_finished_run_is_published_with_its_torch_models(trained, tmp_path):
    """containergym-marl publish ships a MAPPO run like an SB3 one: finished by its final_model.pt
    (the registry's file name; before, only final_model.zip counted, so MAPPO runs stayed behind),
    its small files and both .pt models, and the best/median model of the (row, method)."""
    import shutil

    from containergym_marl.rundir import run_status

    run, evaluations, evaluation, _ = trained
    runs, out, to = tmp_path / "runs", tmp_path / "cmp", tmp_path / "published"
    shutil.copytree(run, runs / "mappo_n5_m2_dt120_s3")
    shutil.copytree(evaluations, out / "evaluations")
    assert run_status(runs / "mappo_n5_m2_dt120_s3") == "finished"
    from containergym_marl.orchestration import publish as publish_results


    done = publish_results.publish(runs, out, to, min_seeds=1)

    assert done["runs"] == ["mappo_n5_m2_dt120_s3"] and done["models"] == ["n5_m2_dt120/mappo"]
    shipped = to / "runs" / "mappo_n5_m2_dt120_s3"
    # .lock: the copy's lock (rundir.RunLock), left like a trained run's; git and the manifest ignore it
    assert sorted(p.name for p in shipped.iterdir()) == sorted(
        [".lock", "args.json", "run.json", "config.toml", "metrics.csv", "best_model.pt", "final_model.pt"])
    for which in ("best", "median"):  # one seed: it is both
        assert (to / "models" / "n5_m2_dt120" / f"mappo_{which}.pt").read_bytes() == (run / "best_model.pt").read_bytes()
    meta = json.loads((to / "models" / "n5_m2_dt120" / "mappo.json").read_text())
    assert meta["files"] == {"best": "mappo_best.pt", "median": "mappo_median.pt"} and meta["best_seed"] == 3
    assert "| n5_m2_dt120 | mappo |" in (to / "table.md").read_text()
    # the shipped run, read with torch alone, gives the published evaluation again
    from containergym_marl.evaluation.run_policies import evaluate_run

    again = evaluate_run(shipped, protocol=EvalProtocol(episodes=2), write=False)
    assert json.loads(again.to_json()) == evaluation
