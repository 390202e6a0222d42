"""Hostile folders and files, the memory-bound half (issue 35, rows 7-11): what a model file, checkpoint,
replay buffer, data set, config or setting declares is bounded before anything is allocated or written,
and refused with an error that names the file or setting, the field and the rule.

The probes that a crafted size could make allocate gigabytes run with at most 500 MB of address space
beyond what the test process holds (``RLIMIT_AS``, on Linux) and must finish within 10 s, so a regression
fails the test (a MemoryError, or another error than the rule's) instead of exhausting the machine.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import io
import json
import math
import pickle
import re
import resource
import tempfile
import time
import warnings
import zipfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import containergym_marl.config.bounds as bounds
from containergym_marl.algorithms import get_algorithm
from containergym_marl.cli import main as cli_main
from containergym_marl.config import ConfigError, load_config
from containergym_marl.demonstrations import agents_path, load_agent_demonstrations
from containergym_marl.envs.vector import ContainerGymVecEnv
from containergym_marl.models import load_model
from containergym_marl.policies.actor_critic import FORMAT, ActorCritic
from containergym_marl.rundir import checkpoints
from containergym_marl.training import TrainArgs, train
from containergym_marl.training import dagger, fast_ppo
from containergym_marl.training.checkpoints import load_replay_buffer, save_replay_buffer
from containergym_marl.training.train_args import memory_estimate

from tests.helpers import CFG, ROOT

HEADROOM_MB, PROBE_SECONDS = 500, 10.0
_STATUS = Path("/proc/self/status")


@contextlib.contextmanager
def bounded():
    """The block runs with at most HEADROOM_MB more address space than the process has now (an
    allocation beyond it fails at once; where /proc is missing, without that limit) and must take
    less than PROBE_SECONDS."""
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    if _STATUS.is_file():
        with _STATUS.open() as status:
            held = next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmSize:"))
        limit = held + HEADROOM_MB * 2**20
        resource.setrlimit(resource.RLIMIT_AS, (limit if hard == resource.RLIM_INFINITY else min(limit, hard), hard))
    start = time.perf_counter()
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
    assert time.perf_counter() - start < PROBE_SECONDS


def _rezip(path: Path, edit=lambda name, data: data, compression=zipfile.ZIP_STORED) -> None:
    """Rewrite the zip archive at ``path`` with ``edit(name, bytes)`` applied to every member."""
    with zipfile.ZipFile(path) as z:
        members = {name: edit(name, z.read(name)) for name in z.namelist()}
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression) as z:
        for name, data in members.items():
            z.writestr(name, data)
    path.write_bytes(buf.getvalue())


def _header(hidden) -> dict:
    """An actor-critic file's header declaring ``hidden``, without weights."""
    return {"format": FORMAT, "version": 1, "view": "centralised", "observation_size": 7, "n_actions": 6,
            "hidden": hidden, "action_mask": False, "state_dict": {}, "meta": {}}


# ==== row 7: model files and checkpoints ===========================================================
def test_a_model_header_of_huge_layers_is_refused_before_the_network_is_built(tmp_path):
    """A 1.5 kB best_model.pt whose header says hidden=[12000, 12000] (1.2 GB of weights; evaluate ran
    for over a minute at 2.6 GB)."""
    path = tmp_path / "best_model.pt"
    torch.save(_header([12000, 12000]), path)
    assert path.stat().st_size < 2000
    for load in (ActorCritic.load, lambda p: load_model(p, "fast_shared_ppo")):
        with bounded(), pytest.raises(ValueError, match=r"best_model\.pt'?: hidden=\[12000, 12000\] must list 1 to "
                                                        r"16 layer widths in \[1, 4096\]"):
            load(path)


def test_weights_that_do_not_match_the_header_are_refused_before_the_network_is_built(tmp_path):
    """A header within the bounds ([4096, 4096]: 33M parameters) but without its weights: refused
    from the header alone, without building (and initialising) the network first."""
    path = tmp_path / "best_model.pt"
    torch.save(_header([4096, 4096]), path)
    with bounded(), pytest.raises(ValueError, match=r"expected the weights \['actor\.0\.bias'"):
        ActorCritic.load(path)
    good = ActorCritic("centralised", 7, 6, hidden=(8, 8)).to_dict()
    good["state_dict"]["critic.2.weight"] = torch.zeros(8, 9)
    torch.save(good, path)
    with pytest.raises(ValueError, match=r"critic\.2\.weight must be a float tensor of shape \(8, 8\)"):
        ActorCritic.load(path)


