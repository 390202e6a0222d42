"""The README and the documentation site: the site builds with warnings as errors, the README's two
loops print what the README shows, every recipe of docs/recipes.md runs as written, the generated
parts are what the generators write now, and the README stays a front page.

The statements of the pages are checked against the result files in tests/docs/test_claims.py; the
integrations page's blocks run in tests/clients/test_readme.py.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers import load_script

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
DOCS = ROOT / "docs"


def _env() -> dict:
    """A subprocess environment that imports this checkout's package first."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    return env


def _blocks(text: str, lang: str) -> list[str]:
    return re.findall(rf"^```{lang}\n(.*?)^```", text, flags=re.S | re.M)


def _hooks():
    return load_script("docs/hooks.py")


# ---- the site --------------------------------------------------------------------------------------
def test_site_builds_with_warnings_as_errors(tmp_path):
    pytest.importorskip("mkdocs", reason="mkdocs is not installed (the docs extra: pip install -e '.[docs]')")
    site = tmp_path / "site"
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "mkdocs.yml"),
                           "-d", str(site)], cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "WARNING" not in proc.stderr, proc.stderr[-3000:]
    pages = {p.parent.name: p.read_text() for p in site.glob("*/index.html")}
    assert {"environments", "physics", "configurations", "recipes", "integrations", "cli", "results",
            "reproducing", "planner", "performance", "changelog", "demonstrations"} <= set(pages)
    assert "usage: containergym-marl evaluate" in pages["cli"]  # generated at build time
    assert "Observation space" in pages["environments"] and "&lt;!-- docstring" not in pages["environments"]
    assert "n16_m2_dt120" in pages["configurations"] and "Changelog" in pages["changelog"]
    assert not any("&lt;!-- cli" in text or "&lt;!-- include" in text for text in pages.values())


def test_every_command_has_its_generated_help_on_the_cli_page():
    from containergym_marl.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.__class__.__name__ == "_SubParsersAction")
    page = (DOCS / "cli.md").read_text()
    hooks = _hooks()
    for command in sub.choices:
        assert f"<!-- cli: {command} -->" in page, f"docs/cli.md lacks the help of {command!r}"
        assert hooks.cli_help(command).startswith(f"usage: containergym-marl {command}")


def test_directives_expand_to_the_package_and_repository_contents():
    hooks = _hooks()
    out = hooks.expand("<!-- docstring: containergym_marl.envs.centralised.ContainerGymEnv -->\n"
                       "<!-- include: CHANGELOG.md shift=1 -->\n<!-- configs -->\n")
    assert "### Observation space" in out and ":class:" not in out  # sections one level down, roles as code
    assert "## Changelog" in out
    from containergym_marl import list_configs

    assert all(f"| `{name}` |" in out for name in list_configs())


# ---- the README --------------------------------------------------------------------------------------
def test_readme_is_a_front_page():
    size = len(README.read_bytes())
    assert size <= 12_000, f"README.md is {size} bytes; the front page stays under 12 KB (details go to docs/)"
    gif = DOCS / "assets" / "episode.gif"
    assert "docs/assets/episode.gif" in README.read_text() and gif.stat().st_size < 300_000
    for link in re.findall(r"\]\((docs/[^)#]+)", README.read_text()):
        assert (ROOT / link).is_file(), f"README links to a missing page: {link}"


def _readme_loops() -> list[tuple[str, str]]:
    """The README's python blocks, each with the text block that follows it (what it prints)."""
    text = README.read_text()
    return re.findall(r"^```python\n(.*?)^```\n\n```text\n(.*?)^```", text, flags=re.S | re.M)


def test_readme_loops_print_what_the_readme_shows():
    loops = _readme_loops()
    assert len(loops) == 2
    for code, shown in loops:
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            exec(compile(code, "README.md", "exec"), {"__name__": "readme"})
        assert out.getvalue() == shown


# ---- the recipes -----------------------------------------------------------------------------------
@pytest.fixture
def recipe_dir(tmp_path, monkeypatch):
    """A working directory where the recipes' paths resolve: results/ is the repository's, read only."""
    (tmp_path / "results").symlink_to(ROOT / "results", target_is_directory=True)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _recipe(title: str, lang: str = "python") -> str:
    page = (DOCS / "recipes.md").read_text()
    section = page.split(f"## {title}\n", 1)[1].split("\n## ", 1)[0]
    (block,) = _blocks(section, lang)
    return block


def test_recipe_plot_an_episode(recipe_dir):
    exec(compile(_recipe("Plot an episode"), "docs/recipes.md", "exec"), {"__name__": "recipe"})
    assert (recipe_dir / "episode.png").stat().st_size > 0 and (recipe_dir / "episode.svg").stat().st_size > 0


def test_recipe_render_an_episode_to_a_gif(recipe_dir):
    from PIL import Image

    exec(compile(_recipe("Render an episode to a GIF"), "docs/recipes.md", "exec"), {"__name__": "recipe"})
    with Image.open(recipe_dir / "episode.gif") as gif:
        assert gif.n_frames == 21


