"""A shared actor saved as plain torch: one MLP that every container agent runs on its own
observation, loadable and evaluable without the library that trained it.

``baselines/train_mappo.py`` exports BenchMARL MAPPO's actor (a TorchRL ``MultiAgentMLP`` with
shared parameters) to this format, so that ``containergym-marl evaluate RUN`` and
:func:`~containergym_marl.evaluation.evaluate` run it with torch alone (the ``train`` extra's torch
is enough; BenchMARL and TorchRL are not imported)::

    from containergym_marl.evaluation import evaluate
    from containergym_marl.policies.shared_actor import SharedActor, SharedActorPolicy

    actor = SharedActor.load("runs/mappo_n5_m2_dt120_s1/best_model.pt")
    result = evaluate(SharedActorPolicy(actor, name="mappo"), "n5_m2_dt120")

The file (``torch.save`` of plain containers, read back with ``weights_only=True``)::

    {"format": "containergym-marl shared actor", "version": 1,
     "layers": [{"type": "Linear", "in": F, "out": 256}, {"type": "Tanh"}, ...,
                {"type": "Linear", "in": 256, "out": 2}],
     "state_dict": {"0.weight": ..., "0.bias": ..., ...},   # of torch.nn.Sequential(*layers)
     "meta": {...}}                                         # where it came from (config, algorithm, steps)

The network maps an agent's observation [F] to the logits of its two actions (0 wait, 1 request
emptying). Acting: requesting is masked while no PU is free (as in training, where BenchMARL's
masked categorical gets the env's ``action_mask``), then the mode of the masked distribution
(``deterministic=True``, the test protocol) or a sample from it.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from containergym_marl.config.bounds import MAX_HIDDEN_LAYERS, MAX_NETWORK_PARAMETERS
from containergym_marl.extras import missing_extra

FORMAT = "containergym-marl shared actor"
VERSION = 1
#: The activations a saved actor may use (torch.nn classes without arguments).
ACTIVATIONS = ("Tanh", "ReLU", "ELU", "GELU", "SiLU", "LeakyReLU", "Sigmoid", "Softplus", "Mish")


def _torch():
    try:
        import torch
    except ImportError as error:
        raise missing_extra("a saved shared actor", "train", error) from error
    return torch


def build_network(layers: list[dict[str, Any]]):
    """``torch.nn.Sequential`` of ``layers`` (``{"type": "Linear", "in": .., "out": ..}`` or an activation)."""
    torch = _torch()
    modules = []
    for layer in layers:
        kind = layer.get("type")
        if kind == "Linear":
            modules.append(torch.nn.Linear(int(layer["in"]), int(layer["out"])))
        elif kind in ACTIVATIONS:
            modules.append(getattr(torch.nn, kind)())
        else:
            raise ValueError(f"unknown layer {layer!r}; expected Linear or one of {ACTIVATIONS}")
    return torch.nn.Sequential(*modules)


def _checked_shapes(layers: Any, source: str) -> dict[str, tuple[int, ...]]:
    """The state dict's tensor shapes of ``layers`` (``torch.nn.Sequential`` indices), whose sizes are
    checked against the network bounds first, so that a file's header cannot make us allocate."""
    if not isinstance(layers, list) or not all(isinstance(layer, dict) for layer in layers):
        raise ValueError(f"{source}: layers must be a list of layer descriptions, got {type(layers).__name__}")
    shapes: dict[str, tuple[int, ...]] = {}
    for i, layer in enumerate(layers):
        if layer.get("type") == "Linear":
            sizes = (layer.get("out"), layer.get("in"))
            if not all(type(x) is int and x >= 1 for x in sizes):
                raise ValueError(f"{source}: layer {i} needs integer sizes in, out >= 1, got {layer!r}")
            shapes[f"{i}.weight"], shapes[f"{i}.bias"] = sizes, sizes[:1]
    parameters = sum(math.prod(shape) for shape in shapes.values())
    if len(shapes) // 2 > MAX_HIDDEN_LAYERS + 1 or parameters > MAX_NETWORK_PARAMETERS:
        raise ValueError(f"{source}: {len(shapes) // 2} Linear layers of {parameters} parameters; at most "
                         f"{MAX_HIDDEN_LAYERS + 1} layers and {MAX_NETWORK_PARAMETERS} parameters")
    return shapes