def test_a_resume_sets_a_checkpoint_of_huge_layers_aside_and_says_why(tmp_path):
    run = train(TrainArgs(algo="fast_ppo", out=str(tmp_path / "run"), timesteps=512, n_envs=2, checkpoint_every=128,
                          hyperparams={"n_steps": 32}, overrides={"episode_length_steps": 20}, progress_bar=False))
    (steps, newest), (previous, _) = checkpoints(run)[:2]
    saved = torch.load(newest, weights_only=True)
    saved["model"]["hidden"] = [12000, 12000]
    torch.save(saved, newest)
    with bounded(), pytest.raises(ValueError, match=r"hidden=\[12000, 12000\] must list"):
        fast_ppo.load_checkpoint(newest, fast_ppo.PPOArgs(n_steps=32))
    (run / "final_model.pt").unlink()
    with bounded(), pytest.warns(UserWarning, match=r"hidden=\[12000, 12000\] must list.*set aside"):
        train(TrainArgs(algo="fast_ppo", out=str(run), timesteps=512, n_envs=2, checkpoint_every=128, resume=True,
                        hyperparams={"n_steps": 32}, overrides={"episode_length_steps": 20}, progress_bar=False))
    assert newest.with_name(newest.name + ".broken").is_file()
    assert json.loads((run / "run.json").read_text())["resumed_from"] == previous < steps


@pytest.fixture
def ppo_zip(tmp_path):
    """A saved SB3 PPO model (2 simulations of the 5-container plant: 7 inputs, 6 actions)."""
    from stable_baselines3 import PPO

    path = tmp_path / "model.zip"
    PPO("MlpPolicy", ContainerGymVecEnv(CFG, 2), n_steps=64, batch_size=64, device="cpu").save(path)
    return path


def _edit_data(path: Path, change) -> None:
    def edit(name, data):
        if name != "data":
            return data
        loaded = json.loads(data)
        change(loaded)
        return json.dumps(loaded).encode()

    _rezip(path, edit)


@pytest.mark.parametrize("change, message", [
    (lambda d: d.update(policy_kwargs={"net_arch": [30000, 30000]}), r"policy_kwargs\.net_arch must list"),
    (lambda d: d.update(policy_kwargs={"net_arch": {"pi": [30000, 30000], "vf": [64]}}),
     r"policy_kwargs\.net_arch\.pi must list"),
    (lambda d: d.update(policy_kwargs={"net_arch": [4096] * 8}), r"more than 67108864"),
    (lambda d: d.update(n_steps=10**9), r"n_steps must be an integer in \[1, 65536\]"),
    (lambda d: d.update(n_steps=65536, n_envs=4096), r"n_steps × n_envs = 268435456 samples"),
    (lambda d: d["action_space"].update(n=10**9), r"action_space: a Discrete space without a readable n"),
], ids=["net_arch", "net_arch_pi", "parameters", "n_steps", "rollout", "actions"])
def test_an_sb3_zip_declaring_huge_sizes_is_refused_before_sb3_allocates(ppo_zip, change, message):
    """policy_kwargs.net_arch=[30000, 30000] made SB3 allocate 3.6 GB; the sizes are plain JSON in
    the zip's data, checked before SB3 builds anything from them."""
    assert load_model(ppo_zip, "ppo").n_steps == 64  # the file as saved loads
    _edit_data(ppo_zip, change)
    with bounded(), pytest.raises(ValueError, match=message):
        load_model(ppo_zip, "ppo")


def test_compressed_tensor_files_and_model_zips_are_refused(tmp_path, ppo_zip):
    """torch.save and SB3 store their members uncompressed; torch and SB3 read deflated ones too, so a
    small file could unpack to gigabytes. Here a model of zero weights re-deflated (800 kB unpacked)."""
    path = tmp_path / "best_model.pt"
    model = ActorCritic("centralised", 7, 6, hidden=(256, 512))
    model.save(path)
    _rezip(path, lambda name, data: bytes(len(data)) if "/data/" in name else data, zipfile.ZIP_DEFLATED)
    with pytest.raises(ValueError, match=r"members unpack to \d+ bytes, more than the \d+ bytes of the archive"):
        ActorCritic.load(path)
    _rezip(ppo_zip, compression=zipfile.ZIP_DEFLATED)
    with pytest.raises(ValueError, match=r"model\.zip'?: its members unpack to"):
        load_model(ppo_zip, "ppo")


