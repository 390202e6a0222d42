"""A method's settings file (configs/hyperparams/<method>.toml): read by train for a new run, under
--hp; a resumed run keeps the settings it recorded; a bad file is refused before anything is written."""

from __future__ import annotations

import json

import pytest

from containergym_marl.algorithms import get_algorithm
from containergym_marl.config import hyperparams as files
from containergym_marl.methods import METHODS
from containergym_marl.training import TrainArgs, train

TINY = dict(config="n5_m2_dt120", n_envs=2, progress_bar=False, overrides={"episode_length_steps": 20})


@pytest.fixture
def folder(tmp_path, monkeypatch):
    path = tmp_path / "hyperparams"
    path.mkdir()
    monkeypatch.setattr(files, "hyperparams_dir", lambda: path)
    return path


def _settings(run) -> dict:
    return json.loads((run / "args.json").read_text())["hyperparams"]


def test_the_shipped_files_are_the_native_methods_and_valid():
    shipped = sorted(p.stem for p in files.hyperparams_dir().glob("*.toml"))
    assert shipped == ["dagger_checked_agents", "dagger_messaging_agents", "fast_ppo", "fast_shared_ppo", "fast_shared_ppo_checked",
                       "fast_shared_ppo_team"]
    for name in shipped:
        assert name in METHODS
        trainer = get_algorithm(METHODS[name].algo).trainer()
        whole = files.read_settings_file(files.settings_file(name))
        for entry in [whole, *whole["by_size"]]:  # the settings of every plant size
            # a file's [settings] may be empty (the method's own defaults) only where it has entries
            assert entry["source"] and (entry["settings"] or (entry is whole and whole["by_size"]))
            trainer.settings(entry["settings"])  # every key a setting of its trainer, every value within bounds


def test_the_checked_imitation_looks_two_steps_ahead_only_where_two_pus_serve_eleven_at_60_s():
    """dagger_checked_agents' file: L = 2 on n11_m2_dt60 (chosen there on validation episodes), the
    trainer's defaults (L = 1) on every other row of the table."""
    from containergym_marl.config import load_config
    from containergym_marl.training.dagger import CHECKED_SETTINGS

    rows = ["n5_m2_dt60", "n5_m2_dt120", "n5_m5_dt60", "n5_m5_dt120", "n11_m2_dt60", "n11_m2_dt120",
            "n11_m11_dt60", "n11_m11_dt120", "n16_m2_dt120"]
    trainer = get_algorithm("dagger_checked_agents").trainer()
    leads = {row: trainer.settings(files.plant_settings("dagger_checked_agents", load_config(row))).own_check_lead_steps
             for row in rows}
    assert CHECKED_SETTINGS["own_check_lead_steps"] == 1
    assert leads == {row: 2 if row == "n11_m2_dt60" else 1 for row in rows}


def test_an_entry_naming_the_plants_interval_or_pus_applies_to_those_plants_only(tmp_path):
    """by_size entries may name timestep_s and num_processing_units: the entry naming the most of them
    that applies wins, then the largest min_containers."""
    path = tmp_path / "m.toml"
    files.write_settings(path, {"n_steps": 16}, "top", by_size=[
        (11, {"n_steps": 8}, "from 11"), (1, {"n_steps": 4}, "at 60 s", {"timestep_s": 60.0}),
        (11, {"n_steps": 2}, "11+, 2 PUs, 60 s", {"timestep_s": 60.0, "num_processing_units": 2})])

    def pick(n, dt, m):
        return files.read_settings(path, n, timestep_s=dt, num_processing_units=m)[1]

    assert [pick(5, 120.0, 2), pick(5, 60.0, 2), pick(11, 120.0, 2), pick(11, 60.0, 11), pick(11, 60.0, 2),
            pick(16, 60.0, 2), pick(11, 60.0, None)] == ["top", "at 60 s", "from 11", "at 60 s",
                                                         "11+, 2 PUs, 60 s", "11+, 2 PUs, 60 s", "at 60 s"]
    assert files.read_settings(path, 11)[1] == "from 11"  # no interval given: only entries naming none


def test_a_run_takes_the_entry_of_its_plants_interval(folder, tmp_path):
    files.write_settings(folder / "fast_shared_ppo.toml", {"n_steps": 16}, "top",
                         by_size=[(1, {"n_steps": 8}, "at 60 s", {"timestep_s": 60.0})])
    at_120 = train(TrainArgs(algo="fast_shared_ppo", timesteps=160, out=str(tmp_path / "a"), **TINY))
    at_60 = train(TrainArgs(algo="fast_shared_ppo", timesteps=160, out=str(tmp_path / "b"),
                            **{**TINY, "overrides": {**TINY["overrides"], "timestep_s": 60}}))
    assert (_settings(at_120), _settings(at_60)) == ({"n_steps": 16}, {"n_steps": 8})


