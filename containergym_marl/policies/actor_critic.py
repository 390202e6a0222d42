"""The actor-critic of the native PPO trainer, saved as tensors: a model file that loads with
``torch.load(..., weights_only=True)`` and never runs code.

``fast_ppo`` and ``fast_shared_ppo`` (:mod:`containergym_marl.training.fast_ppo`) write their best
and final models in this format; ``containergym-marl evaluate RUN`` and
:func:`~containergym_marl.evaluation.evaluate` run them with torch alone::

    from containergym_marl.evaluation import evaluate
    from containergym_marl.policies.actor_critic import ActorCritic, policy_for

    model = ActorCritic.load("runs/fast_shared_ppo_n5_m2_dt120_s1/best_model.pt")
    result = evaluate(policy_for(model, name="fast_shared_ppo"), "n5_m2_dt120")

The file (``torch.save`` of plain containers)::

    {"format": "containergym-marl actor-critic", "version": 1,
     "view": "centralised" | "decentralised",
     "observation_size": F, "n_actions": A, "hidden": [64, 64], "action_mask": bool,
     "state_dict": {"actor.0.weight": ..., ..., "critic.4.bias": ...},
     "meta": {...}}                       # where it came from (algorithm, config, seed, samples)

The network is Stable-Baselines3's ``MlpPolicy`` for a discrete action: separate policy and value
MLPs (``hidden`` units, tanh), a linear action head (logits) and a linear value head, orthogonal
initialisation (gain √2 for the hidden layers, 0.01 for the action head, 1 for the value head).

Acting: with ``action_mask`` (a model trained with the free-PU mask) the actions that empty a
container are masked while no PU is free, as in training; then the mode of the distribution
(``deterministic=True``, the test protocol) or a sample from it.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from containergym_marl.extras import missing_extra

FORMAT = "containergym-marl actor-critic"
VERSION = 1
VIEWS = ("centralised", "decentralised")
#: The logit of a masked action (sb3-contrib's MaskablePPO uses the same).
MASKED_LOGIT = -1e8


def _torch():
    try:
        import torch
    except ImportError as error:
        raise missing_extra("the native PPO models", "train", error) from error
    return torch


def _mlp(torch, sizes: Sequence[int], generator=None):
    """Linear-tanh layers through ``sizes`` then a last linear layer (no activation), orthogonal
    init as SB3's: gain √2 for every layer but the last (set by the caller), biases 0."""
    from containergym_marl.policies._fast_tanh import Tanh

    layers: list[Any] = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        linear = torch.nn.Linear(a, b)
        torch.nn.init.orthogonal_(linear.weight, gain=math.sqrt(2), generator=generator)
        torch.nn.init.zeros_(linear.bias)
        layers.append(linear)
        if i < len(sizes) - 2:
            layers.append(Tanh())
    return torch.nn.Sequential(*layers)


