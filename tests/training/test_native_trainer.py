"""A native trainer is one module and one registry line: ``train`` runs it like the package's own.

The trainer below is the smallest that keeps the interface
(:class:`containergym_marl.training.native.NativeTrainer`): it never learns, it counts samples and
episodes and saves an untrained ``fast_shared_ppo`` network. Registered under a new name, it trains
through ``train`` (run directory, settings, memory check, run.json, final model) and its model is
evaluated like any other.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

pytest.importorskip("torch")

from containergym_marl import algorithms  # noqa: E402
from containergym_marl.algorithms import AlgorithmSpec  # noqa: E402
from containergym_marl.policies.actor_critic import ActorCritic, SharedActorCriticPolicy  # noqa: E402
from containergym_marl.training.checkpoints import TrainingProgress  # noqa: E402
from containergym_marl.training.native import MemoryShapes  # noqa: E402


@dataclass(frozen=True)
class IdleSettings:
    request_probability: float = 0.1
    rollout_steps: int = 4


class IdleTrainer:
    """Requests at random, learns nothing."""

    calls: list[str] = []

    def settings(self, hyperparams: dict[str, Any]) -> IdleSettings:
        unknown = set(hyperparams) - {"request_probability", "rollout_steps"}
        if unknown:
            raise ValueError(f"hp: unknown idle setting(s) {sorted(unknown)}")
        self.calls.append("settings")
        return IdleSettings(**hyperparams)

    def default_sims(self, settings: IdleSettings, agents_per_sim: int) -> int:
        return 3

    def memory(self, settings: IdleSettings, shapes: MemoryShapes) -> dict[str, int]:
        return {f"rollout_steps={settings.rollout_steps}": shapes.rollout(settings.rollout_steps, shapes.obs)}

    def new_state(self, env, settings: IdleSettings, view: str, seed: int, meta: dict[str, Any]):
        model = ActorCritic(view, env.observation_space.shape[0], int(env.action_space.n), (8,), meta=meta)
        return SimpleNamespace(model=model, num_timesteps=0, rng=np.random.default_rng(seed))

    def load_checkpoint(self, path: Path, settings: IdleSettings):
        raise ValueError("the idle trainer saves no checkpoint")

    def learn(self, run: Path, state, env, budget: int, gamma: float, settings: IdleSettings,
              progress: TrainingProgress, interval: int, seed: int, on_samples=None):
        env.reset()
        returns = np.zeros(env.num_envs)
        lengths = np.zeros(env.num_envs, dtype=int)
        while state.num_timesteps < budget:
            actions = (state.rng.random(env.num_envs) < settings.request_probability).astype(np.int64)
            _, rewards, dones, _ = env.step(actions)
            returns += rewards
            lengths += 1
            for slot in np.flatnonzero(dones):
                progress.add_episode(returns[slot], lengths[slot])
                returns[slot], lengths[slot] = 0.0, 0
            state.num_timesteps += env.num_envs
        return state

    def save_final(self, state, path: Path) -> None:
        state.model.save(path)

    def run_summary(self, run: Path) -> dict[str, Any]:
        return {"idle": {"learned": False}}


IDLE = IdleTrainer()


@pytest.fixture
def idle_algorithm(monkeypatch):
    spec = AlgorithmSpec("idle_agents", None, SharedActorCriticPolicy, "container agents that request at random",
                         native=f"{__name__}:IDLE", default_n_envs=None, minibatch=None, adam_eps=None,
                         reward_modes=("individual",), model_suffix=".pt")
    monkeypatch.setitem(algorithms.REGISTRY, spec.name, spec)
    IdleTrainer.calls = []
    return spec


def test_a_registered_native_trainer_trains_and_its_model_is_evaluated(idle_algorithm, tmp_path, monkeypatch):
    from containergym_marl.evaluation.run_policies import evaluate_run
    from containergym_marl.training.loop import train
    from containergym_marl.training.train_args import TrainArgs

    monkeypatch.chdir(tmp_path)
    args = TrainArgs(algo="idle_agents", config="n5_m2_dt120", seed=3, timesteps=3000, out=str(tmp_path / "run"),
                     progress_bar=False, hyperparams={"request_probability": 0.0})
    run = train(args)
    summary = json.loads((run / "run.json").read_text())
    assert summary["status"] == "finished" and summary["algo"] == "idle_agents"
    assert summary["idle"] == {"learned": False}  # the trainer's own entry
    assert summary["timesteps"] >= 3000 and summary["episodes"] > 0
    saved = json.loads((run / "args.json").read_text())
    assert saved["n_envs"] == 3  # the trainer's default_sims
    assert saved["hyperparams"] == {"request_probability": 0.0}  # never empties: short episodes
    # parsed once per check: the command line's, then the run's own (method file and --hp)
    assert IdleTrainer.calls == ["settings", "settings"]
    assert (run / "final_model.pt").is_file()
    result = evaluate_run(run, which="final")
    assert len(result.episodes) == 15 and np.isfinite(result.returns).all()
    assert result.policy.startswith("idle_agents")


def test_a_native_trainer_refuses_its_bad_settings_before_anything_is_written(idle_algorithm, tmp_path):
    from containergym_marl.training.loop import train
    from containergym_marl.training.train_args import TrainArgs

    args = TrainArgs(algo="idle_agents", config="n5_m2_dt120", timesteps=1000, out=str(tmp_path / "run"),
                     progress_bar=False, hyperparams={"learning_rate": 0.1})
    with pytest.raises(ValueError, match=r"unknown idle setting\(s\) \['learning_rate'\]"):
        train(args)
    assert not (tmp_path / "run").exists()


def test_a_native_trainers_memory_terms_are_checked_before_the_run(idle_algorithm, tmp_path):
    from containergym_marl.training.loop import train
    from containergym_marl.training.train_args import TrainArgs

    args = TrainArgs(algo="idle_agents", config="n5_m2_dt120", timesteps=1000, out=str(tmp_path / "run"),
                     progress_bar=False, hyperparams={"rollout_steps": 10**12})
    with pytest.raises(ValueError, match="rollout_steps=1000000000000"):
        train(args)
    assert not (tmp_path / "run").exists()
