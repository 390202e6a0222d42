"""The demonstration datasets (``containergym-marl demonstrations``): what the shipped one holds is what
the planner did (its actions replay in fresh environments to the same observations and rewards, and
an evaluation of the planner on the same seeds plays the same episodes), the container agents' labels
are planner_agents' decisions, DAgger's data set takes them, every file matches the manifest; a build
reuses finished datasets, recovers from an interrupted one, writes nothing outside its folder and
refuses bad input before writing anything."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from containergym_marl import container_agents_v1
from containergym_marl.cli import main
from containergym_marl.core.params import PlantParams
from containergym_marl.demonstrations import (
    AGENT_FIELDS,
    DemonstrationsArgs,
    POLICIES,
    DemonstrationsError,
    agents_path,
    build,
    load_agent_demonstrations,
    minari_root,
)
from containergym_marl.evaluation import EvalProtocol, evaluate
from containergym_marl.evaluation.protocol import DEMONSTRATIONS, FRESH, PAPER, SELECTION
from containergym_marl.manifest import MANIFEST, ManifestError, check_file, covered, read_manifest
from containergym_marl.policies import RuleBasedAgents
from containergym_marl.policies.planner import PlannerAgents, RolloutPlanner
from tests.helpers import CFG, ROOT

SHIPPED = ROOT / "results" / "datasets"
SHIPPED_ID = "containergym_marl/n5_m2_dt120/planner-v0"
SHIPPED_EPISODES = 10


def _minari():
    return pytest.importorskip("minari", reason="the offline extra is not installed (pip install -e '.[offline]')")


@pytest.fixture
def shipped(monkeypatch):
    minari = _minari()
    monkeypatch.delenv("MINARI_DATASETS_PATH", raising=False)
    with minari_root(SHIPPED / "minari"):
        yield minari.load_dataset(SHIPPED_ID)
    assert "MINARI_DATASETS_PATH" not in os.environ  # restored


def _seeds(dataset) -> list[int]:
    return [int(m["seed"]) for m in dataset.storage.get_episode_metadata(range(dataset.total_episodes))]


# ---- the shipped datasets ---------------------------------------------------------------------------------
def test_the_demonstration_seeds_serve_nothing_else():
    seeds = set(DEMONSTRATIONS.seeds)
    assert DEMONSTRATIONS.first_seed == 40_000 and len(seeds) == 100
    for other in (PAPER, SELECTION, FRESH):
        assert max(other.seeds) < DEMONSTRATIONS.first_seed and not seeds & set(other.seeds)
    assert (DEMONSTRATIONS.timestep_s, DEMONSTRATIONS.episode_length_steps) == (120.0, 600)  # the test plant


def test_the_demonstrated_policies_are_the_rule_and_the_planner_with_their_container_agents():
    assert POLICIES == {"rule_based": "rule_based_agents", "planner": "planner_agents"}


def test_the_shipped_minari_dataset_holds_its_episodes_and_metadata(shipped):
    assert shipped.total_episodes == SHIPPED_EPISODES
    assert _seeds(shipped) == list(range(40_000, 40_000 + SHIPPED_EPISODES))
    meta = shipped.storage.metadata
    assert meta["algorithm_name"] == "planner" and meta["author"] == {"The containergym-marl contributors"}
    assert "containergym_marl/demonstrations.py" in meta["code_permalink"] and "n5_m2_dt120" in meta["description"]
    assert shipped.spec.env_spec.id == "containergym_marl/ContainerGym-v0"
    assert shipped.spec.env_spec.kwargs == {"config": CFG, "timestep_s": 120.0, "episode_length_steps": 600}
    assert meta["containergym_marl"]["seeds"] == _seeds(shipped)
    env = shipped.recover_environment()
    assert shipped.observation_space == env.observation_space and shipped.action_space == env.action_space
    total = 0
    for episode in shipped.iterate_episodes():
        steps = len(episode)
        assert episode.observations.dtype == np.float32 and episode.observations.shape == (steps + 1, 7)
        assert episode.actions.shape == episode.rewards.shape == (steps,)
        assert (episode.actions.dtype, episode.rewards.dtype) == (np.int64, np.float64)  # docs/demonstrations.md
        assert episode.terminations.dtype == episode.truncations.dtype == np.bool_
        assert episode.terminations[-1] or episode.truncations[-1]
        assert not (episode.terminations[:-1].any() or episode.truncations[:-1].any())
        total += steps
    assert total == shipped.total_steps


def test_the_shipped_episodes_replay_to_the_same_observations_and_rewards(shipped):
    """Each episode's actions, stepped in the environment the dataset names from the episode's seed,
    give back every stored observation, reward and ending: the data is what happened in the plant."""
    env = shipped.recover_environment()
    for seed, episode in zip(_seeds(shipped), shipped.iterate_episodes()):
        obs, _ = env.reset(seed=seed)
        observations, rewards, terminations, truncations = [obs], [], [], []
        for action in episode.actions:
            obs, reward, terminated, truncated, _ = env.step(int(action))
            observations.append(obs)
            rewards.append(reward)
            terminations.append(terminated)
            truncations.append(truncated)
        np.testing.assert_array_equal(np.array(observations), episode.observations)
        np.testing.assert_array_equal(np.array(rewards), episode.rewards)
        np.testing.assert_array_equal(terminations, episode.terminations)
        np.testing.assert_array_equal(truncations, episode.truncations)


def test_the_shipped_episodes_are_those_an_evaluation_of_the_planner_plays(shipped):
    """The planner evaluated on the first two demonstration seeds (as evaluate seeds it) empties the
    same containers at the same steps and scores the same returns as the dataset's episodes."""
    protocol = EvalProtocol(episodes=2, first_seed=DEMONSTRATIONS.first_seed)
    result = evaluate(RolloutPlanner(), CFG, protocol)
    for record, episode in zip(result.records, shipped.iterate_episodes(range(2))):
        emptied = np.where(record.requested.any(axis=1), record.requested.argmax(axis=1) + 1, 0)
        np.testing.assert_array_equal(emptied, episode.actions)
        assert record.cumulative_reward == pytest.approx(episode.rewards.sum(), abs=1e-9)