# ==== row 8: replay buffers ========================================================================
@pytest.fixture
def replay(tmp_path):
    """A saved replay buffer of 64 samples of the 5-container plant (6 actions), 17 of them filled,
    and a fresh buffer of the same shape to load it into."""
    from stable_baselines3.common.buffers import ReplayBuffer

    env = ContainerGymVecEnv(CFG, 1)

    def fresh():
        return SimpleNamespace(replay_buffer=ReplayBuffer(64, env.observation_space, env.action_space, n_envs=1))

    saved = fresh().replay_buffer
    rng = np.random.default_rng(0)
    saved.observations[:17] = rng.random((17, 1, 7))
    saved.actions[:17] = (np.arange(17) % 6)[:, None, None]
    saved.rewards[:17] = rng.random((17, 1))
    saved.pos = 17
    path = tmp_path / "buffer.npz"
    save_replay_buffer(SimpleNamespace(replay_buffer=saved), path)
    return path, saved, fresh


def _members(path: Path) -> dict[str, bytes]:
    with zipfile.ZipFile(path) as z:
        return {name: z.read(name) for name in z.namelist()}


def _write_members(path: Path, members: dict[str, bytes], compression=zipfile.ZIP_STORED) -> None:
    with zipfile.ZipFile(path, "w", compression) as z:
        for name, data in members.items():
            z.writestr(name, data)


def _npy(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, array)
    return buf.getvalue()


def test_a_saved_replay_buffer_loads_back_whole(replay):
    path, saved, fresh = replay
    model = fresh()
    load_replay_buffer(model, path)
    for name in ("observations", "next_observations", "actions", "rewards", "dones", "timeouts"):
        np.testing.assert_array_equal(getattr(model.replay_buffer, name), getattr(saved, name))
    assert (model.replay_buffer.pos, model.replay_buffer.full) == (17, False)


def test_a_replay_array_declaring_a_huge_shape_is_refused_before_it_is_read(replay):
    """A 1 kB member whose .npy header says (10**8, 1, 7) float32 (2.8 GB): numpy allocates what the
    header says before it reads the data, so the header is read and checked first."""
    path, _, fresh = replay
    members = _members(path)
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f4", "fortran_order": False, "shape": (10**8, 1, 7)})
    members["observations.npy"] = header.getvalue() + bytes(1000)
    _write_members(path, members)
    with bounded(), pytest.raises(ValueError, match=r"buffer\.npz'?: observations is a \(100000000, 1, 7\) float32 "
                                                    r"array; the buffer's is \(64, 1, 7\) float32"):
        load_replay_buffer(fresh(), path)


@pytest.mark.parametrize("member, array, message", [
    ("pos", np.int64(-3), r"pos=-3 lies outside the buffer \[0, 64\)"),
    ("pos", np.int64(10**9), r"pos=1000000000 lies outside the buffer \[0, 64\)"),
    ("actions", np.full((64, 1, 1), 6), r"actions must lie in \[0, 6\), got 0 to 6"),
    ("actions", np.full((64, 1, 1), -1), r"actions must lie in \[0, 6\), got -1 to 5"),
    ("observations", np.zeros((64, 1, 7)), r"observations is a \(64, 1, 7\) float64 array; the buffer's is "
                                           r"\(64, 1, 7\) float32"),
    ("rewards", np.zeros((63, 1), np.float32), r"rewards is a \(63, 1\) float32 array"),
    ("full", np.zeros(3, bool), r"full is a \(3,\) bool array; the buffer's is \(\) bool"),
], ids=["pos_negative", "pos_1e9", "action_too_large", "action_negative", "float64", "short", "full"])
def test_a_replay_buffer_that_does_not_fit_is_refused_and_leaves_the_buffer_empty(replay, member, array, message):
    path, saved, fresh = replay
    members = _members(path)
    if member == "actions":
        array = np.where(np.arange(64)[:, None, None] < 17, saved.actions, array)  # the filled part stays valid
    members[f"{member}.npy"] = _npy(array)
    _write_members(path, members)
    model = fresh()
    with pytest.raises(ValueError, match=rf"replay buffer '.*buffer\.npz': {message}"):
        load_replay_buffer(model, path)
    assert (model.replay_buffer.pos, model.replay_buffer.full) == (0, False)
    assert not model.replay_buffer.actions.any()


