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
     "observation": "local",              # the container agents' observation variant it was trained on
     "own_check": {"risk": ε, "lead_steps": L},  # only with a container agent's own deadline check
     "request_threshold": τ,              # only where a greedy container agent requests above τ, not 0.5
     "shared_check": {"risk": ε, "window_steps": W, "prefer": "policy"},  # only with the agents' shared check
     "state_dict": {"actor.0.weight": ..., ..., "critic.4.bias": ...},
     "meta": {...}}                       # where it came from (algorithm, config, seed, samples)

``observation`` (:data:`~containergym_marl.core.observations.OBSERVATIONS`) is absent from files
written before the variants existed: they read as ``"local"``, the observation they were trained on.
A model acts only on the variant it records (its policy adapter refuses another, naming both), and
an evaluation builds that variant; a centralised model's is always ``"local"``.

``own_check`` (absent from older files: None) is a decentralised model's own deadline check
(:func:`~containergym_marl.policies.safety.own_deadline_due`): wherever the model acts, an agent whose
own observation says its container would overflow within ``lead_steps`` + 1 fills with probability
above ``risk`` asks for a free PU, whatever the network says. It is part of the policy: the policy
adapters apply it, so every evaluation of the model does.

``request_threshold`` (absent: None) is a decentralised model's greedy decision rule: an agent
requests a PU where the network's probability of requesting is above τ rather than above 1/2 (its
most likely action). An imitation whose agents see less than the planner that labels them learns
the share of similar-looking states in which the planner requests; below 1/2 the most likely
action is to wait, although a missed request near an overflow costs far more than an early one.
Greedy acting (``deterministic=True``, every evaluation) applies it; sampling ignores it.

``shared_check`` (absent: None) is a decentralised model's one round of messages between its agents
(:mod:`~containergym_marl.policies.shared_check`): each agent broadcasts its container's volume and its
log-odds of requesting, and all apply the same rule: the requests the arbitration would deny are
withdrawn, and emptyings that the reference's deadline check finds unsafe are replaced by the safe set
the policy finds most likely. The rule needs the plant's description: the policy adapter binds it from
the environment it acts in (``act``), or from :meth:`SharedActorCriticPolicy.bind` (``act_batch``;
:func:`~containergym_marl.evaluation.batched.evaluate_batched` binds it). It applies after the own check
and the request threshold, to greedy and sampled actions alike.

The same model as safetensors (:meth:`ActorCritic.save_safetensors`, ``.safetensors``: a format
that holds tensors and a string header, never code): the state dict's tensors, and the other fields
as the header's metadata (``format``, ``version``, ``view``, ``observation_size``, ``n_actions``,
``hidden``, ``action_mask``, ``observation``, ``own_check``, ``request_threshold``, ``shared_check``, ``meta``;
numbers, lists, ``own_check``, ``shared_check`` and ``meta`` as JSON text).
:meth:`ActorCritic.load` reads either by the file's suffix, with the same checks.

The network is Stable-Baselines3's ``MlpPolicy`` for a discrete action: separate policy and value
MLPs (``hidden`` units, tanh), a linear action head (logits) and a linear value head, orthogonal
initialisation (gain √2 for the hidden layers, 0.01 for the action head, 1 for the value head).

Acting: with ``action_mask`` (a model trained with the free-PU mask) the actions that empty a
container are masked while no PU is free, as in training; then the mode of the distribution
(``deterministic=True``, the test protocol; with ``request_threshold``, a request above τ) or a sample
from it.
"""

from __future__ import annotations

import json
import math
import operator
import zipfile
import zlib
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from containergym_marl.config.bounds import MAX_HIDDEN_LAYERS, MAX_HIDDEN_WIDTH, MAX_NETWORK_PARAMETERS
from containergym_marl.core.dynamics import DEFAULT_ARBITRATION
from containergym_marl.core.observations import DEFAULT_OBSERVATION, check_observation, check_same_observation
from containergym_marl.policies.safety import check_own_check, own_deadline_due
from containergym_marl.policies.shared_check import SharedCheck, check_shared_check
from containergym_marl.extras import missing_extra

FORMAT = "containergym-marl actor-critic"
VERSION = 1
VIEWS = ("centralised", "decentralised")
#: The logit of a masked action (sb3-contrib's MaskablePPO uses the same).
MASKED_LOGIT = -1e8


def check_request_threshold(value, where: str = "request_threshold") -> float | None:
    """``value`` as a greedy container agent's request threshold τ (a probability in (0, 1)), or None
    (its most likely action); a ValueError naming ``where`` otherwise."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and 0 < value < 1):
        raise ValueError(f"{where}: expected None or a probability in (0, 1), got {value!r}")
    return float(value)