def test_the_shipped_container_agents_dataset_is_planner_agents_episodes():
    data = load_agent_demonstrations(agents_path(SHIPPED, CFG, "planner"))
    n, features = 5, 12 + 2 + 5
    steps = int(data.episode_lengths.sum())
    assert data.episodes == SHIPPED_EPISODES and list(data.seeds) == list(range(40_000, 40_000 + SHIPPED_EPISODES))
    assert data.observations.shape == (steps, n, features) and data.final_observations.shape == (10, n, features)
    for name, (dtype, _) in AGENT_FIELDS.items():
        if name != "metadata":
            assert getattr(data, name).dtype == np.dtype(dtype), name
    assert data.metadata["policy"] == data.metadata["labeller"] == "planner_agents"
    np.testing.assert_array_equal(data.labels, data.actions)  # where the planner acts, its decisions are the labels
    assert 0 < data.actions.mean() < 0.1  # requests are rare
    # planner_agents evaluated (container_agents_v0, as every evaluation) on the first two seeds requests the same
    result = evaluate(PlannerAgents(), CFG, EvalProtocol(episodes=2, first_seed=DEMONSTRATIONS.first_seed))
    for index, record in enumerate(result.records):
        episode = data.episode(index)
        np.testing.assert_array_equal(record.requested.astype(np.uint8), episode["actions"])
        assert record.cumulative_reward == pytest.approx(episode["plant_rewards"].sum(), abs=1e-9)


