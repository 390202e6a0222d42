"""Every training value is checked before anything is written: a refused command names the
offending value, exits 2 and leaves no run directory, so the corrected command then runs."""

from __future__ import annotations

import pytest

from containergym_marl.cli import main as cli_main


@pytest.mark.parametrize("extra, named", [
    (["--gamma", "nan"], "gamma"),
    (["--gamma", "2.5"], "gamma"),
    (["--gamma", "0"], "gamma"),
    (["--seed", "-1"], "seed"),
    (["--seed", str(2**32)], "seed"),
    (["--n-envs", "100000000"], "n_envs"),
    (["--hp", "bogus_kw=1"], "bogus_kw"),
    (["--hp", "n_steps=0"], "hp"),
    (["--algo", "shared_ppo", "--vec", "supersuit", "--num-cpus", "-1"], "num_cpus"),
    (["--algo", "fast_ppo", "--hp", "minibatch_size=0"], "minibatch_size"),
    (["--algo", "fast_ppo", "--hp", "clip_range=nan"], "clip_range"),
])
def test_a_bad_value_is_refused_before_anything_is_written(extra, named, tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["train", "--algo", "ppo", *extra] if "--algo" not in extra else ["train", *extra]
    assert cli_main([*argv, "--out", str(out), "--timesteps", "256", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert named in err and "Traceback" not in err
    assert not out.exists()


def test_the_corrected_command_runs_after_a_refused_one(tmp_path, capsys):
    out = tmp_path / "run"
    assert cli_main(["train", "--algo", "ppo", "--hp", "n_steps=0", "--out", str(out), "--timesteps", "128",
                     "--no-progress"]) == 2
    assert cli_main(["train", "--algo", "ppo", "--hp", "n_steps=64", "--n-envs", "2", "--out", str(out),
                     "--timesteps", "128", "--no-progress"]) == 0
    assert (out / "final_model.zip").is_file()