def test_a_replay_member_declaring_more_bytes_than_its_array_is_refused(replay):
    """Trailing data after a valid array: the member's declared size is checked before it is unpacked."""
    path, _, fresh = replay
    members = _members(path)
    members["dones.npy"] += bytes(10_000_000)
    _write_members(path, members, zipfile.ZIP_DEFLATED)
    with pytest.raises(ValueError, match=r"dones unpacks to 10000\d{3} bytes; the buffer's \(64, 1\) float32 array "
                                         r"has 256"):
        load_replay_buffer(fresh(), path)


# ==== row 9: configs ===============================================================================
@pytest.mark.parametrize("text", [
    "a." * 100_000 + "b = 1\n",
    "[" + "a." * 100_000 + "b]\nc = 1\n",
    "x = {" + "a." * 100_000 + "b = 1}\n",
], ids=["dotted_key", "table_name", "inline_table"])
def test_a_toml_key_of_100000_dotted_parts_is_refused_before_parsing(tmp_path, text):
    """200 kB of one dotted key: TOML's parser needs memory that grows with the square of its parts
    (24 GB here), and the bracket count saw no nesting at all."""
    path = tmp_path / "deep.toml"
    path.write_text(text)
    with bounded(), pytest.raises(ConfigError, match=r"deep\.toml'?: lists, tables or dotted keys nested deeper "
                                                     r"than 16 levels"):
        load_config(path)


def test_dotted_key_depth_counts_parts_outside_strings_and_comments_only(tmp_path):
    text = "".join(line for line in load_config(CFG).to_toml().splitlines(keepends=True)
                   if not line.startswith("description = "))
    path = tmp_path / "plant.toml"
    # dots in a comment and in a multi-line string that holds quotes do not count
    path.write_text('description = """a "quoted" ' + "." * 40 + ' ""\\""" done"""  # ' + "." * 40 + "\n" + text)
    assert load_config(path).description == 'a "quoted" ' + "." * 40 + ' """"" done'
    # a key of 16 parts is within the bound (refused as an unknown key); of 17 parts, refused unparsed
    path.write_text(".".join(["a"] * 16) + " = 1\n" + text)
    with pytest.raises(ConfigError, match=r"unknown") as within:
        load_config(path)
    assert "nested deeper" not in str(within.value)
    path.write_text(".".join(["a"] * 17) + " = 1\n" + text)
    with pytest.raises(ConfigError, match=r"nested deeper than 16"):
        load_config(path)
    # a deep key after a multi-line string that a plain quote count would take as still open
    path.write_text('description = """ " """\n' + "a." * 100 + "b = 1\n")
    with pytest.raises(ConfigError, match=r"nested deeper than 16"):
        load_config(path)


# ==== row 10: settings and plant sizes, before the run directory is written ========================
@pytest.mark.parametrize("algo, hp, message", [
    ("fast_ppo", {"hidden": "60000,60000"}, r"hp: hidden must list 1 to 16 layer widths in \[1, 4096\]"),
    ("fast_shared_ppo", {"n_steps": 1e8}, r"hp: n_steps must be an integer in \[1, 65536\]"),
    ("fast_ppo", {"rollout_samples": 1e9}, r"hp: rollout_samples must be an integer in \[1, 1048576\]"),
    ("fast_ppo", {"minibatch_size": 10**9}, r"hp: minibatch_size must be an integer in \[1, 1048576\]"),
    ("dagger_agents", {"dataset_size": 1e11}, r"hp: dataset_size must be an integer in \[1, 67108864\]"),
    ("dagger_agents", {"futures": 10**6}, r"hp: futures must be an integer in \[1, 1024\]"),
    ("dagger_ppo_agents", {"ppo_n_steps": 10**8}, r"hp: ppo_n_steps must be an integer"),
    ("ppo", {"n_steps": 10**8}, r"hp: n_steps must be an integer in \[1, 65536\]"),
    ("ppo", {"policy_kwargs": {"net_arch": [60000, 60000]}}, r"hp: policy_kwargs\.net_arch must list"),
    ("dqn", {"buffer_size": 10**9}, r"hp: buffer_size must be an integer in \[1, 16777216\]"),
], ids=["hidden", "n_steps", "rollout_samples", "minibatch_size", "dataset_size", "futures", "ppo_n_steps",
        "sb3_n_steps", "sb3_net_arch", "sb3_buffer_size"])
