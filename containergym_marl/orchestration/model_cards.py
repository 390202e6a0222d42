"""What ``publish`` ships beside each picked model: its weights as safetensors and a model card.

For every shipped model ``models/<row>/<method>_<which>.<ext>`` (``which``: best or median):

* ``<method>_<which>.safetensors`` when it is a native actor-critic (``.pt`` of
  :class:`~containergym_marl.policies.actor_critic.ActorCritic`): the same weights and header in a
  format that cannot hold code, read by the same loader;
* ``<method>_<which>.md``: a model card in the Hugging Face format (the ``README.md`` of a Hub
  repository holding it and the weights): YAML front matter with ``library_name``, tags and a
  ``model-index`` whose metric is the mean ± std return on the fresh episodes (``fresh/``); a body
  on how it was trained (method, budget, seed, settings), how to load and evaluate it, and its
  limitations (the share of fresh episodes that overflow).

Every number on a card comes from the folder's evaluation files and the run's own files
(``tests/orchestration/test_publish.py`` recomputes them). Nothing is uploaded.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from containergym_marl import ENV_ID
from containergym_marl.algorithms import get_algorithm
from containergym_marl.evaluation.table import FRESH_FOLDER, VALIDATION_FOLDER, evaluation_key
from containergym_marl.files import atomic_write_text
from containergym_marl.policies.actor_critic import ActorCritic
from containergym_marl.rundir import read_run_summary, run_args

#: The environment a decentralised model acts in (PettingZoo modules have no registry id).
AGENTS_ENV = "containergym_marl.container_agents_v0"
ROLES = {"centralised": "the centralised controller: one action for the plant",
         "decentralised": "container agents: one policy, each container an agent asking to be emptied"}


def is_actor_critic(algo: str) -> bool:
    """Whether ``algo``'s model files are native actor-critics (which get a safetensors copy)."""
    spec = get_algorithm(algo)
    return not spec.sb3 and getattr(spec.policy_adapter, "load_model", None) == ActorCritic.load


def write_safetensors(model: Path, target: Path) -> Path:
    """The actor-critic of ``model`` (``.pt``) as safetensors at ``target``."""
    return ActorCritic.load(model).save_safetensors(target)


def _summary(data: dict[str, Any]) -> dict[str, float]:
    """Mean, std and overflow share of an evaluation file's episodes (recomputed, not its summary)."""
    returns = np.array([e["cumulative_reward"] for e in data["episodes"]], dtype=float)
    return {"episodes": len(returns), "mean": float(returns.mean()), "std": float(returns.std()),
            "overflow_rate": float(np.mean([e["overflow"] for e in data["episodes"]])),
            "first_seed": int(data["protocol"]["first_seed"])}