def check_agent_rules(view: str, own_check, request_threshold, shared_check=None,
                      where: str = "") -> tuple[dict | None, float | None, dict | None]:
    """A model's container-agent rules (its own check, its request threshold, its shared check), each checked,
    and none on a centralised model, which has no container agents (a ValueError naming the field and ``where``)."""
    prefix = f"{where}: " if where else ""
    rules = (("own_check", check_own_check(own_check, f"{prefix}own_check")),
             ("request_threshold", check_request_threshold(request_threshold, f"{prefix}request_threshold")),
             ("shared_check", check_shared_check(shared_check, f"{prefix}shared_check")))
    for name, value in rules:
        if view == "centralised" and value is not None:
            raise ValueError(f"{prefix}{name}: a container agent's rule; a centralised model has no container agents")
    return tuple(value for _, value in rules)


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
        observation: the container agents' observation variant it acts on
            (:data:`~containergym_marl.core.observations.OBSERVATIONS`; "local" for a centralised model).
        own_check: a decentralised model's own deadline check, ``{"risk": ε, "lead_steps": L}``, or None.
        request_threshold: a decentralised model's greedy request threshold τ, or None (the most likely action).
        shared_check: a decentralised model's shared check, ``{"risk": ε, "window_steps": W, "prefer": ...}``, or None.
    """

    def __init__(self, view: str, observation_size: int, n_actions: int, hidden: Sequence[int] = (64, 64),
                 action_mask: bool = False, state_dict: dict[str, Any] | None = None,
                 meta: dict[str, Any] | None = None, generator=None, observation: str = DEFAULT_OBSERVATION,
                 own_check: dict[str, Any] | None = None, request_threshold: float | None = None,
                 shared_check: dict[str, Any] | None = None):
        torch = _torch()
        if view not in VIEWS:
            raise ValueError(f"view: expected one of {VIEWS}, got {view!r}")
        self.observation = check_observation(observation)
        if view == "centralised" and observation != DEFAULT_OBSERVATION:
            raise ValueError(f"observation: {observation!r} is a variant of the container agents' observation; "
                             f"a centralised model observes the global state ({DEFAULT_OBSERVATION!r})")
        self.own_check, self.request_threshold, self.shared_check = check_agent_rules(
            view, own_check, request_threshold, shared_check)
        self.view, self.action_mask = view, bool(action_mask)
        self.observation_size, self.n_actions, self.hidden = check_network(observation_size, n_actions, hidden)
        self.meta = dict(meta or {})
        net = torch.nn.Module()
        net.actor = _mlp(torch, [self.observation_size, *self.hidden, self.n_actions], generator)
        net.critic = _mlp(torch, [self.observation_size, *self.hidden, 1], generator)
        torch.nn.init.orthogonal_(net.actor[-1].weight, gain=0.01, generator=generator)
        torch.nn.init.orthogonal_(net.critic[-1].weight, gain=1.0, generator=generator)
        self.net = net
        if state_dict is not None:
            net.load_state_dict(state_dict)
        # the actor's Linear modules (they persist when their parameters' data moves)
        self._actor_linears = [m for m in net.actor if isinstance(m, torch.nn.Linear)]

    # ---- acting ------------------------------------------------------------------------------
    def logits(self, observations, masks=None):
        """Logits [B, A] of observations [B, F] (tensors), masked where ``masks`` [B, A] is False."""
        logits = self.net.actor(observations)
        if masks is not None:
            logits = logits.masked_fill(~masks, MASKED_LOGIT)
        return logits

    def decision_logits(self, observations):
        """:meth:`logits` without masks, outside autograd, bit for bit: the same ``addmm`` and tanh as the
        actor's modules, called directly (a decision on a dozen observations costs about half as much)."""
        from containergym_marl.policies._fast_tanh import tanh_

        torch = _torch()
        layers = self._actor_linears
        with torch.no_grad():
            x = observations
            for layer in layers[:-1]:
                x = tanh_(torch.addmm(layer.bias, x, layer.weight.t()))
            return torch.addmm(layers[-1].bias, x, layers[-1].weight.t())

    def greedy(self, logits):
        """The greedy actions [B] of decision logits [B, A]: the most likely action, or for a model with a
        ``request_threshold`` τ, a request (1) where its probability is above τ."""
        if self._greedy_shift is None:
            return logits.argmax(-1)
        return (logits - self._greedy_shift).argmax(-1)

    @property
    def request_threshold(self) -> float | None:
        return self._request_threshold

    @request_threshold.setter
    def request_threshold(self, tau: float | None) -> None:
        # P(request) > τ  <=>  l1 - log(τ / (1 - τ)) > l0: greedy's most likely action of logits shifted once
        # (argmax keeps the wait on a tie), one subtraction instead of three ops per decision
        self._request_threshold = tau
        self._greedy_shift = None if tau is None else _torch().tensor([0.0, math.log(tau / (1 - tau))])

    def value(self, observations):
        """State values [B] of observations [B, F]."""
        return self.net.critic(observations).squeeze(-1)

    # ---- the file ----------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {"format": FORMAT, "version": VERSION, "view": self.view,
                "observation_size": self.observation_size, "n_actions": self.n_actions, "hidden": self.hidden,
                "action_mask": self.action_mask, "observation": self.observation,
                "state_dict": {k: v.detach().clone() for k, v in self.net.state_dict().items()},
                "meta": self.meta,
                # only where there is one: a model without keeps the bytes of a file written before the check
                **({"own_check": self.own_check} if self.own_check is not None else {}),
                **({"request_threshold": self.request_threshold} if self.request_threshold is not None else {}),
                **({"shared_check": self.shared_check} if self.shared_check is not None else {})}

    @classmethod
    def from_dict(cls, data: Any, source: str = "model") -> "ActorCritic":
        """The actor-critic of :meth:`to_dict`'s output. Its sizes are checked against the bounds and
        its weights against its sizes before the network is built (a ValueError naming ``source``)."""
        check_header(data, FORMAT, VERSION, source, "actor-critic")
        missing = [key for key in ("view", "observation_size", "n_actions", "hidden", "action_mask", "state_dict")
                   if key not in data]
        if missing:
            raise ValueError(f"{source}: no {', '.join(missing)}")
        sizes = check_network(data["observation_size"], data["n_actions"], data["hidden"], source)
        check_state_dict(data["state_dict"], _shapes(*sizes), source)
        observation = check_observation(data.get("observation", DEFAULT_OBSERVATION), f"{source}: observation")
        if data["view"] == "centralised" and observation != DEFAULT_OBSERVATION:
            raise ValueError(f"{source}: a centralised model with the container agents' {observation!r} observation")
        own_check, threshold, shared_check = check_agent_rules(
            data["view"], data.get("own_check"), data.get("request_threshold"), data.get("shared_check"), source)
        try:
            return cls(data["view"], *sizes, data["action_mask"], data["state_dict"], data.get("meta"),
                       observation=observation, own_check=own_check, request_threshold=threshold,
                       shared_check=shared_check)
        except (TypeError, RuntimeError, ValueError) as exc:
            raise ValueError(f"{source}: its shape and weights do not match ({type(exc).__name__}: {exc})") from exc

    def save(self, path: str | Path, durable: bool = True) -> Path:
        """Write the file crash-safe (temporary file, then rename); ``durable=False``: without the
        flushes to disk (:func:`~containergym_marl.files.atomic_write`)."""
        return save_tensors(path, self.to_dict(), durable)

    def save_safetensors(self, path: str | Path) -> Path:
        """Write the model as safetensors (see the module doc), crash-safe."""
        from containergym_marl.files import atomic_write

        data = self.to_dict()
        metadata = {"format": data["format"], "version": str(data["version"]), "view": data["view"],
                    "observation_size": str(data["observation_size"]), "n_actions": str(data["n_actions"]),
                    "hidden": json.dumps(list(data["hidden"])), "action_mask": json.dumps(bool(data["action_mask"])),
                    "observation": data["observation"], "meta": json.dumps(data["meta"], sort_keys=True),
                    **({"own_check": json.dumps(data["own_check"])} if "own_check" in data else {}),
                    **({key: json.dumps(data[key]) for key in ("request_threshold", "shared_check") if key in data})}
        blob = _safetensors_torch().save({k: v.contiguous() for k, v in data["state_dict"].items()}, metadata)
        return atomic_write(path, lambda tmp: tmp.write_bytes(_sorted_header(blob)))

    @classmethod
    def load(cls, path: str | Path) -> "ActorCritic":
        """Read a saved actor-critic (tensors and plain containers only: ``weights_only=True``), with
        an error that says what is wrong with a missing, broken or foreign file."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"model file {str(path)!r} does not exist")
        data = read_safetensors(path) if path.suffix == SAFETENSORS_SUFFIX else load_tensors(path)
        return cls.from_dict(data, f"model file {str(path)!r}")


SAFETENSORS_SUFFIX = ".safetensors"


def _safetensors_torch():
    try:
        import safetensors.torch
    except ImportError as error:
        raise missing_extra("the native PPO models' .safetensors files", "train", error) from error
    return safetensors.torch


def _sorted_header(blob: bytes) -> bytes:
    """A safetensors file with its JSON header's keys sorted. The library writes them in the order of a
    hash map seeded anew each time, so the same model made different bytes at every write (and every
    publish rewrote every published file); the tensors' bytes and offsets stay as they are."""
    size = int.from_bytes(blob[:8], "little")
    header = json.dumps(json.loads(blob[8:8 + size]), sort_keys=True, separators=(",", ":")).encode()
    header += b" " * (-len(header) % 8)  # the format pads its header to a multiple of 8 bytes
    return len(header).to_bytes(8, "little") + header + blob[8 + size:]