class SharedActor:
    """The network (a ``torch.nn.Sequential``), its layer list and where it came from (``meta``)."""

    def __init__(self, layers: list[dict[str, Any]], state_dict: dict[str, Any] | None = None,
                 meta: dict[str, Any] | None = None):
        linear = [layer for layer in layers if layer.get("type") == "Linear"]
        if not linear:
            raise ValueError("a shared actor needs at least one Linear layer")
        self.layers = [dict(layer) for layer in layers]
        self.meta = dict(meta or {})
        self.net = build_network(self.layers)
        if state_dict is not None:
            self.net.load_state_dict(state_dict)
        self.net.eval()
        self.observation_size = int(linear[0]["in"])
        self.n_actions = int(linear[-1]["out"])

    def logits(self, observations):
        """Logits [..., n_actions] of observations [..., F] (a tensor or an array)."""
        torch = _torch()
        x = torch.as_tensor(np.asarray(observations, dtype=np.float32)) if not torch.is_tensor(observations) \
            else observations.float()
        with torch.no_grad():
            return self.net(x)

    def to_dict(self) -> dict[str, Any]:
        return {"format": FORMAT, "version": VERSION, "layers": self.layers,
                "state_dict": {k: v.detach().cpu().clone() for k, v in self.net.state_dict().items()},
                "meta": self.meta}

    def save(self, path: str | Path) -> Path:
        """Write the file crash-safe (temporary file, then rename)."""
        from containergym_marl.policies.actor_critic import save_tensors

        return save_tensors(path, self.to_dict())

    @classmethod
    def load(cls, path: str | Path) -> "SharedActor":
        """Read a saved actor, with an error that says what is wrong with a missing or broken file."""
        from containergym_marl.policies.actor_critic import check_header, check_state_dict, load_tensors

        _torch()  # the missing extra is named before anything else
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"model file {str(path)!r} does not exist")
        data = load_tensors(path, otherwise="not a saved shared actor")
        source = f"model file {str(path)!r}"
        check_header(data, FORMAT, VERSION, source, "shared actor")
        check_state_dict(data.get("state_dict"), _checked_shapes(data.get("layers"), source), source)
        try:
            return cls(data["layers"], data["state_dict"], data.get("meta"))
        except (KeyError, RuntimeError, ValueError) as exc:
            raise ValueError(f"model file {str(path)!r}: its layers and weights do not match ({exc})") from exc


class SharedActorPolicy:
    """A :class:`SharedActor` acting for every container agent of the decentralised view (one batched
    forward per step); the policy adapter of ``mappo`` runs in the algorithm registry.

    Args:
        model: the actor (or a path to a saved one).
        name: the policy's name in evaluation results.
        deterministic: the mode of the masked distribution (test protocol) or a sample from it.
    """

    view = "decentralised"

    def __init__(self, model: SharedActor | str | Path, name: str = "shared_actor", deterministic: bool = True):
        self.model = model if isinstance(model, SharedActor) else SharedActor.load(model)
        self.name, self.deterministic = name, deterministic
        from gymnasium import spaces

        # what evaluate() checks against the environment's agent observation space
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(self.model.observation_size,), dtype=np.float32)

    #: How the algorithm registry loads this adapter's model files.
    load_model = staticmethod(SharedActor.load)

    def act(self, observations: dict[str, Any], env: Any) -> dict[str, int]:
        torch = _torch()
        agents = list(observations)
        obs = np.stack([o["observation"] if isinstance(o, dict) else o for o in observations.values()])
        logits = self.model.logits(obs)
        if not bool(env.simulator.free_pu_count()[0] > 0):  # the env's action_mask: [True, free PU]
            logits[:, 1] = -torch.inf
        if self.deterministic:
            actions = logits.argmax(-1)
        else:
            actions = torch.distributions.Categorical(logits=logits).sample()
        return {a: int(x) for a, x in zip(agents, actions.tolist())}

    def act_batch(self, observations: np.ndarray, masks: np.ndarray) -> np.ndarray:
        """The actions of any number of agents at once (N, F) -> (N,); ``masks[:, 1]``: a PU is free."""
        if not self.deterministic:
            raise ValueError("act_batch: deterministic policies only")
        torch = _torch()
        logits = self.model.logits(observations)
        logits[~torch.as_tensor(masks[:, 1]), 1] = -torch.inf
        return logits.argmax(-1).numpy().astype(np.int64)