def test_recipe_evaluate_a_shipped_policy(recipe_dir, capsys):
    pytest.importorskip("stable_baselines3", reason="the train extra is not installed")
    ns = {"__name__": "recipe"}
    exec(compile(_recipe("Evaluate a shipped policy"), "docs/recipes.md", "exec"), ns)
    assert re.fullmatch(r"shared_ppo\[s\d+,best\]: return -?\d+\.\d\d ± \d+\.\d\d, overflow rate \d\.\d\d\n",
                        capsys.readouterr().out)
    assert len(ns["result"].episodes) == 3
    assert not (Path(ns["run"]) / "evaluation_best.json").exists()


def test_recipe_give_any_policy_the_agents_own_check(recipe_dir, capsys):
    """The late policy overflows on this episode; with the check it reaches the time limit."""
    exec(compile(_recipe("Give any policy the agents' own check"), "docs/recipes.md", "exec"), {"__name__": "recipe"})
    without, with_check = capsys.readouterr().out.splitlines()
    assert re.fullmatch(r"without the check: (\d+) steps, return -?\d+\.\d\d", without)
    assert int(without.split()[3]) < 600
    assert re.fullmatch(r"with the check: 600 steps, return \d+\.\d\d", with_check)


def test_recipe_let_the_agents_talk_once_a_step(recipe_dir, capsys):
    """The policy that asks at its target has requests denied on this episode; with the rule none, and a
    higher return."""
    exec(compile(_recipe("Let the agents talk once a step"), "docs/recipes.md", "exec"), {"__name__": "recipe"})
    pattern = r"with(out)? the shared check: 600 steps, return (\d+\.\d\d), (\d+) requests denied"
    without, with_check = (re.fullmatch(pattern, line) for line in capsys.readouterr().out.splitlines())
    assert int(without.group(3)) > 0 and int(with_check.group(3)) == 0
    assert float(with_check.group(2)) > float(without.group(2))


def test_recipe_train_one_small_run(recipe_dir):
    pytest.importorskip("torch", reason="the train extra is not installed")
    lines = [line for line in _recipe("Train one small run", "bash").splitlines() if line.strip()]
    assert all(line.startswith("containergym-marl ") for line in lines)
    for line in lines:
        args = shlex.split(line)[1:] + (["--no-progress"] if line.startswith("containergym-marl train") else [])
        proc = subprocess.run([sys.executable, "-m", "containergym_marl.cli", *args], cwd=recipe_dir, env=_env(),
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
    assert (recipe_dir / "runs" / "try" / "final_model.pt").is_file()
    assert "1 episodes" in proc.stdout or "1 episode" in proc.stdout


def test_recipe_clone_the_planner_from_its_demonstrations(recipe_dir, monkeypatch, capsys):
    """The recipe loads the shipped Minari dataset, clones the planner and evaluates the clone on
    validation episodes: it scores above a uniformly random controller on the same episodes and
    overflows in fewer of them (the random one overflows in one of the ten)."""
    pytest.importorskip("minari", reason="the offline extra is not installed (pip install -e '.[offline]')")
    torch = pytest.importorskip("torch", reason="the train extra is not installed")
    import numpy as np

    from containergym_marl.evaluation import evaluate

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(recipe_dir / "elsewhere"))  # the recipe sets it; restored after
    ns = {"__name__": "recipe"}
    with torch.random.fork_rng():  # the recipe seeds torch's global generator
        exec(compile(_recipe("Clone the planner from its demonstrations"), "docs/recipes.md", "exec"), ns)
    assert re.fullmatch(r"behaviour cloning: return -?\d+\.\d\d, overflow rate \d\.\d\d; the planner's "
                        r"demonstrations: \d+\.\d\d\n", capsys.readouterr().out)
    assert ns["dataset"].total_episodes == 10 and ns["validation"].seeds == list(range(20_000, 20_010))

    class RandomController:
        """Uniformly random actions, from each episode's seed."""

        name, view = "random", "centralised"

        def reset(self, seed):
            self.rng = np.random.default_rng(seed)

        def act(self, observation, env):
            return int(self.rng.integers(env.action_space.n))

    random = evaluate(RandomController(), "n5_m2_dt120", ns["validation"]).summary()
    cloned = ns["summary"]
    assert random["overflow_rate"] > 0
    assert cloned["return_mean"] > random["return_mean"] and cloned["overflow_rate"] < random["overflow_rate"]


def test_gif_script_draws_an_episode(tmp_path):
    make_gif = load_script("docs/make_gif.py")
    assert make_gif.main(["--config", "n5_m2_dt120", "--steps", "2", "--out", str(tmp_path / "e.gif")]) == 0
    from PIL import Image

    with Image.open(tmp_path / "e.gif") as gif:
        assert gif.n_frames == 3