def read_safetensors(path: str | Path) -> dict[str, Any]:
    """A ``.safetensors`` file of :meth:`ActorCritic.save_safetensors` as :meth:`ActorCritic.to_dict`'s
    layout (checked by :meth:`ActorCritic.from_dict`); a ValueError naming the file when it is broken or
    its header lacks or garbles a field."""
    _torch()
    _safetensors_torch()
    from safetensors import safe_open

    source = f"model file {str(path)!r}"
    try:
        with safe_open(str(path), framework="pt") as f:
            metadata = f.metadata() or {}
            tensors = {name: f.get_tensor(name) for name in f.keys()}
    except Exception as exc:  # noqa: BLE001 - safetensors raises its own kinds for a cut or foreign file
        raise ValueError(f"cannot read {source}: the file is broken or not safetensors ({type(exc).__name__}: "
                         f"{exc})") from exc
    try:
        return {"format": metadata.get("format"), "version": int(metadata.get("version", "")),
                "view": metadata.get("view"), "observation_size": int(metadata["observation_size"]),
                "n_actions": int(metadata["n_actions"]), "hidden": json.loads(metadata["hidden"]),
                "action_mask": json.loads(metadata["action_mask"]), "state_dict": tensors,
                "observation": metadata.get("observation", DEFAULT_OBSERVATION),
                "own_check": json.loads(metadata.get("own_check", "null")),
                "request_threshold": json.loads(metadata.get("request_threshold", "null")),
                "shared_check": json.loads(metadata.get("shared_check", "null")),
                "meta": json.loads(metadata.get("meta", "{}"))}
    except (KeyError, ValueError, TypeError) as exc:
        raise ValueError(f"{source}: its safetensors header lacks or garbles a field of the "
                         f"{FORMAT!r} format ({type(exc).__name__}: {exc})") from exc


