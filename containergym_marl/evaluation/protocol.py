"""The paper's test protocol and one evaluation function for every kind of policy and view.

Default protocol (paper, section 6.1): δ = 120 s, T = 600, 15 episodes, deterministic actions, on
fixed evaluation seeds (10 000, 10 001, …) that no training run uses (training seeds are small).

Cumulative reward counts *every* reward of an episode, the final step's included. The paper's
evaluation script dropped the final step's reward (it summed rewards before checking ``done``), so
an episode ending in an overflow scored r_min higher there than here.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Protocol

import numpy as np

from containergym_marl.core.dynamics import DEFAULT_ARBITRATION
from containergym_marl.core.observations import DEFAULT_OBSERVATION, check_same_observation
from containergym_marl.config import PAPER_TEST_PROTOCOL, PlantConfig, load_config
from containergym_marl.evaluation.metrics import Steps, episode_values
from containergym_marl.evaluation.metrics import summary as metric_summary
from containergym_marl.evaluation.records import EpisodeRecord, EpisodeRecorder

#: First evaluation seed; training runs use seeds far below it.
EVAL_SEED_BASE = 10_000


@dataclass(frozen=True)
class EvalProtocol:
    """How policies are evaluated. ``PAPER`` is the paper's test protocol."""

    timestep_s: float = PAPER_TEST_PROTOCOL["timestep_s"]
    episode_length_steps: int = PAPER_TEST_PROTOCOL["episode_length_steps"]
    episodes: int = 15
    first_seed: int = EVAL_SEED_BASE
    deterministic: bool = True

    @property
    def seeds(self) -> list[int]:
        return list(range(self.first_seed, self.first_seed + self.episodes))

    def plant(self, config: str | PlantConfig) -> PlantConfig:
        """The plant under this protocol: the config with δ and T replaced."""
        return load_config(config, timestep_s=self.timestep_s, episode_length_steps=self.episode_length_steps)


PAPER = EvalProtocol()
#: Episodes for choosing settings (the native PPO's search, the planner's): disjoint from the test seeds.
VALIDATION = EvalProtocol(episodes=30, first_seed=20_000)
#: Validation episodes on which the published table picks each method's best and median seed: enough
#: to see, with probability 0.87, a policy that overflows in 2 % of its episodes.
SELECTION = EvalProtocol(episodes=100, first_seed=20_000)
#: Fresh episodes, for reporting only: every published policy, rule and planner is evaluated on them
#: beside the test episodes; seeds 30000-30199 serve nothing else (no training, tuning or choice).
FRESH = EvalProtocol(episodes=200, first_seed=30_000)
#: The episodes of the demonstration datasets (``containergym-marl demonstrations``,
#: :mod:`containergym_marl.demonstrations`): the test protocol's plant (δ = 120 s, T = 600) on seeds
#: 40000 on (100 a dataset by default), which serve nothing else (no training, test, tuning, choice or report).
DEMONSTRATIONS = EvalProtocol(episodes=100, first_seed=40_000)
#: The protocols by name, as ``compare --protocol`` names them.
PROTOCOLS = {"paper": PAPER, "validation": VALIDATION, "fresh": FRESH}


class Policy(Protocol):
    """What :func:`evaluate` needs: a name, a view and an act function for that view."""

    name: str
    view: str  # "centralised" or "decentralised"

    def act(self, observation: Any, env: Any) -> Any: ...


@dataclass
class EpisodeMetrics:
    """One episode's seed, return and every metric of :data:`~containergym_marl.evaluation.metrics.METRICS`
    (``values``, by name; also read as attributes: ``m.denied_requests``)."""

    seed: int
    cumulative_reward: float
    values: dict[str, float | int | bool]

    def __getattr__(self, name: str):
        values = self.__dict__.get("values", {})
        if name in values:
            return values[name]
        raise AttributeError(f"{type(self).__name__!r} has no metric or attribute {name!r}")

    @classmethod
    def from_record(cls, rec: EpisodeRecord) -> "EpisodeMetrics":
        terminated = np.zeros(rec.steps, dtype=bool)
        terminated[-1:] = rec.terminated
        steps = Steps(requested=rec.requested, granted=rec.granted, denied=rec.denied,
                      container_reward=rec.container_reward, pu_busy=rec.pu_timers_s[1:] > 0, terminated=terminated,
                      overflow_probability=rec.overflow_probability)
        return cls(int(rec.seed) if rec.seed is not None else -1, rec.cumulative_reward, episode_values(steps))

    def to_dict(self) -> dict[str, Any]:
        """The episode as the evaluation files hold it: seed, return, then each metric (NaN as None)."""
        return {"seed": self.seed, "cumulative_reward": self.cumulative_reward,
                **{k: None if isinstance(v, float) and math.isnan(v) else v for k, v in self.values.items()}}