class ActorCritic:
    """Policy and value networks, their shape and where they came from.

    Args:
        view: "centralised" (one controller, ``Discrete(n + 1)``) or "decentralised" (one policy
            shared by every container agent, ``Discrete(2)``).
        observation_size, n_actions: the network's input and output sizes.
        hidden: hidden layer widths of both networks (SB3: [64, 64]).
        action_mask: the model acts with the free-PU action mask.
        state_dict: weights to load (None: a fresh initialisation drawn from ``generator``).
        meta: JSON-able facts about the model (algorithm, config, seed, samples).
        generator: the torch.Generator of a fresh initialisation (all randomness from the run's seed).
    """

    def __init__(self, view: str, observation_size: int, n_actions: int, hidden: Sequence[int] = (64, 64),
                 action_mask: bool = False, state_dict: dict[str, Any] | None = None,
                 meta: dict[str, Any] | None = None, generator=None):
        torch = _torch()
        if view not in VIEWS:
            raise ValueError(f"view: expected one of {VIEWS}, got {view!r}")
        if int(observation_size) < 1 or int(n_actions) < 2 or not hidden or any(int(h) < 1 for h in hidden):
            raise ValueError(f"bad network shape: observation_size={observation_size!r}, n_actions={n_actions!r}, "
                             f"hidden={list(hidden)!r}")
        self.view, self.action_mask = view, bool(action_mask)
        self.observation_size, self.n_actions = int(observation_size), int(n_actions)
        self.hidden = [int(h) for h in hidden]
        self.meta = dict(meta or {})
        net = torch.nn.Module()
        net.actor = _mlp(torch, [self.observation_size, *self.hidden, self.n_actions], generator)
        net.critic = _mlp(torch, [self.observation_size, *self.hidden, 1], generator)
        torch.nn.init.orthogonal_(net.actor[-1].weight, gain=0.01, generator=generator)
        torch.nn.init.orthogonal_(net.critic[-1].weight, gain=1.0, generator=generator)
        self.net = net
        if state_dict is not None:
            net.load_state_dict(state_dict)

    # ---- acting ------------------------------------------------------------------------------
    def logits(self, observations, masks=None):
        """Logits [B, A] of observations [B, F] (tensors), masked where ``masks`` [B, A] is False."""
        logits = self.net.actor(observations)
        if masks is not None:
            logits = logits.masked_fill(~masks, MASKED_LOGIT)
        return logits

    def value(self, observations):
        """State values [B] of observations [B, F]."""
        return self.net.critic(observations).squeeze(-1)

    # ---- the file ----------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {"format": FORMAT, "version": VERSION, "view": self.view,
                "observation_size": self.observation_size, "n_actions": self.n_actions, "hidden": self.hidden,
                "action_mask": self.action_mask,
                "state_dict": {k: v.detach().clone() for k, v in self.net.state_dict().items()},
                "meta": self.meta}

    @classmethod
    def from_dict(cls, data: Any, source: str = "model") -> "ActorCritic":
        check_header(data, FORMAT, VERSION, source, "actor-critic")
        try:
            return cls(data["view"], data["observation_size"], data["n_actions"], data["hidden"],
                       data["action_mask"], data["state_dict"], data.get("meta"))
        except (KeyError, TypeError, RuntimeError, ValueError) as exc:
            raise ValueError(f"{source}: its shape and weights do not match ({type(exc).__name__}: {exc})") from exc

    def save(self, path: str | Path) -> Path:
        """Write the file crash-safe (temporary file, then rename)."""
        return save_tensors(path, self.to_dict())

    @classmethod
    def load(cls, path: str | Path) -> "ActorCritic":
        """Read a saved actor-critic (tensors and plain containers only: ``weights_only=True``), with
        an error that says what is wrong with a missing, broken or foreign file."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"model file {str(path)!r} does not exist")
        return cls.from_dict(load_tensors(path), f"model file {str(path)!r}")


def load_tensors(path: str | Path, otherwise: str = "holds more than tensors") -> Any:
    """``torch.load(path, weights_only=True)``: plain containers and tensors, never pickled code;
    a ValueError naming the file when it is broken or ``otherwise`` (what else it may be)."""
    torch = _torch()
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises many kinds for a cut, foreign or unsafe file
        raise ValueError(f"cannot read model file {str(path)!r}: the file is broken or {otherwise} "
                         f"({type(exc).__name__}: {exc})") from exc


def save_tensors(path: str | Path, data: Any) -> Path:
    """``torch.save(data)`` crash-safe (temporary file, then rename)."""
    from containergym_marl.files import atomic_write

    torch = _torch()
    return atomic_write(path, lambda tmp: torch.save(data, tmp))


class _ActorCriticPolicy:
    """Shared by the two views' adapters: the model, its name, greedy or sampled actions."""

    view = ""

    def __init__(self, model: ActorCritic | str | Path, name: str = "ppo", deterministic: bool = True):
        self.model = model if isinstance(model, ActorCritic) else ActorCritic.load(model)
        if self.model.view != self.view:
            raise ValueError(f"model: a {self.model.view} actor-critic cannot act in the {self.view} view")
        self.name, self.deterministic = name, deterministic
        from gymnasium import spaces

        # what evaluate() checks against the environment's observation space
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(self.model.observation_size,), dtype=np.float32)

    #: How the algorithm registry loads this adapter's model files.
    load_model = staticmethod(ActorCritic.load)

    def _actions(self, observations: np.ndarray, masks: np.ndarray | None) -> list[int]:
        torch = _torch()
        with torch.no_grad():
            logits = self.model.logits(torch.as_tensor(observations, dtype=torch.float32),
                                       None if masks is None else torch.as_tensor(masks))
            if self.deterministic:
                return logits.argmax(-1).tolist()
            return torch.distributions.Categorical(logits=logits).sample().tolist()

    def act_batch(self, observations: np.ndarray, masks: np.ndarray | None) -> np.ndarray:
        """The actions for a batch of observations (N, F) -> (N,); ``masks`` (N, actions) are applied
        when the model was trained with them, as :meth:`act` does."""
        return np.asarray(self._actions(observations, masks if self.model.action_mask else None), dtype=np.int64)


class CentralisedActorCriticPolicy(_ActorCriticPolicy):
    """A native-PPO controller acting on the centralised Gymnasium view."""

    view = "centralised"

    def act(self, observation: np.ndarray, env: Any) -> int:
        masks = np.asarray(env.action_masks(), dtype=bool)[None] if self.model.action_mask else None
        return self._actions(np.asarray(observation, dtype=np.float32)[None], masks)[0]


class SharedActorCriticPolicy(_ActorCriticPolicy):
    """A native-PPO policy shared by every container agent of the decentralised view (one batched
    forward per step)."""

    view = "decentralised"

    def act(self, observations: dict[str, Any], env: Any) -> dict[str, int]:
        agents = list(observations)
        obs = np.stack([o["observation"] if isinstance(o, dict) else o for o in observations.values()])
        masks = None
        if self.model.action_mask:
            free = bool(env.simulator.free_pu_count()[0] > 0)
            masks = np.tile(np.array([True, free]), (len(agents), 1))
        return dict(zip(agents, self._actions(obs.astype(np.float32, copy=False), masks)))


def policy_for(model: ActorCritic, name: str = "ppo", deterministic: bool = True):
    """The evaluation policy of ``model`` in its own view."""
    cls = CentralisedActorCriticPolicy if model.view == "centralised" else SharedActorCriticPolicy
    return cls(model, name=name, deterministic=deterministic)


def check_header(data: Any, fmt: str, version: int, source: str, what: str) -> None:
    """A saved tensor file's header as this package writes it: ``format`` ``fmt`` at ``version``
    (a ValueError naming ``source`` otherwise)."""
    if not isinstance(data, dict) or data.get("format") != fmt:
        raise ValueError(f"{source} is not a saved {what} (format {fmt!r})")
    if data.get("version") != version:
        raise ValueError(f"{source}: {what} version {data.get('version')!r}; this package reads version {version}")