def _replay_agents(data, index: int, config: str = CFG, policy=None):
    """Episode ``index`` of a container agents' dataset replayed in container_agents_v1 from its seed:
    every observation, reward and ending checked; with ``policy`` (and a fresh PlannerAgents), what
    each decides in every state checked against the actions and the labels."""
    episode = data.episode(index)
    seed = int(data.seeds[index])
    env = container_agents_v1.parallel_env(config, protocol="paper_test", reward_mode="individual")
    agents = env.possible_agents
    labeller = PlannerAgents()
    labeller.reset(seed=seed)
    observations, _ = env.reset(seed=seed)
    for t, actions in enumerate(episode["actions"]):
        np.testing.assert_array_equal(np.stack([observations[a] for a in agents]), episode["observations"][t])
        if policy is not None:
            decided = policy.act(observations, env)
            assert [decided[a] for a in agents] == episode["actions"][t].tolist()
            labels = labeller.decide(env.simulator.state, env.simulator.params)
            assert labels.astype(np.uint8).tolist() == episode["labels"][t].tolist()
        observations, rewards, terminations, truncations, infos = env.step(
            {a: int(actions[i]) for i, a in enumerate(agents)})
        assert [rewards[a] for a in agents] == episode["rewards"][t].tolist()
        assert infos[agents[0]]["plant_reward"] == episode["plant_rewards"][t]
        assert (terminations[agents[0]], truncations[agents[0]]) == (episode["terminations"][t],
                                                                     episode["truncations"][t])
    assert not env.agents
    np.testing.assert_array_equal(np.stack([observations[a] for a in agents]), episode["final_observation"])


def test_the_shipped_container_agents_episodes_replay():
    data = load_agent_demonstrations(agents_path(SHIPPED, CFG, "planner"))
    for index in range(data.episodes):
        _replay_agents(data, index)


def test_dagger_takes_the_container_agents_demonstrations():
    """Every agent step is one (observation, label) sample of DAgger's data set, and the observations
    are those DAgger's own environment (ContainerAgentsVecEnv) shows on the same seed."""
    torch = pytest.importorskip("torch", reason="the train extra is not installed")
    pytest.importorskip("stable_baselines3", reason="the train extra is not installed")
    from containergym_marl.envs.vector import ContainerAgentsVecEnv
    from containergym_marl.training.dagger import Dataset, update, DAggerArgs
    from containergym_marl.policies.actor_critic import ActorCritic

    data = load_agent_demonstrations(agents_path(SHIPPED, CFG, "planner"))
    obs, labels = data.dagger_samples()
    env = ContainerAgentsVecEnv(CFG, 1, protocol="paper_test")
    features = env.observation_space.shape[0]
    dataset = Dataset(len(labels) + 10, features)
    dataset.add(obs, labels)
    assert dataset.size == data.labels.size == len(obs)
    assert torch.equal(dataset.obs[:dataset.size], torch.from_numpy(data.observations.reshape(-1, features)))
    assert dataset.labels[:dataset.size].tolist() == data.labels.reshape(-1).tolist()
    # the first episode, through DAgger's vectorised environment
    first = data.episode(0)
    env.seed(int(data.seeds[0]))
    seen = env.reset()
    for t, actions in enumerate(first["actions"][:-1]):
        np.testing.assert_array_equal(seen, first["observations"][t])
        seen, *_ = env.step(actions.astype(np.int64))
    # and a DAgger update trains on it
    generator = torch.Generator().manual_seed(0)
    model = ActorCritic("decentralised", features, 2, generator=generator)
    optimizer = torch.optim.Adam(model.net.parameters(), lr=1e-2)
    before = torch.nn.functional.cross_entropy(model.logits(obs), labels.long()).item()
    update(model, optimizer, DAggerArgs(minibatch_size=512, n_epochs=4), generator, dataset, obs[:512],
           torch.zeros(512))  # 4 Adam steps on minibatches of the whole data set
    assert torch.nn.functional.cross_entropy(model.logits(obs), labels.long()).item() < before


def test_the_shipped_files_match_their_manifest_and_stay_small():
    manifest = read_manifest(SHIPPED)
    on_disk = {p.relative_to(SHIPPED).as_posix() for p in covered(SHIPPED, ("minari", "agents"))}
    assert set(manifest) == on_disk and len(on_disk) == 5
    for name in manifest:
        check_file(SHIPPED, name, manifest)
    assert sum((SHIPPED / name).stat().st_size for name in on_disk) < 1_000_000  # docs/demonstrations.md: under 1 MB
    assert not (SHIPPED / ".partial").exists()