#: What reading a broken zip archive raises besides BadZipFile: an encrypted member, an unknown
#: compression method, a corrupt compressed stream, a cut file.
ZIP_ERRORS = (zipfile.BadZipFile, OSError, EOFError, RuntimeError, NotImplementedError, zlib.error)


def load_tensors(path: str | Path, otherwise: str = "holds more than tensors") -> Any:
    """``torch.load(path, weights_only=True)``: plain containers and tensors, never pickled code;
    a ValueError naming the file when it is broken or ``otherwise`` (what else it may be), or when
    its members would unpack to more than the file holds (see :func:`check_unpacked_size`)."""
    torch = _torch()
    path = Path(path)
    try:
        with zipfile.ZipFile(path) as archive:
            check_unpacked_size(archive, path.stat().st_size, f"model file {str(path)!r}")
    except ZIP_ERRORS as exc:
        raise ValueError(f"cannot read model file {str(path)!r}: the file is broken or {otherwise} (not the zip "
                         f"archive torch.save writes: {exc})") from exc
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises many kinds for a cut, foreign or unsafe file
        raise ValueError(f"cannot read model file {str(path)!r}: the file is broken or {otherwise} "
                         f"({type(exc).__name__}: {exc})") from exc


def check_unpacked_size(archive: zipfile.ZipFile, size: int, source: str) -> None:
    """Refuse (a ValueError naming ``source``) a zip archive whose members declare more bytes than
    the ``size`` bytes that hold it. torch.save and SB3 store members uncompressed, so theirs never
    do; a compressed or overlapping member could unpack to gigabytes from a small file, and torch
    and SB3 read every member whole."""
    unpacked = sum(info.file_size for info in archive.infolist())
    if unpacked > size:
        raise ValueError(f"{source}: its members unpack to {unpacked} bytes, more than the {size} bytes of the "
                         f"archive (members are stored uncompressed)")