def test_settings_beyond_their_bounds_are_refused_before_anything_is_written(tmp_path, algo, hp, message):
    out = tmp_path / "run"
    with bounded(), pytest.raises(ValueError, match=message):
        train(TrainArgs(algo=algo, out=str(out), timesteps=1000, hyperparams=hp, progress_bar=False))
    assert not out.exists()


def test_the_cli_refuses_a_huge_network_naming_it_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "run"
    with bounded():
        code = cli_main(["train", "--algo", "fast_ppo", "--out", str(out), "--timesteps", "1000", "--no-progress",
                         "--hp", "hidden=60000,60000"])
    assert code == 2 and "hidden must list 1 to 16 layer widths" in capsys.readouterr().err
    assert not out.exists()


@pytest.fixture(scope="module")
def plant_1024(tmp_path_factory):
    """A valid plant of 1024 containers and 1024 PUs, the largest the config bounds allow."""
    plant = load_config(CFG)
    containers = tuple(dataclasses.replace(plant.containers[i % 5], name=f"C{i}") for i in range(1024))
    path = tmp_path_factory.mktemp("plant") / "n1024_m1024.toml"
    path.write_text(plant.replace(containers=containers, num_processing_units=1024, name="n1024_m1024").to_toml())
    return path


@pytest.mark.parametrize("algo, setting", [("dqn", "buffer_size=1000000"), ("dagger_agents", "n_steps=64")])
def test_a_valid_plant_whose_run_needs_more_than_the_machine_is_refused(tmp_path, monkeypatch, plant_1024, algo,
                                                                        setting):
    """A 1024 × 1024 plant: DQN's replay buffer of 10**6 observations of 2048 floats needs 15 GiB; DAgger's
    iterations of 64 steps of 64 simulations × 1024 agents, 65 GiB. On a machine of 4 GiB both are
    refused, naming the setting of the largest need, before anything is written."""
    monkeypatch.setattr(bounds, "machine_memory", lambda: 4 * 2**30, raising=False)
    out = tmp_path / "run"
    with bounded(), pytest.raises(ValueError, match=rf"^{setting}: the run needs about \d+\.\d GiB of memory "
                                                    rf"\(\d+\.\d GiB for {setting}\), more than this machine's 4\.0 GiB"):
        train(TrainArgs(algo=algo, config=str(plant_1024), out=str(out), timesteps=1000, progress_bar=False))
    assert not out.exists()
    plant = load_config(plant_1024)
    assert sum(memory_estimate(TrainArgs(algo="fast_shared_ppo"), plant, 1).values()) < 4 * 2**30  # this one fits


def test_every_bound_is_named_in_the_one_table():
    """Each MAX_/MIN_ constant of the bounds module appears in its docstring's tables (as itself or
    in a MIN/MAX_ pair), the one place the bounds are documented."""
    names = [name for name in vars(bounds) if re.fullmatch(r"(MAX|MIN)_[A-Z_]+", name)]
    assert {"MAX_HIDDEN_WIDTH", "MAX_DATASET_SIZE", "MAX_REPLAY_BUFFER", "MAX_CONFIG_DEPTH"} <= set(names)
    undocumented = [name for name in names if name not in bounds.__doc__ and f"MIN/MAX_{name[4:]}" not in bounds.__doc__]
    assert not undocumented


def test_the_memory_estimate_counts_what_the_buffers_allocate():
    """The replay buffer's and the DAgger data set's entries are the bytes SB3's buffer and the data
    set actually hold."""
    from stable_baselines3 import DQN

    plant = load_config(CFG)
    env = ContainerGymVecEnv(plant, 1)
    buffer = DQN("MlpPolicy", env, buffer_size=5000, device="cpu").replay_buffer
    held = sum(getattr(buffer, name).nbytes for name in ("observations", "next_observations", "actions", "rewards",
                                                         "dones", "timeouts"))
    args = TrainArgs(algo="dqn", hyperparams={"buffer_size": 5000})
    assert memory_estimate(args, plant, 1)["buffer_size=5000"] == held
    data = dagger.Dataset(5000, 12 + plant.num_processing_units + plant.n_containers)
    args = TrainArgs(algo="dagger_agents", hyperparams={"dataset_size": 5000})
    assert memory_estimate(args, plant, 64)["dataset_size=5000"] == data.obs.nbytes + data.labels.nbytes + data.contended.nbytes