@dataclass
class EvaluationResult:
    """Per-episode metrics, their aggregate, and (optionally) the full episode records.

    ``training``: what the evaluated policy was trained with, when its run directory records it
    (``run.json``'s ``"training"``, written by ``baselines/train_mappo.py``: its budget in plant steps,
    agent steps and the table's samples); written to the JSON only when set."""

    policy: str
    view: str
    config: str
    protocol: EvalProtocol
    episodes: list[EpisodeMetrics]
    records: list[EpisodeRecord] = field(default_factory=list, repr=False)
    training: dict[str, Any] | None = None

    @property
    def returns(self) -> np.ndarray:
        return np.array([e.cumulative_reward for e in self.episodes])

    def summary(self) -> dict[str, float]:
        """Episodes, the return's mean and std, and each metric's mean (its summary key)."""
        r = self.returns
        return {"episodes": len(self.episodes), "return_mean": float(r.mean()), "return_std": float(r.std()),
                **metric_summary([e.values for e in self.episodes])}

    def to_json(self) -> str:
        def clean(x):
            return None if isinstance(x, float) and math.isnan(x) else x

        return json.dumps(
            {
                "policy": self.policy,
                "view": self.view,
                "config": self.config,
                "protocol": asdict(self.protocol),
                "summary": {k: clean(v) for k, v in self.summary().items()},
                "episodes": [e.to_dict() for e in self.episodes],
                **({"training": self.training} if self.training is not None else {}),
            },
            indent=2,
        )


def evaluate(
    policy: Policy,
    config: str | PlantConfig,
    protocol: EvalProtocol = PAPER,
    *,
    arbitration: str = DEFAULT_ARBITRATION,
    keep_records: bool = True,
    on_step: Callable[[Any], None] | None = None,
    on_episode: Callable[[int, EpisodeMetrics], None] | None = None,
) -> EvaluationResult:
    """Run ``policy`` for ``protocol.episodes`` episodes through its view; one seed per episode.
    ``on_step(env)`` is called after every step, ``on_episode(episodes done, metrics)`` after every
    episode (progress).

    The decentralised view is stepped with ``reward_mode="team"`` only to read the plant reward;
    the policy's own observations do not depend on the reward mode. It builds the observation the
    policy was trained on (its ``observation``, :func:`policy_observation`).
    """
    from containergym_marl.envs.centralised import ContainerGymEnv
    from containergym_marl.envs.container_agents_v0 import parallel_env

    plant = protocol.plant(config)
    if policy.view == "centralised":
        env = ContainerGymEnv(plant)
    elif policy.view == "decentralised":
        env = parallel_env(config=plant, arbitration=arbitration, reward_mode="team", action_masking=True,
                           observation=policy_observation(policy))
    else:
        raise ValueError(f"policy {policy.name!r}: unknown view {policy.view!r}")
    _check_policy_fits(policy, env)

    episodes, records = [], []
    for seed in protocol.seeds:
        if hasattr(policy, "reset"):  # a policy with its own randomness (the planner) is seeded per episode
            policy.reset(seed=seed)
        rec = EpisodeRecorder(env.simulator, view=policy.view, policy=policy.name, seed=seed)
        if policy.view == "centralised":
            obs, _ = env.reset(seed=seed)
            rec.start()
            done = False
            while not done:
                obs, _, terminated, truncated, _ = env.step(policy.act(obs, env))
                rec.add()
                done = terminated or truncated
                if on_step:
                    on_step(env)
        else:
            obs, _ = env.reset(seed=seed)
            rec.start()
            while env.agents:
                obs, *_ = env.step(policy.act(obs, env))
                rec.add()
                if on_step:
                    on_step(env)
        record = rec.finish()
        episodes.append(EpisodeMetrics.from_record(record))
        if keep_records:
            records.append(record)
        if on_episode:
            on_episode(len(episodes), episodes[-1])
    return EvaluationResult(policy.name, policy.view, plant.name, protocol, episodes, records)


def policy_observation(policy: Policy) -> str:
    """The container-agent observation variant a policy acts on: a learned model's records the one
    it was trained on; rules, planners and older models see the default (``"local"``)."""
    return getattr(policy, "observation", DEFAULT_OBSERVATION)


def _check_policy_fits(policy: Policy, env: Any) -> None:
    """Refuse a learned model whose observation variant or space differs from the environment's."""
    if policy.view == "decentralised":
        check_same_observation(policy_observation(policy), getattr(env, "observation", DEFAULT_OBSERVATION),
                               f"policy {policy.name!r}")
    env_space = env.observation_space if policy.view == "centralised" else env.observation_space(env.possible_agents[0])
    check_observation_shape(policy, env_space.shape, env.config.name)


def check_observation_shape(policy: Policy, shape: tuple, plant_name: str) -> None:
    """Refuse a learned model whose observations are not of ``shape`` (those of the view of ``plant_name``)."""
    model_space = getattr(policy, "observation_space", None)
    if model_space is not None and model_space.shape != tuple(shape):
        raise ValueError(
            f"policy {policy.name!r} expects observations of shape {model_space.shape}, but the "
            f"{policy.view} view of {plant_name!r} gives {tuple(shape)}: the model was "
            f"trained on a plant with a different number of containers or PUs"
        )