def card(to: Path, method: str, config: str, view: str, which: str, seed: int, seeds: int, picked_on: str,
         run: Path, files: dict[str, str]) -> str:
    """The model card of one shipped model (see the module doc). ``files``: the model's file names in
    ``models/<config>/`` (``model``, and ``safetensors`` where written)."""
    args = run_args(run)
    algo = args["algo"]
    spec = get_algorithm(algo)
    mode = args.get("reward_mode") if spec.reward_modes else None  # a centralised one trains on the plant's
    command = (f"`containergym-marl train --algo {algo} --config {config} --seed {seed}"
               + (f" --reward-mode {mode}" if mode else "") + "`") if spec.trained_here else f"`{spec.trainer_name}`"
    summary = read_run_summary(run) or {}
    stem = f"{evaluation_key(method, seed)}.json"
    fresh = _summary(json.loads((to / FRESH_FOLDER / config / stem).read_text()))
    test = _summary(json.loads((to / "evaluations" / config / stem).read_text()))
    env = ENV_ID if view == "centralised" else AGENTS_ENV
    chosen_on = to / VALIDATION_FOLDER / config / stem if picked_on == "validation" else None
    picked = f"the {picked_on} episodes"
    if chosen_on is not None and chosen_on.is_file():
        validation = _summary(json.loads(chosen_on.read_text()))
        picked = f"{validation['episodes']} validation episodes (seeds {validation['first_seed']}+)"
    library = "stable-baselines3" if spec.sb3 else "containergym-marl"
    name = f"{method}-{config}-{which}"
    tags = ["reinforcement-learning", env, "containergym", config] + (["multi-agent"] if view == "decentralised" else [])
    load_file = files.get("safetensors", files["model"])
    settings = args.get("hyperparams") or {}
    front = ["---", f"library_name: {library}", "tags:", *(f"- {t}" for t in tags), "model-index:",
             f"- name: {name}", "  results:", "  - task:", "      type: reinforcement-learning",
             "      name: reinforcement-learning", "    dataset:", f"      name: {env} {config}",
             f"      type: {env}", "    metrics:", "    - type: mean_reward",
             f"      value: {fresh['mean']:.2f} +/- {fresh['std']:.2f}",
             f"      name: mean_reward on {fresh['episodes']} fresh episodes", "      verified: false", "---"]
    body = [
        "", f"# `{method}` on `{config}` ({which} of {seeds} seeds)", "",
        f"A policy of the containergym-marl benchmark ({ROLES[view]}), trained by {command}.", "",
        "## Training", "",
        f"- method: `{method}` (algorithm `{algo}`" + (f", reward mode {mode}" if mode else "") + ")",
        f"- plant: `{config}`; budget {int(args['timesteps']):,} samples, {int(summary.get('timesteps', 0)):,} trained; seed {seed}",
        "- settings: " + (f"`{json.dumps(settings, sort_keys=True)}` (the method's settings file, "
                          f"`configs/hyperparams/{method}.toml`, as it was then, and `--hp`)" if settings
                          else "the trainer's defaults"),
        f"- picked: the {which} of {seeds} seeds by mean return on {picked}",
        f"- model: {_model_rule(run)}", "",
        "## Use", "", "```python",
        "from containergym_marl.algorithms import get_algorithm",
        "from containergym_marl.evaluation import evaluate",
        "from containergym_marl.evaluation.protocol import FRESH",
        "from containergym_marl.models import load_model",
        "",
        f'policy = get_algorithm("{algo}").policy(load_model("{load_file}", algo="{algo}"), name="{method}")',
        f'print(evaluate(policy, "{config}", FRESH).summary())', "```", "",
        "## Evaluation", "",
        "| episodes | seeds | return (mean ± std) | overflowing episodes |", "|---|---|---|---|",
        f"| the paper's test protocol | {test['first_seed']}+ ({test['episodes']}) | {test['mean']:.2f} ± {test['std']:.2f} "
        f"| {test['overflow_rate']:.1%} |",
        f"| fresh | {fresh['first_seed']}+ ({fresh['episodes']}) | {fresh['mean']:.2f} ± {fresh['std']:.2f} "
        f"| {fresh['overflow_rate']:.1%} |", "",
        "## Limitations", "",
        f"- An overflow ends an episode and is an incident in the plant: this policy overflows in "
        f"{fresh['overflow_rate']:.1%} of the fresh episodes.",
        f"- Trained and evaluated on the simulated plant `{config}` only (the paper's δ = 120 s test protocol); "
        "another plant needs another model.",
        "- Greedy actions (the mode of the policy), as the test protocol evaluates it.", ""]
    return "\n".join(front + body)


def _model_rule(run: Path) -> str:
    """Which of the seed's models is shipped, and why (the one its evaluations evaluated)."""
    from containergym_marl.evaluation.curves import read_curve
    from containergym_marl.evaluation.run_policies import evaluated_which

    if evaluated_which(run) == "validated":
        curve = read_curve(run)
        return (f"the run's validated model, its policy at {curve['validated']['samples']:,} samples, of the highest "
                f"return on {curve['protocol']['episodes']} validation episodes among those its curve evaluated")
    return "the run's best model, of the highest mean return over 100 training episodes"


def write_card(to: Path, path: Path, **kwargs) -> Path:
    """Write :func:`card` (``kwargs``: its arguments) to ``path`` inside ``to``, crash-safe."""
    return atomic_write_text(path, card(to, **kwargs), within=to)


__all__ = ["AGENTS_ENV", "card", "is_actor_critic", "write_card", "write_safetensors"]