def check_network(observation_size: Any, n_actions: Any, hidden: Any, where: str = "model") -> tuple[int, int, list[int]]:
    """The sizes of a policy and a value network (input, actions, hidden widths) as ints, within the
    bounds of :mod:`containergym_marl.config.bounds` (a ValueError naming ``where`` and the rule
    otherwise); nothing is allocated."""
    try:
        obs, actions = operator.index(observation_size), operator.index(n_actions)
        widths = [operator.index(h) for h in hidden]
    except TypeError:
        raise ValueError(f"{where}: observation_size, n_actions and hidden must be integers, got "
                         f"{observation_size!r}, {n_actions!r}, {hidden!r}") from None
    if any(isinstance(x, bool) for x in (observation_size, n_actions, *hidden)) or obs < 1 or actions < 2:
        raise ValueError(f"{where}: bad network shape observation_size={observation_size!r}, n_actions={n_actions!r}")
    if not 1 <= len(widths) <= MAX_HIDDEN_LAYERS or not all(1 <= h <= MAX_HIDDEN_WIDTH for h in widths):
        raise ValueError(f"{where}: hidden={widths if len(widths) <= 32 else '[...]'} must list 1 to "
                         f"{MAX_HIDDEN_LAYERS} layer widths in [1, {MAX_HIDDEN_WIDTH}]")
    parameters = network_parameters(obs, actions, widths)
    if parameters > MAX_NETWORK_PARAMETERS:
        raise ValueError(f"{where}: a network of {obs} inputs, {actions} actions and hidden={widths} has {parameters} "
                         f"parameters, more than {MAX_NETWORK_PARAMETERS}")
    return obs, actions, widths


def network_parameters(observation_size: int, n_actions: int, hidden: Sequence[int]) -> int:
    """Weights and biases of the policy network (to ``n_actions`` logits) and the value network together."""
    return sum(mlp_parameters([observation_size, *hidden, out]) for out in (n_actions, 1))


def mlp_parameters(sizes: Sequence[int]) -> int:
    """Weights and biases of linear layers through ``sizes``."""
    return sum(a * b + b for a, b in zip(sizes[:-1], sizes[1:]))


def _shapes(observation_size: int, n_actions: int, hidden: list[int]) -> dict[str, tuple[int, ...]]:
    """The state dict's tensor shapes of an actor-critic of these sizes (Linear layers at even indices)."""
    shapes: dict[str, tuple[int, ...]] = {}
    for name, out in (("actor", n_actions), ("critic", 1)):
        sizes = [observation_size, *hidden, out]
        for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
            shapes[f"{name}.{2 * i}.weight"], shapes[f"{name}.{2 * i}.bias"] = (b, a), (b,)
    return shapes


def check_state_dict(state_dict: Any, shapes: dict[str, tuple[int, ...]], source: str) -> None:
    """``state_dict`` holds float tensors of exactly ``shapes`` (a ValueError naming ``source``, the
    first tensor that differs and its shape): checked before a network is built from a file."""
    torch = _torch()
    if not isinstance(state_dict, dict) or set(state_dict) != set(shapes):
        keys = sorted(state_dict)[:8] if isinstance(state_dict, dict) else type(state_dict).__name__
        raise ValueError(f"{source}: expected the weights {sorted(shapes)}, got {keys}")
    for key, shape in shapes.items():
        tensor = state_dict[key]
        if not (torch.is_tensor(tensor) and tensor.is_floating_point() and tuple(tensor.shape) == shape):
            got = (tensor.dtype, tuple(tensor.shape)) if torch.is_tensor(tensor) else type(tensor).__name__
            raise ValueError(f"{source}: {key} must be a float tensor of shape {shape}, got {got}")