def test_the_package_s_own_searches_stay_well_within_the_bounds():
    """The native PPO search's largest shape and DAgger's largest data set, on the 16-container plant:
    accepted, and estimated below 2 GiB."""
    plant = load_config("n16_m2_dt120")
    ppo = {"rollout_samples": 16384, "n_steps": 256, "minibatch_size": 2048, "n_epochs": 20}
    imitation = {"dataset_size": 6_000_000, "hidden": "128,128", "futures": 32}
    for algo, hp in (("fast_shared_ppo", ppo), ("fast_ppo", ppo), ("dagger_ppo_agents", imitation)):
        args = TrainArgs(algo=algo, config="n16_m2_dt120", hyperparams=hp)
        args.validate()
        sims = get_algorithm(algo).default_sims(16, hp)
        assert sum(memory_estimate(args, plant, sims).values()) < 2 * 2**30


# ==== row 11: DAgger data sets ======================================================================
def _dataset(**change) -> dict:
    data = {"format": dagger.DATASET_FORMAT, "version": 1, "obs": torch.zeros(10, 4),
            "labels": torch.tensor([0, 1] * 5, dtype=torch.uint8), "next": 10}
    return {**data, **change}


@pytest.mark.parametrize("data, message", [
    (_dataset(labels=torch.zeros(10, 1, dtype=torch.uint8)), r"labels are \(torch\.uint8, \(10, 1\)\), expected "
                                                             r"integers \(10,\)"),
    (_dataset(labels=torch.tensor([0, 2] * 5, dtype=torch.uint8)), r"labels must be 0 or 1 \(the two actions\), got "
                                                                   r"0 to 2"),
    (_dataset(labels=torch.tensor([0, -1] * 5)), r"labels must be 0 or 1 \(the two actions\), got -1 to 0"),
    (_dataset(labels=torch.zeros(10)), r"labels are \(torch\.float32"),
    (_dataset(obs=torch.zeros(10, 4, dtype=torch.float64)), r"observations are \(torch\.float64, \(10, 4\)\)"),
    (_dataset(obs=torch.full((10, 4), math.nan)), r"observations are not all finite"),
    (_dataset(next=11), r"next slot must be an integer in \[0, 10\], got 11"),
    (_dataset(next="3"), r"next slot must be an integer in \[0, 10\], got '3'"),
], ids=["labels_2d", "label_2", "label_negative", "labels_float", "obs_float64", "obs_nan", "next_11", "next_str"])
def test_a_data_set_that_does_not_fit_is_refused_naming_it(data, message):
    dataset = dagger.Dataset(100, 4)
    with pytest.raises(ValueError, match=rf"^data set 'x\.pt': its {message}"):
        dataset.load(data, "data set 'x.pt'")
    assert dataset.size == 0


def test_a_resume_with_a_bad_data_set_continues_with_an_empty_one(tmp_path):
    """What used to raise on every resume (a RuntimeError copying 2-D labels, an IndexError in the
    first update for a label of 7): the checkpoint is resumed, without the data set, and says why."""
    hp = dagger.DAggerArgs(n_steps=16, minibatch_size=64)
    run = train(TrainArgs(algo="dagger_agents", out=str(tmp_path / "run"), timesteps=640, n_envs=2,
                          checkpoint_every=160, hyperparams={"n_steps": 16, "minibatch_size": 64},
                          overrides={"episode_length_steps": 20}, progress_bar=False))
    steps, path = checkpoints(run)[0]
    saved = dagger.dataset_file(run, steps)
    for labels, message in ((torch.zeros(steps, 1, dtype=torch.uint8), r"labels are"),
                            (torch.full((steps,), 7, dtype=torch.uint8), r"labels must be 0 or 1")):
        torch.save(_dataset(obs=torch.zeros(steps, 19), labels=labels, next=0), saved)  # F = 12 + m + n
        with pytest.warns(UserWarning, match=rf"data set .*{message}.*DAgger continues with an empty one"):
            state = dagger.load_checkpoint(path, hp)
        assert state.num_timesteps == steps and state.dataset.size == 0