def test_the_checked_method_trains_at_the_shared_methods_setting():
    """fast_shared_ppo_checked is fast_shared_ppo with the agents' own check: its file holds the same
    PPO setting (the one the tuning study's --own-check comparison trained with the check)."""
    assert files.read_settings_file(files.settings_file("fast_shared_ppo_checked"))["settings"] == \
        files.read_settings_file(files.settings_file("fast_shared_ppo"))["settings"]


def test_a_new_run_takes_its_methods_file_under_hp(folder, tmp_path):
    files.write_settings(folder / "fast_shared_ppo.toml", {"n_steps": 16, "learning_rate": 1e-3}, "a test")
    files.write_settings(folder / "fast_shared_ppo_team.toml", {"n_steps": 8, "minibatch_size": 32}, "a test")
    run = train(TrainArgs(algo="fast_shared_ppo", timesteps=400, out=str(tmp_path / "a"),
                          hyperparams={"learning_rate": "5e-4"}, **TINY))
    assert _settings(run) == {"n_steps": 16, "learning_rate": "5e-4"}  # --hp wins over the file
    rows = (run / "metrics.csv").read_text().splitlines()[1:]
    assert all(int(r.split(",")[0]) % (16 * 2 * 5) == 0 for r in rows)  # 16 steps x 2 sims x 5 agents
    team = train(TrainArgs(algo="fast_shared_ppo", reward_mode="team", timesteps=400, out=str(tmp_path / "b"), **TINY))
    assert _settings(team) == {"n_steps": 8, "minibatch_size": 32}  # the method fast_shared_ppo_team's file
    sb3 = train(TrainArgs(algo="ppo", timesteps=64, out=str(tmp_path / "c"), **TINY))
    assert _settings(sb3) == {}  # no file: the algorithm's defaults


def test_a_resumed_run_keeps_its_recorded_settings(folder, tmp_path):
    files.write_settings(folder / "fast_shared_ppo.toml", {"n_steps": 16}, "a test")
    first = train(TrainArgs(algo="fast_shared_ppo", timesteps=160, out=str(tmp_path / "r"), **TINY))
    files.write_settings(folder / "fast_shared_ppo.toml", {"n_steps": 8}, "changed since")
    run = train(TrainArgs(algo="fast_shared_ppo", timesteps=480, out=str(first), resume=True, **TINY))
    assert _settings(run) == {"n_steps": 16}
    steps = [int(r.split(",")[0]) for r in (run / "metrics.csv").read_text().splitlines()[1:]]
    assert steps and steps[-1] == 480 and all(s % 160 == 0 for s in steps)


def test_a_plant_takes_the_settings_of_its_size(folder, tmp_path):
    """[[by_size]] entries replace [settings] (whole, not merged) from their min_containers on: the
    entry of the largest min_containers <= n applies; a resumed run keeps what it recorded."""
    files.write_settings(folder / "fast_shared_ppo.toml", {"n_steps": 16, "learning_rate": 1e-3}, "small plants",
                         by_size=[(16, {"n_steps": 4}, "the largest"), (11, {"n_steps": 8}, "from 11 on")])
    path = folder / "fast_shared_ppo.toml"
    assert files.read_settings(path) == ({"n_steps": 16, "learning_rate": 1e-3}, "small plants")
    assert [files.read_settings(path, n) for n in (5, 10, 11, 15, 16, 128)] == [
        ({"n_steps": 16, "learning_rate": 1e-3}, "small plants")] * 2 + [({"n_steps": 8}, "from 11 on")] * 2 + [
        ({"n_steps": 4}, "the largest")] * 2
    assert [e["min_containers"] for e in files.read_settings_file(path)["by_size"]] == [11, 16]
    small = train(TrainArgs(algo="fast_shared_ppo", timesteps=160, out=str(tmp_path / "a"), **TINY))
    assert _settings(small) == {"n_steps": 16, "learning_rate": 1e-3}
    large = train(TrainArgs(algo="fast_shared_ppo", timesteps=528, out=str(tmp_path / "b"),
                            **{**TINY, "config": "n11_m2_dt120"}))
    assert _settings(large) == {"n_steps": 8}
    steps = [int(r.split(",")[0]) for r in (large / "metrics.csv").read_text().splitlines()[1:]]
    assert steps and all(s % (8 * 2 * 11) == 0 for s in steps)  # 8 steps x 2 sims x 11 agents per update
    files.write_settings(path, {"n_steps": 16}, "changed since")
    resumed = train(TrainArgs(algo="fast_shared_ppo", timesteps=704, out=str(large), resume=True,
                              **{**TINY, "config": "n11_m2_dt120"}))
    assert _settings(resumed) == {"n_steps": 8}


