"""The saved shared actor (containergym_marl.policies.shared_actor) and the registry's ``mappo`` entry:
a MAPPO run directory is evaluated by ``containergym-marl evaluate`` with torch alone, its budget
reaches the table, and the SB3 training paths do not offer it. (Training it needs BenchMARL:
tests/clients/test_mappo.py.)"""

from __future__ import annotations

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from containergym_marl import load_config  # noqa: E402
from containergym_marl.cli import build_parser  # noqa: E402
from containergym_marl.cli import main as cli  # noqa: E402
from containergym_marl.evaluation import EvalProtocol, evaluate  # noqa: E402
from containergym_marl.evaluation import table as tables  # noqa: E402
from containergym_marl.evaluation.run_policies import policy_from_run  # noqa: E402
from containergym_marl.policies.shared_actor import SharedActor, SharedActorPolicy  # noqa: E402
from containergym_marl.training import ALGORITHMS, REGISTRY, TrainArgs, get_algorithm  # noqa: E402
from containergym_marl.rundir import RunWarning  # noqa: E402

F5 = 12 + 2 + 5  # agent observation size of n5_m2


def _actor(request_bias: float = 0.0, seed: int = 0, inputs: int = F5) -> SharedActor:
    torch.manual_seed(seed)
    actor = SharedActor([{"type": "Linear", "in": inputs, "out": 8}, {"type": "Tanh"},
                         {"type": "Linear", "in": 8, "out": 2}], meta={"algorithm": "mappo"})
    with torch.no_grad():
        actor.net[2].bias[1] += request_bias
    return actor


def test_registry_evaluates_mappo_but_sb3_does_not_train_it():
    spec = get_algorithm("mappo")
    assert "mappo" in REGISTRY and "mappo" not in ALGORITHMS and not spec.sb3
    assert spec.policy_adapter is SharedActorPolicy and spec.view == "decentralised"
    assert (spec.model_file("best"), spec.trainer_name) == ("best_model.pt", "baselines/train_mappo.py")
    assert all(REGISTRY[a].model_file("final") == ("final_model.zip" if REGISTRY[a].sb3 else "final_model.pt")
               and REGISTRY[a].trained_here for a in ALGORITHMS)
    with pytest.raises(ValueError, match="baselines/train_mappo.py"):
        spec.load_class()
    with pytest.raises(ValueError, match="not trained by containergym-marl train"):
        TrainArgs(algo="mappo").validate()
    with pytest.raises(SystemExit):  # not a choice of `train --algo`
        build_parser().parse_args(["train", "--algo", "mappo"])
    from containergym_marl.methods import COMPARABLE, METHODS

    assert "mappo" not in COMPARABLE and METHODS["mappo"].view == "decentralised"  # compare: not its trainer


def test_saved_actor_round_trip_and_broken_files(tmp_path):
    actor = _actor(seed=1)
    path = actor.save(tmp_path / "a.pt")
    loaded = SharedActor.load(path)
    x = np.random.default_rng(0).normal(size=(5, F5)).astype(np.float32)
    assert torch.equal(loaded.logits(x), actor.logits(x)) and loaded.meta == {"algorithm": "mappo"}
    assert (loaded.observation_size, loaded.n_actions) == (F5, 2)
    (tmp_path / "cut.pt").write_bytes(path.read_bytes()[:200])
    with pytest.raises(ValueError, match="broken"):
        SharedActor.load(tmp_path / "cut.pt")
    torch.save({"format": "something else"}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="not a saved shared actor"):
        SharedActor.load(tmp_path / "other.pt")
    with pytest.raises(FileNotFoundError):
        SharedActor.load(tmp_path / "absent.pt")
    with pytest.raises(ValueError, match="unknown layer"):
        SharedActor([{"type": "Linear", "in": 3, "out": 2}, {"type": "Dropout"}])


def test_masked_while_no_pu_is_free():
    """An actor that always wants to request never does while no PU is free (the env's mask)."""
    result = evaluate(SharedActorPolicy(_actor(request_bias=50.0), name="greedy"), "n5_m2_dt120",
                      EvalProtocol(episodes=1, episode_length_steps=80), keep_records=True)
    record = result.records[0]
    none_free = (record.pu_timers_s[:-1] > 0).all(axis=1)  # before each step
    assert none_free.any() and record.requested[~none_free].all()
    assert not record.requested[none_free].any()


def test_a_mappo_run_directory_is_evaluated_like_any_other(tmp_path, capsys):
    run = tmp_path / "mappo_n5_m2_dt120_s2"
    run.mkdir()
    (run / "args.json").write_text(json.dumps({"algo": "mappo", "config": "n5_m2_dt120", "seed": 2,
                                               "timesteps": 2_000_000, "arbitration": "fullest"}))
    _actor(seed=2).save(run / "final_model.pt")
    training = {"budget_plant_steps": 2_000_000, "plant_steps": 2_004_000, "agent_steps": 10_020_000,
                "samples": 10_000_000}
    (run / "run.json").write_text(json.dumps({"best_model": None, "note": "no training episode finished",
                                              "training": training}))
    with pytest.warns(RunWarning, match="no training episode finished"):
        policy = policy_from_run(run, "best")  # no best model: the final one, named so
    assert isinstance(policy, SharedActorPolicy) and policy.name == "mappo[s2,final: no training episode finished]"

    out = tmp_path / "evaluations" / "n5_m2_dt120" / "mappo_s2.json"
    assert cli(["evaluate", str(run), "--episodes", "2", "--json", str(out)]) == 0
    saved = json.loads(out.read_text())
    assert saved["view"] == "decentralised" and saved["training"] == training and len(saved["episodes"]) == 2
    assert json.loads((run / "evaluation_best.json").read_text()) == saved
    (row,) = tables.build_table(tables.load_evaluations(tmp_path / "evaluations"), (), reps=50).rows
    assert (row["method"], row["view"], row["samples"]) == ("mappo", "decentralised", 10_000_000)
    assert "| mappo | decentralised | 1 |" in tables.markdown([row], []) and "| 10M |" in tables.markdown([row], [])

    with pytest.raises(ValueError, match="observations of shape"):  # a 5-container actor on an 11-container plant
        evaluate(policy, load_config("n11_m2_dt120"), EvalProtocol(episodes=1))


def test_without_torch_the_extra_is_named(tmp_path):
    """Evaluating a MAPPO run needs torch only: without it, the error names the train extra."""
    import subprocess
    import sys

    code = ("import sys\n"
            "sys.modules['torch'] = None\n"
            "from containergym_marl.training import get_algorithm\n"  # the registry imports without torch
            "from containergym_marl.policies.shared_actor import SharedActor\n"
            "try:\n"
            f"    SharedActor.load({str(tmp_path / 'a.pt')!r})\n"
            "except ImportError as e:\n"
            "    print(type(e).__name__, e)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "MissingExtraError" in done.stdout and "containergym-marl[train]" in done.stdout