def save_tensors(path: str | Path, data: Any, durable: bool = True) -> Path:
    """``torch.save(data)`` crash-safe (temporary file, then rename)."""
    from containergym_marl.files import atomic_write

    torch = _torch()
    return atomic_write(path, lambda tmp: torch.save(data, tmp), durable=durable)


class _ActorCriticPolicy:
    """Shared by the two views' adapters: the model, its name, greedy or sampled actions."""

    view = ""

    def __init__(self, model: ActorCritic | str | Path, name: str = "ppo", deterministic: bool = True):
        self.model = model if isinstance(model, ActorCritic) else ActorCritic.load(model)
        if self.model.view != self.view:
            raise ValueError(f"model: a {self.model.view} actor-critic cannot act in the {self.view} view")
        self.name, self.deterministic = name, deterministic
        #: the observation variant the model was trained on: evaluate() builds it, act() refuses another
        self.observation = self.model.observation
        from gymnasium import spaces

        # what evaluate() checks against the environment's observation space
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(self.model.observation_size,), dtype=np.float32)

    #: How the algorithm registry loads this adapter's model files.
    load_model = staticmethod(ActorCritic.load)

    def _action_tensor(self, observations: np.ndarray, masks: np.ndarray | None, logits=None):
        torch = _torch()
        with torch.no_grad():
            if logits is None:
                logits = self.model.decision_logits(torch.as_tensor(observations, dtype=torch.float32))
            if masks is not None:
                logits = logits.masked_fill(~torch.as_tensor(masks), MASKED_LOGIT)
            if self.deterministic:
                return self.model.greedy(logits)
            return torch.distributions.Categorical(logits=logits).sample()

    def _actions(self, observations: np.ndarray, masks: np.ndarray | None) -> list[int]:
        return self._action_tensor(observations, masks).tolist()

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
    forward per step), with the model's own check and shared check where it has them."""

    view = "decentralised"

    def __init__(self, model: ActorCritic | str | Path, name: str = "ppo", deterministic: bool = True):
        super().__init__(model, name, deterministic)
        self._shared_check: SharedCheck | None = None

    def bind(self, params: Any, arbitration: str = DEFAULT_ARBITRATION) -> "SharedActorCriticPolicy":
        """Bind the model's shared check to the plant ``params`` (a PlantParams) it acts in, whose requests
        ``arbitration`` ranks; nothing to do for a model without one. ``act`` binds it from its environment."""
        if self.model.shared_check is not None:
            bound = self._shared_check
            if bound is None or bound.params is not params or bound.arbitration != arbitration:
                self._shared_check = SharedCheck(self.model.shared_check, params, self.observation, arbitration)
        return self

    def _actions(self, observations: np.ndarray, masks: np.ndarray | None) -> list[int]:
        if self.model.shared_check is None:
            actions = self._action_tensor(observations, masks)
            if self.model.own_check is not None:
                actions.numpy()[own_deadline_due(observations, **self.model.own_check)] = 1  # in place, no copy
            return actions.tolist()
        if self._shared_check is None:
            raise ValueError(f"policy {self.name!r}: its model's shared check needs the plant it acts in: call "
                             "bind(params) first (evaluate() and evaluate_batched() do)")
        torch = _torch()
        logits = self.model.decision_logits(torch.as_tensor(observations, dtype=torch.float32))
        actions = self._action_tensor(observations, masks, logits).numpy()
        if self.model.own_check is not None:
            actions[own_deadline_due(observations, **self.model.own_check)] = 1
        return self._shared_check.requests_after(observations, actions, logits).tolist()

    def act(self, observations: dict[str, Any], env: Any) -> dict[str, int]:
        if getattr(env, "observation", DEFAULT_OBSERVATION) != self.observation:
            check_same_observation(self.observation, getattr(env, "observation", DEFAULT_OBSERVATION),
                                   f"policy {self.name!r}")
        if self.model.shared_check is not None:
            self.bind(env.simulator.params, env.simulator.arbitration)
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
    if not isinstance(data, dict) or not isinstance(data.get("format"), str) or data["format"] != fmt:
        raise ValueError(f"{source} is not a saved {what} (format {fmt!r})")
    if type(data.get("version")) is not int or data["version"] != version:
        raise ValueError(f"{source}: {what} version {data.get('version')!r}; this package reads version {version}")