def test_a_container_agents_file_never_runs_code_and_is_checked_field_by_field(tmp_path):
    source = agents_path(SHIPPED, CFG, "planner")
    with np.load(source, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    bad = tmp_path / "bad.npz"
    np.savez(bad, **{**arrays, "labels": arrays["labels"] * 2})
    with pytest.raises(ValueError, match="labels must be 0 or 1"):
        load_agent_demonstrations(bad)
    np.savez(bad, **{**arrays, "observations": arrays["observations"].astype(np.float64)})
    with pytest.raises(ValueError, match="observations is float64, expected float32"):
        load_agent_demonstrations(bad)
    np.savez(bad, **{**arrays, "episode_lengths": arrays["episode_lengths"] + 1})
    with pytest.raises(ValueError, match="episode_starts and episode_lengths"):
        load_agent_demonstrations(bad)
    np.savez(bad, **{**arrays, "metadata": np.array([{"format": "x"}], dtype=object)})
    with pytest.raises(ValueError, match="pickle"):  # an object array is never unpickled
        load_agent_demonstrations(bad)


# ---- building --------------------------------------------------------------------------------------------
def _args(out: Path, **kwargs) -> DemonstrationsArgs:
    return DemonstrationsArgs(**{"configs": [CFG], "policies": ["rule_based"], "episodes": 2, "out": str(out),
                                 **kwargs})


def _stops_after_first_episode(real):
    def build_one(out, target, protocol, on_episode):
        def stop(episode):
            on_episode(episode)
            raise KeyboardInterrupt

        return real(out, target, protocol, stop)

    return build_one


def test_a_build_resumes_after_an_interruption_and_reuses_what_is_finished(tmp_path, monkeypatch):
    """rule_based on n5_m2_dt120, 2 episodes: an interruption in the first episode of each dataset
    leaves no dataset that looks finished; the next build cleans up, keeps the finished ones and
    builds the rest; the rule-based agents' labels are planner_agents' decisions in their states."""
    from containergym_marl import demonstrations

    minari = _minari()
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))  # Minari's default folder would be ~/.minari
    monkeypatch.delenv("MINARI_DATASETS_PATH", raising=False)
    out = tmp_path / "out"
    lines = []
    centralised = out / "minari" / "containergym_marl" / CFG / "rule_based-v0"
    agents = agents_path(out, CFG, "rule_based")

    # interrupted in the centralised dataset: a half-written collector in .partial, nothing finished
    with monkeypatch.context() as patch:
        patch.setattr(demonstrations, "_build_centralised",
                      _stops_after_first_episode(demonstrations._build_centralised))
        with pytest.raises(KeyboardInterrupt):
            build(_args(out), report=lines.append, show_progress=False)
    assert (out / ".partial").is_dir() and not centralised.exists() and not agents.exists()

    # interrupted in the agents' dataset: the centralised one is finished and listed, the other absent
    with monkeypatch.context() as patch:
        patch.setattr(demonstrations, "_build_agents", _stops_after_first_episode(demonstrations._build_agents))
        with pytest.raises(KeyboardInterrupt):
            build(_args(out), report=lines.append, show_progress=False)
    assert centralised.is_dir() and not agents.exists() and not (out / ".partial").exists()
    assert sorted(read_manifest(out)) == sorted(p.relative_to(out).as_posix() for p in (out / "minari").rglob("*")
                                                if p.is_file())
    finished_at = (centralised / "data" / "main_data.hdf5").stat().st_mtime_ns
    (out / "agents" / CFG).mkdir(parents=True)
    (out / "agents" / CFG / ".rule_based_agents.npz.x1y2.tmp").write_bytes(b"cut short")  # atomic writes cut short
    (out / f".{MANIFEST}.z9.tmp").write_bytes(b"cut short")

    lines.clear()
    built = build(_args(out), report=lines.append, show_progress=False)
    assert [(b.target.view, b.built) for b in built] == [("centralised", False), ("agents", True)]
    assert lines[0] == f"containergym_marl/{CFG}/rule_based-v0: reused (2 episodes)"
    assert (centralised / "data" / "main_data.hdf5").stat().st_mtime_ns == finished_at
    assert sorted(p.name for p in out.iterdir()) == [".lock", MANIFEST, "agents", "minari"]
    assert sorted(p.name for p in (out / "agents" / CFG).iterdir()) == ["rule_based_agents.npz"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # nothing outside the output folder, no ~/.minari
    assert "MINARI_DATASETS_PATH" not in os.environ
    manifest = read_manifest(out)
    assert len(manifest) == 5
    for name in manifest:
        check_file(out, name, manifest)

    with minari_root(out / "minari"):
        dataset = minari.load_dataset(f"containergym_marl/{CFG}/rule_based-v0")
        assert dataset.total_episodes == 2 and _seeds(dataset) == [40_000, 40_001]
        assert dataset.storage.metadata["algorithm_name"] == "rule_based"
    data = load_agent_demonstrations(agents)
    assert data.episodes == 2 and data.metadata["policy"] == "rule_based_agents"
    assert data.metadata["labeller"] == "planner_agents"
    assert not np.array_equal(data.actions, data.labels)  # the rule and the planner disagree somewhere
    params = PlantParams.from_config(container_agents_v1.parallel_env(CFG).config)
    _replay_agents(data, 1, policy=RuleBasedAgents(params))


@pytest.fixture(scope="module")
def small_build(tmp_path_factory):
    """rule_based on n5_m2_dt120, 1 episode."""
    _minari()
    out = tmp_path_factory.mktemp("demonstrations") / "out"
    build(_args(out, episodes=1), report=lambda line: None, show_progress=False)
    return out


def test_a_dataset_of_other_episodes_is_refused_naming_it(small_build):
    before = (small_build / MANIFEST).read_bytes()
    with pytest.raises(DemonstrationsError, match=r"rule_based-v0: holds 1 episodes .* not the 3 asked for"):
        build(_args(small_build, episodes=3), report=lambda line: None, show_progress=False)
    assert (small_build / MANIFEST).read_bytes() == before and not (small_build / ".partial").exists()


def test_a_changed_dataset_file_is_refused_naming_it(small_build, tmp_path):
    import shutil

    out = tmp_path / "out"
    shutil.copytree(small_build, out)
    path = agents_path(out, CFG, "rule_based")
    data = bytearray(path.read_bytes())
    data[-40] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(ManifestError, match="rule_based_agents.npz: its sha256 differs"):
        build(_args(out, episodes=1), report=lambda line: None, show_progress=False)


@pytest.mark.parametrize("argv, named", [
    (["--configs", "n7_m2_dt120"], "n7_m2_dt120"),
    (["--policies", "dqn"], "dqn"),
    (["--episodes", "0"], "0"),
    (["--episodes", "-3"], "-3"),
])
def test_bad_options_are_refused_by_the_command_before_anything_is_written(tmp_path, capsys, argv, named):
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:
        main(["demonstrations", "--out", str(out), *argv])
    assert exc.value.code == 2 and named in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("field, value, named", [
    ("configs", ["n5_m2_dt120", "nope"], "--configs: unknown config 'nope'"),
    ("policies", ["planner_agents"], "--policies: unknown policy 'planner_agents'"),
    ("episodes", 0, "--episodes: expected a positive integer, got 0"),
    ("episodes", True, "--episodes: expected a positive integer, got True"),
])
def test_bad_values_are_refused_before_anything_is_written(tmp_path, field, value, named):
    out = tmp_path / "out"
    with pytest.raises(ValueError, match=named):
        build(_args(out, **{field: value}), report=lambda line: None, show_progress=False)
    assert not out.exists()


def test_an_output_path_that_is_a_file_is_refused(tmp_path, capsys):
    (tmp_path / "file").write_text("mine")
    for out in (tmp_path / "file", tmp_path / "file" / "below"):
        assert main(["demonstrations", "--configs", CFG, "--policies", "rule_based", "--episodes", "1",
                     "--out", str(out)]) == 2
        assert f"--out: {str(tmp_path / 'file')!r} is a file" in capsys.readouterr().err
    assert (tmp_path / "file").read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_the_command_builds_and_then_reuses(small_build, tmp_path, capsys):
    import shutil

    out = tmp_path / "out"
    shutil.copytree(small_build, out)
    assert main(["demonstrations", "--configs", CFG, "--policies", "rule_based", "--episodes", "1",
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[:2] == [f"containergym_marl/{CFG}/rule_based-v0: reused (1 episodes)",
                           f"agents/{CFG}/rule_based_agents.npz: reused (1 episodes)"]
    assert str(out / MANIFEST) in printed[2]


def test_the_package_imports_without_minari_and_the_command_names_the_offline_extra(tmp_path):
    """Importing the package and its command line loads no Minari, jax or h5py; without Minari the
    command fails naming the extra, before anything is written."""
    code = textwrap.dedent(f"""
        import sys
        import containergym_marl, containergym_marl.demonstrations
        from containergym_marl.cli import main
        print(sorted(m for m in ("minari", "jax", "h5py") if m in sys.modules))
        sys.modules["minari"] = None  # makes `import minari` fail
        sys.exit(main(["demonstrations", "--configs", "{CFG}", "--episodes", "1", "--out", {str(tmp_path / "out")!r}]))
    """)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stdout == "[]\n"
    assert "pip install 'containergym-marl[offline]'" in proc.stderr and "minari" in proc.stderr
    assert not (tmp_path / "out").exists()


# ---- the documentation ------------------------------------------------------------------------------------
PAGE = ROOT / "docs" / "demonstrations.md"


def test_the_page_lists_every_field_of_the_container_agents_layout():
    rows = {m.group(1): (m.group(2), m.group(3)) for m in
            re.finditer(r"^\| `(\w+)` \| (\w+) \| \(([^)]*)\) \|", PAGE.read_text(), flags=re.M)}
    for name, (dtype, shape) in AGENT_FIELDS.items():
        assert name in rows, name
        assert rows[name][0] == dtype and rows[name][1].rstrip(",").replace(" ", "") == shape.replace(" ", "")


def test_the_pages_python_blocks_run(tmp_path, monkeypatch, capsys):
    _minari()
    pytest.importorskip("torch", reason="the train extra is not installed")
    (tmp_path / "results").symlink_to(ROOT / "results", target_is_directory=True)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "elsewhere"))  # a block sets it; restored after
    blocks = re.findall(r"^```python\n(.*?)^```", PAGE.read_text(), flags=re.S | re.M)
    assert len(blocks) == 3
    spaces = {}
    for block in blocks:
        spaces[len(spaces)] = ns = {"__name__": "docs"}
        exec(compile(block, "docs/demonstrations.md", "exec"), ns)
    assert spaces[0]["dataset"].total_episodes == SHIPPED_EPISODES
    assert capsys.readouterr().out == ("planner_agents ['container_0', 'container_1', 'container_2', 'container_3', "
                                       "'container_4'] (600, 5, 19) (600, 5)\n")
    assert spaces[2]["dataset"].size == spaces[2]["labels"].shape[0] == spaces[1]["metadata"]["protocol"]["episodes"] \
        * 600 * 5


def test_the_default_rows_are_the_paper_rows_distinct_test_plants():
    """Under the test protocol a δ = 60 s row's plant is the δ = 120 s row's (names aside), so the
    default build leaves the δ = 60 s rows out and misses no plant."""
    import dataclasses

    from containergym_marl.demonstrations import TEST_PLANTS
    from containergym_marl.evaluation.protocol import PAPER
    from containergym_marl.orchestration.compare_args import PAPER_ROWS

    def plant(row):
        return {k: v for k, v in dataclasses.asdict(PAPER.plant(row)).items() if k not in ("name", "description")}

    assert DemonstrationsArgs().configs == list(TEST_PLANTS)
    distinct = {json.dumps(plant(row), sort_keys=True) for row in PAPER_ROWS}
    assert {json.dumps(plant(row), sort_keys=True) for row in TEST_PLANTS} == distinct
    assert len(TEST_PLANTS) == len(distinct)