@pytest.mark.parametrize("text, named", [
    ("[settings]\nn_steps = 8\n[[by_size]]\nmin_containers = 0\n[by_size.settings]\nn_steps = 4\n",
     r"by_size\[0\]\.min_containers"),
    ("[settings]\nn_steps = 8\n[[by_size]]\nmin_containers = 2\nsetings = 1\n", "setings"),
    ("[settings]\nn_steps = 8\n[[by_size]]\nmin_containers = 2\n", r"by_size\[0\]: no settings"),
    ("[settings]\nn_steps = 8\n[[by_size]]\nmin_containers = 2\n[by_size.settings]\nlearning_rate = inf\n",
     r"by_size\[0\]\.settings\.learning_rate"),
    ("[settings]\nn_steps = 8\n" + "[[by_size]]\nmin_containers = 2\n[by_size.settings]\nn_steps = 4\n" * 2,
     "names a size twice"),
    ("by_size = 3\n", "by_size"),
    ("[settings]\nn_steps = 8\n[[by_size]]\nmin_containers = 2\ntimestep_s = 0\n[by_size.settings]\nn_steps = 4\n",
     r"by_size\[0\]\.timestep_s"),
    ("[settings]\nn_steps = 8\n[[by_size]]\nmin_containers = 2\nnum_processing_units = 1.5\n[by_size.settings]\n"
     "n_steps = 4\n", r"by_size\[0\]\.num_processing_units"),
    ("[settings]\nn_steps = 8\n[[by_size]]\nmin_containers = 5\n[by_size.settings]\nn_epochs = 0\n", "n_epochs"),
    ("[settings]\nn_epochs = 0\n", "n_epochs"),  # out of PPOArgs' bounds
    ("[settings]\nlearning_rte = 0.1\n", "learning_rte"),  # not a setting
    ("[settings]\nlearning_rate = nan\n", "settings.learning_rate"),
    ("[settings]\nhidden = {a = 1}\n", "settings.hidden"),
    ("sources = 'x'\n", "sources"),
    ("[settings\n", "not a TOML file"),
    ("[settings]\nx = " + "[" * 5000 + "]" * 5000 + "\n", "nested deeper"),  # bounded before parsing
])
def test_a_bad_file_is_refused_before_anything_is_written(folder, tmp_path, text, named):
    (folder / "fast_shared_ppo.toml").write_text(text)
    with pytest.raises(ValueError, match=named):
        train(TrainArgs(algo="fast_shared_ppo", timesteps=160, out=str(tmp_path / "run"), **TINY))
    assert not (tmp_path / "run").exists()


def test_write_settings_reads_back(tmp_path):
    settings = {"anneal_lr": True, "hidden": [64, 32], "learning_rate": 2.5e-4, "n_epochs": 5}
    files.write_settings(tmp_path / "m.toml", settings, 'trial 3 of "a search"')
    assert files.read_settings(tmp_path / "m.toml") == (settings, 'trial 3 of "a search"')
    with pytest.raises(ValueError, match="method"):
        files.settings_file("../escape")


def test_every_published_run_of_a_method_with_a_file_trained_at_its_plants_entry():
    """The published table's runs are what the shipped files say: each run's recorded settings are its method's
    file's entry for the run's plant (a file changed without retraining fails here)."""
    from pathlib import Path

    from containergym_marl.config import load_config

    runs = Path(__file__).resolve().parents[2] / "results" / "paper_rows" / "runs"
    checked = 0
    for path in sorted(files.hyperparams_dir().glob("*.toml")):
        for run in sorted(runs.glob(f"{path.stem}_n*_s*")):
            args = json.loads((run / "args.json").read_text())
            if args["algo"] != METHODS[path.stem].algo:
                continue  # another method whose name starts with this one's
            expected = files.plant_settings(path.stem, load_config(args["config"]))
            assert args["hyperparams"] == expected, f"{run.name}: trained at {args['hyperparams']}, file {expected}"
            checked += 1
    assert checked >= 135 * 3 + 45 * 2