# ==== fuzz: random and mutated files raise the package's errors, never run code ======================
# the fixtures that the fuzz tests take are read, never changed, by their examples
FUZZ = settings(max_examples=60, deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


def _mutations(seed_files: list[bytes]):
    """A seed file with bytes replaced, inserted or cut, or random bytes."""
    def mutate(args):
        data, edits = args
        data = bytearray(data)
        for position, kind, value in edits:
            i = position % (len(data) + 1)
            if kind == 0:
                data[i:i + len(value)] = value
            elif kind == 1:
                data[i:i] = value
            else:
                del data[i:i + len(value)]
        return bytes(data)

    edit = st.tuples(st.integers(0, 2**20), st.integers(0, 2), st.binary(min_size=1, max_size=16))
    return st.one_of(st.binary(max_size=4096),
                     st.tuples(st.sampled_from(seed_files), st.lists(edit, min_size=1, max_size=4)).map(mutate))


def _refused_or_loaded(load, path: Path, data: bytes, errors=(ValueError,)) -> None:
    path.write_bytes(data)
    with bounded(), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            load(path)
        except errors:
            pass


_CONFIG_SEEDS = [load_config(CFG).to_toml().encode(), json.dumps({"name": "p", "containers": []}).encode(),
                 ("a." * 20 + "b = 1\n").encode()]


@FUZZ
@given(data=_mutations(_CONFIG_SEEDS), suffix=st.sampled_from([".toml", ".json"]))
def test_the_config_loader_refuses_random_and_mutated_files_with_config_errors(data, suffix):
    with tempfile.TemporaryDirectory() as folder:
        _refused_or_loaded(load_config, Path(folder) / f"plant{suffix}", data, ConfigError)


class _Payload:
    """Unpickling it writes a marker file: code from the file ran."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (Path.write_text, (self.marker, "code from a file ran"))


@pytest.fixture(scope="module")
def tensor_seeds(tmp_path_factory):
    """A model file, a native PPO checkpoint and a DAgger data set as saved, and a pickled payload."""
    folder = tmp_path_factory.mktemp("seeds")
    model = ActorCritic("centralised", 7, 6, hidden=(8, 8))
    state = fast_ppo.TrainingState(model, fast_ppo._optimizer(model, fast_ppo.PPOArgs()), torch.Generator())
    buf = io.BytesIO()
    state.save(buf)
    files = [buf.getvalue()]
    for data in (model.to_dict(), _dataset(obs=torch.zeros(10, 17)), {"payload": _Payload(folder / "ran.txt")}):
        buf = io.BytesIO()
        torch.save(data, buf)
        files.append(buf.getvalue())
    return files, folder / "ran.txt"


@FUZZ
@given(data=st.data())
def test_tensor_file_loaders_refuse_random_and_mutated_files_with_value_errors(tensor_seeds, data):
    seeds, marker = tensor_seeds
    content = data.draw(_mutations(seeds))
    hp = dagger.DAggerArgs(dataset_size=100)
    loaders = [ActorCritic.load, lambda p: fast_ppo.load_checkpoint(p, fast_ppo.PPOArgs()),
               lambda p: dagger.Dataset(100, 17).load(dagger.load_tensors(p), "data set"),
               lambda p: dagger.load_checkpoint(p, hp)]
    with tempfile.TemporaryDirectory() as folder:
        _refused_or_loaded(data.draw(st.sampled_from(loaders)), Path(folder) / "file.pt", content)
    assert not marker.exists()


_ANY_VALUE = st.one_of(
    st.none(), st.booleans(), st.integers(-2**70, 2**70), st.floats(), st.text(max_size=8),
    st.lists(st.integers(-2**40, 2**40), max_size=20),
    st.tuples(st.lists(st.integers(0, 5), max_size=3), st.sampled_from([torch.float32, torch.float64, torch.int64,
                                                                          torch.uint8, torch.bool]))
    .map(lambda shape_dtype: torch.zeros(shape_dtype[0], dtype=shape_dtype[1])),
    st.dictionaries(st.text(max_size=8), st.integers(), max_size=3))


@FUZZ
@given(data=st.data())
def test_model_and_data_set_fields_of_any_value_are_refused_with_value_errors(data):
    """A saved model or DAgger data set with one field, or one of its weights, replaced by any value."""
    model = ActorCritic("decentralised", 17, 2, hidden=(8, 8)).to_dict()
    files = {"model": model, "data set": _dataset(obs=torch.zeros(10, 17))}
    which = data.draw(st.sampled_from(sorted(files)))
    saved = files[which]
    inner = saved["state_dict"] if which == "model" and data.draw(st.booleans()) else saved
    inner[data.draw(st.sampled_from(sorted(inner)))] = data.draw(_ANY_VALUE)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "file.pt"
        torch.save(saved, path)
        load = ActorCritic.load if which == "model" else \
            (lambda p: dagger.Dataset(100, 17).load(dagger.load_tensors(p), "data set"))
        _refused_or_loaded(load, path, path.read_bytes())


@FUZZ
@given(data=st.data())
def test_the_sb3_loader_refuses_random_and_mutated_files_and_data_with_value_errors(ppo_zip, data):
    """Mutated bytes of the zip, and its data (JSON) with one entry replaced by any JSON value."""
    seed = ppo_zip.read_bytes()
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "model.zip"
        if data.draw(st.booleans()):
            _refused_or_loaded(lambda p: load_model(p, "ppo"), path, data.draw(_mutations([seed])))
            return
        path.write_bytes(seed)
        entries = json.loads(_members(path)["data"])
        key = data.draw(st.sampled_from(sorted(entries)))
        json_values = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False)
                                   | st.text(max_size=20), lambda inner: st.lists(inner, max_size=4)
                                   | st.dictionaries(st.text(max_size=8), inner, max_size=4), max_leaves=10)
        value = data.draw(json_values)
        if isinstance(entries[key], dict) and entries[key] and data.draw(st.booleans()):  # one field of an entry
            field = data.draw(st.sampled_from(sorted(entries[key])))
            _edit_data(path, lambda d: d[key].update({field: value}))
        else:
            _edit_data(path, lambda d: d.update({key: value}))
        _refused_or_loaded(lambda p: load_model(p, "ppo"), path, path.read_bytes())


@FUZZ
@given(data=st.data())
def test_the_replay_buffer_loader_refuses_random_and_mutated_files_with_value_errors(replay, data):
    path, _, fresh = replay
    seed = path.read_bytes()
    payload = pickle.dumps(_Payload(path.parent / "ran.txt"))
    with tempfile.TemporaryDirectory() as folder:
        _refused_or_loaded(lambda p: load_replay_buffer(fresh(), p), Path(folder) / "buffer.npz",
                           data.draw(_mutations([seed, payload])))
    assert not (path.parent / "ran.txt").exists()


@functools.cache
def _agent_demonstrations() -> tuple[bytes, ...]:
    """The shipped container agents' dataset cut to one episode of its first 6 steps, compressed (as
    the package writes it) and not."""
    with np.load(agents_path(ROOT / "results" / "datasets", CFG, "planner"), allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    steps = 6
    for name in ("observations", "actions", "labels", "rewards", "plant_rewards", "terminations", "truncations"):
        arrays[name] = arrays[name][:steps]
    arrays.update(final_observations=arrays["final_observations"][:1], episode_starts=np.zeros(1, np.int64),
                  episode_lengths=np.full(1, steps, np.int64), seeds=arrays["seeds"][:1])
    files = []
    for save in (np.savez_compressed, np.savez):
        buffer = io.BytesIO()
        save(buffer, **arrays)
        files.append(buffer.getvalue())
    return tuple(files)


def test_the_cut_demonstrations_load(tmp_path):
    for data in _agent_demonstrations():
        (tmp_path / "d.npz").write_bytes(data)
        assert load_agent_demonstrations(tmp_path / "d.npz").observations.shape == (6, 5, 19)


@FUZZ
@given(data=st.data())
def test_the_demonstrations_loader_refuses_random_and_mutated_files_with_value_errors(data):
    payload = pickle.dumps(_Payload(Path(tempfile.gettempdir()) / "ran-demonstrations.txt"))
    with tempfile.TemporaryDirectory() as folder:
        _refused_or_loaded(load_agent_demonstrations, Path(folder) / "d.npz",
                           data.draw(_mutations([*_agent_demonstrations(), payload])))
    assert not (Path(tempfile.gettempdir()) / "ran-demonstrations.txt").exists()
