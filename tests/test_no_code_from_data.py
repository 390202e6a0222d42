"""Data never runs code: model files, checkpoints and replay buffers with a pickled payload are
loaded (or refused) without the payload running, on every load path (evaluate, resume, the shipped
policies of compare, MAPPO's actor, the native PPO's files)."""

from __future__ import annotations

import base64
import io
import json
import pickle
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from containergym_marl.cli import main as cli_main
from containergym_marl.evaluation import EvalProtocol
from containergym_marl.evaluation.run_policies import evaluate_run
from containergym_marl.training import TrainArgs, train
from containergym_marl.rundir import checkpoint_files, checkpoints
from containergym_marl.models import load_model

pytestmark = pytest.mark.filterwarnings("ignore::containergym_marl.rundir.RunWarning")
TINY = dict(n_envs=2, progress_bar=False, hyperparams={"n_steps": 64, "batch_size": 64},
            overrides={"episode_length_steps": 50})


class _Payload:
    """Unpickling it calls Path.write_text(marker, ...): code from the file runs."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (Path.write_text, (self.marker, "code from a model file ran"))


def _with_payload(path: Path, marker: Path, key: str = "_last_obs") -> None:
    """Rewrite an SB3 zip so that its ``data`` entry ``key`` is a pickled payload (cloudpickle's format)."""
    blob = base64.b64encode(pickle.dumps(_Payload(marker))).decode()
    with zipfile.ZipFile(path) as z:
        members = {name: z.read(name) for name in z.namelist()}
    data = json.loads(members["data"])
    data[key] = {":type:": "<class 'numpy.ndarray'>", ":serialized:": blob}
    members["data"] = json.dumps(data).encode()
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for name, content in members.items():
            z.writestr(name, content)
    path.write_bytes(buf.getvalue())


@pytest.fixture
def ppo_run(tmp_path):
    return train(TrainArgs(algo="ppo", out=str(tmp_path / "run"), timesteps=512, checkpoint_every=128, **TINY))


def test_the_crafted_file_runs_its_code_under_a_plain_sb3_load(ppo_run, tmp_path):
    """What the other tests guard against: SB3's own load unpickles the entry."""
    from stable_baselines3 import PPO

    marker = tmp_path / "ran.txt"
    _with_payload(ppo_run / "best_model.zip", marker)
    PPO.load(ppo_run / "best_model.zip", device="cpu")
    assert marker.exists()


@pytest.mark.parametrize("key", ["_last_obs", "policy_class", "observation_space", "lr_schedule", "some_new_entry"])
def test_evaluate_never_runs_code_from_a_model_file(ppo_run, tmp_path, key, capsys):
    marker = tmp_path / "ran.txt"
    before = evaluate_run(ppo_run, protocol=EvalProtocol(episodes=1), write=False).returns
    _with_payload(ppo_run / "best_model.zip", marker, key)
    if key != "observation_space":  # replaced by safe values: evaluates as before
        after = evaluate_run(ppo_run, protocol=EvalProtocol(episodes=1), write=False).returns
        np.testing.assert_array_equal(before, after)
    else:  # a space without its description cannot be rebuilt: refused, naming the entry
        assert cli_main(["evaluate", str(ppo_run), "--episodes", "1"]) == 2
        assert key in capsys.readouterr().err
    assert not marker.exists()


def test_resume_never_runs_code_from_a_checkpoint(ppo_run, tmp_path):
    marker = tmp_path / "ran.txt"
    newest = checkpoints(ppo_run)[0][1]
    _with_payload(newest, marker)
    (ppo_run / "final_model.zip").unlink()
    train(TrainArgs(algo="ppo", out=str(ppo_run), timesteps=640, checkpoint_every=128, resume=True, **TINY))
    assert not marker.exists()
    assert load_model(ppo_run / "final_model.zip", "ppo").num_timesteps >= 640


def test_a_replay_buffer_is_kept_as_plain_arrays_and_a_pickled_one_is_refused(tmp_path):
    dqn = dict(n_envs=1, progress_bar=False, hyperparams={"buffer_size": 2000, "learning_starts": 64},
               overrides={"episode_length_steps": 50})
    run = train(TrainArgs(algo="dqn", out=str(tmp_path / "run"), timesteps=256, checkpoint_every=64, **dqn))
    steps = checkpoints(run)[0][0]
    path = checkpoint_files(run, steps)["replay_buffer"]
    assert path.suffix == ".npz"
    with np.load(path, allow_pickle=False) as saved:
        assert int(saved["pos"]) == steps and saved["observations"].shape[0] == 2000
    marker = tmp_path / "ran.txt"
    path.write_bytes(pickle.dumps(_Payload(marker)))  # what SB3's save_replay_buffer would have written
    (run / "final_model.zip").unlink()
    with pytest.warns(UserWarning, match="replay buffer .* is unreadable"):
        train(TrainArgs(algo="dqn", out=str(run), timesteps=320, checkpoint_every=64, resume=True, **dqn))
    assert not marker.exists()


def test_a_crafted_mappo_actor_never_runs_its_code(tmp_path, capsys):
    from containergym_marl.policies.shared_actor import SharedActor

    marker = tmp_path / "ran.txt"
    path = tmp_path / "best_model.pt"
    torch.save({"format": "containergym-marl shared actor", "payload": _Payload(marker)}, path)
    with pytest.raises(ValueError, match="broken or not a saved shared actor"):
        SharedActor.load(path)
    assert not marker.exists()
