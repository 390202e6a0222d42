"""Model files: a run's model loaded without running code from it (:func:`load_model`).

An SB3 zip keeps the algorithm's attributes in its ``data`` member as JSON; the ones that are not
plain values (the policy class, the spaces, the schedules, buffers) are cloudpickle blobs under a
``":serialized:"`` key, which ``BaseAlgorithm.load`` unpickles, so a crafted file runs whatever
its blob says. The weights (``policy.pth`` and the others) are read by SB3 with
``torch.load(weights_only=True)`` already.

:func:`safe_custom_objects` replaces *every* serialized entry before SB3 sees it (its
``custom_objects`` argument, SB3's documented way), each with a value rebuilt from plain data:

* ``policy_class``: the algorithm's own ``MlpPolicy`` (the only policy this package trains);
* ``observation_space`` / ``action_space``: a ``Box`` from the numbers of its JSON description
  (shape, bounds, dtype) or a ``Discrete`` from its ``n``;
* schedules (``lr_schedule``, ``clip_range``, ``exploration_schedule``…): a constant or linear
  schedule parsed from their description (``ConstantSchedule(val=0.2)``);
* ``train_freq`` (DQN): from the run's settings (SB3's default, every 4 steps, when none is given);
* anything else (last observations, episode buffers, buffer classes): None, which SB3 rebuilds.

Entries that cannot be rebuilt this way are refused with a ValueError naming them; nothing is
ever unpickled. What the file declares is bounded before SB3 allocates anything from it
(:mod:`containergym_marl.config.bounds`): its members unpack to no more than the file holds, the
network that ``policy_kwargs.net_arch`` and the spaces describe, ``n_steps``, ``n_envs``,
``batch_size``, ``buffer_size`` and the memory of its buffers.
"""

from __future__ import annotations

import ast
import json
import math
import re
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from containergym_marl.algorithms import get_algorithm
from containergym_marl.config.bounds import (
    MAX_EPOCHS,
    MAX_HIDDEN_LAYERS,
    MAX_HIDDEN_WIDTH,
    MAX_MINIBATCH,
    MAX_N_STEPS,
    MAX_NETWORK_PARAMETERS,
    MAX_REPLAY_BUFFER,
    MAX_ROLLOUT_SAMPLES,
    MAX_SIMS,
    check_count,
    check_memory,
)
from containergym_marl.policies.actor_critic import ZIP_ERRORS, check_unpacked_size, mlp_parameters
from containergym_marl.rundir import check_model_file

SERIALIZED = ":serialized:"
_SCHEDULE = re.compile(r"^(ConstantSchedule|LinearSchedule)\((.*)\)$")
_ARGUMENT = re.compile(r"^\s*(\w+)\s*=\s*([-+0-9.eE]+|inf|nan)\s*$")


def _numbers(text: Any, what: str) -> np.ndarray:
    """A 1-D float array from numpy's printed form (``'[ 0.  80. 832.5585]'``)."""
    if not isinstance(text, str):
        raise ValueError(f"{what}: expected numpy's printed array, got {type(text).__name__}")
    body = text.strip()
    if not (body.startswith("[") and body.endswith("]")) or "..." in body:
        raise ValueError(f"{what}: not a complete printed array")
    try:
        return np.array([float(x) for x in body[1:-1].split()], dtype=np.float64)
    except ValueError as exc:
        raise ValueError(f"{what}: {exc}") from None


def _space(entry: dict, key: str):
    from gymnasium import spaces

    kind = str(entry.get(":type:", ""))
    if kind.endswith("spaces.discrete.Discrete'>"):
        try:
            n, start = int(entry["n"]), int(entry.get("start", 0))
            if not 1 <= n <= MAX_NETWORK_PARAMETERS:  # its actions are the outputs of a network
                raise ValueError(n)
            return spaces.Discrete(n, start=start)
        except (KeyError, TypeError, ValueError, OverflowError):
            raise ValueError(f"{key}: a Discrete space without a readable n in [1, {MAX_NETWORK_PARAMETERS}]") from None
    if kind.endswith("spaces.box.Box'>"):
        shape = entry.get("_shape")
        if not (isinstance(shape, list) and all(type(d) is int and d >= 0 for d in shape)):
            raise ValueError(f"{key}: a Box space without a readable shape")
        try:
            dtype = np.dtype(entry.get("dtype", "float32"))
        except TypeError:
            raise ValueError(f"{key}: a Box space of an unknown dtype {entry.get('dtype')!r}") from None
        if dtype.kind != "f":
            raise ValueError(f"{key}: a Box space of {dtype}; this package's models observe floats")
        size = math.prod(shape)
        low, high = _numbers(entry.get("low"), f"{key}.low"), _numbers(entry.get("high"), f"{key}.high")
        if low.size != size or high.size != size:
            raise ValueError(f"{key}: bounds of {low.size} and {high.size} numbers for a shape {shape}")
        return spaces.Box(low.reshape(shape).astype(dtype), high.reshape(shape).astype(dtype), dtype=dtype)
    raise ValueError(f"{key}: a space of type {kind or '?'}; only Box and Discrete are rebuilt")


def _schedule(entry: dict, key: str):
    from stable_baselines3.common.utils import ConstantSchedule, FloatSchedule, LinearSchedule

    if entry.get(":type:", "").endswith("utils.LinearSchedule'>"):  # its numbers are plain entries
        try:
            return LinearSchedule(float(entry["start"]), float(entry["end"]), float(entry["end_fraction"]))
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"{key}: a linear schedule without readable start, end and end_fraction") from None
    text = entry.get("value_schedule") if "FloatSchedule" in entry.get(":type:", "") else None
    m = _SCHEDULE.match(text.strip()) if isinstance(text, str) else None
    if m is None:
        raise ValueError(f"{key}: a schedule this package cannot rebuild from its description")
    kwargs = {}
    for part in filter(None, (p.strip() for p in m.group(2).split(","))):
        arg = _ARGUMENT.match(part)
        if arg is None:
            raise ValueError(f"{key}: unreadable schedule argument {part!r}")
        kwargs[arg.group(1)] = float(ast.literal_eval(arg.group(2)) if arg.group(2) not in ("inf", "nan")
                                     else float(arg.group(2)))
    try:
        inner = ConstantSchedule(**kwargs) if m.group(1) == "ConstantSchedule" else LinearSchedule(**kwargs)
    except TypeError as exc:
        raise ValueError(f"{key}: {exc}") from None
    return FloatSchedule(inner)


def _train_freq(hyperparams: dict[str, Any]):
    """An off-policy algorithm's training frequency, from the run's settings (SB3's default: every 4 steps)."""
    from stable_baselines3.common.type_aliases import TrainFreq, TrainFrequencyUnit

    value = hyperparams.get("train_freq", 4)
    if isinstance(value, (list, tuple)) and len(value) == 2:
        return TrainFreq(int(value[0]), TrainFrequencyUnit(value[1]))
    return TrainFreq(int(value), TrainFrequencyUnit.STEP)


def safe_custom_objects(path: str | Path, algorithm_class, hyperparams: dict[str, Any] | None = None) -> dict[str, Any]:
    """``custom_objects`` for ``algorithm_class.load(path, ...)`` that replace every serialized entry
    of the file's ``data`` (see the module docstring); a ValueError naming an entry that cannot be
    rebuilt, a file whose ``data`` is not a JSON object, or sizes beyond the bounds (:func:`check_sizes`).
    ``hyperparams``: the run's SB3 settings, which rebuild an off-policy algorithm's ``train_freq``
    for a resumed run."""
    source = f"model file {str(path)!r}"
    try:
        with zipfile.ZipFile(path) as z:
            check_unpacked_size(z, Path(path).stat().st_size, source)
            for info in z.infolist():  # the weights: torch files that SB3 reads whole
                if info.filename.endswith(".pth"):
                    with z.open(info) as member, zipfile.ZipFile(member) as weights:
                        check_unpacked_size(weights, info.file_size, f"{source}, member {info.filename!r}")
            data = json.loads(z.read("data"))
    except (*ZIP_ERRORS, KeyError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise ValueError(f"cannot read the data of {source}: {exc}") from exc
    if not isinstance(data, dict):
        raise ValueError(f"{source}: its data is not a JSON object")
    objects: dict[str, Any] = {}
    for key, value in data.items():
        if not (isinstance(value, dict) and SERIALIZED in value):
            continue
        kind = str(value.get(":type:", ""))
        if key == "policy_class":
            objects[key] = algorithm_class.policy_aliases["MlpPolicy"]
        elif key in ("observation_space", "action_space"):
            objects[key] = _space(value, key)
        elif "Schedule" in kind:
            objects[key] = _schedule(value, key)
        elif key == "train_freq":
            objects[key] = _train_freq(hyperparams or {})
        else:
            objects[key] = None
    missing = [key for key in ("policy_class", "observation_space", "action_space") if key not in objects]
    if missing:
        raise ValueError(f"{source}: no {', '.join(missing)}")
    check_sizes(data, objects["observation_space"], objects["action_space"], source)
    return objects


def sb3_networks(policy_kwargs: Any, where: str) -> list[list[int]]:
    """The hidden widths of each network an SB3 policy builds from ``policy_kwargs``: its ``net_arch``,
    a list of widths for every network (the policy and value networks, or DQN's network and its
    target) or ``{"pi": [...], "vf": [...]}``; SB3's default [64, 64]. A ValueError naming ``where``
    when they are not widths within the bounds."""
    if not isinstance(policy_kwargs, dict):
        raise ValueError(f"{where} must be a mapping, got {type(policy_kwargs).__name__}")
    arch = policy_kwargs.get("net_arch", [64, 64])
    parts = {part: arch.get(part, []) for part in ("pi", "vf", "qf")} if isinstance(arch, dict) else {"": arch}
    for part, widths in parts.items():
        if not (isinstance(widths, list) and len(widths) <= MAX_HIDDEN_LAYERS
                and all(type(h) is int and 1 <= h <= MAX_HIDDEN_WIDTH for h in widths)):
            shown = widths if len(repr(widths)) < 200 else type(widths).__name__
            raise ValueError(f"{where}.net_arch{'.' * bool(part)}{part} must list at most {MAX_HIDDEN_LAYERS} layer "
                             f"widths in [1, {MAX_HIDDEN_WIDTH}], got {shown}")
    return list(parts.values()) if isinstance(arch, dict) else [arch, arch]


def check_sizes(data: dict[str, Any], observation_space, action_space, source: str) -> None:
    """The sizes an SB3 model's ``data`` declares, within the bounds of
    :mod:`containergym_marl.config.bounds`, before SB3 builds the model from them: ``n_steps``,
    ``n_envs``, ``batch_size``, ``n_epochs``, ``buffer_size``, the networks of ``policy_kwargs.net_arch``
    (a list of widths, or ``{"pi": [...], "vf": [...]}``; SB3's default [64, 64]) on these spaces, and
    the memory of its buffers and networks. A ValueError naming ``source`` and the entry otherwise."""
    for key, hi in (("n_steps", MAX_N_STEPS), ("n_envs", MAX_SIMS), ("batch_size", MAX_MINIBATCH),
                    ("n_epochs", MAX_EPOCHS), ("buffer_size", MAX_REPLAY_BUFFER)):
        if key in data:
            check_count(data[key], 1, hi, f"{source}: {key}")
    nets = sb3_networks(data.get("policy_kwargs") or {}, f"{source}: policy_kwargs")
    inputs = math.prod(observation_space.shape)
    outputs = int(getattr(action_space, "n", 0)) or math.prod(action_space.shape)
    parameters = sum(mlp_parameters([inputs, *widths, outputs]) for widths in nets)
    if parameters > MAX_NETWORK_PARAMETERS:
        raise ValueError(f"{source}: policy_kwargs.net_arch={nets} on {inputs} inputs and {outputs} actions makes "
                         f"networks of {parameters} parameters, more than {MAX_NETWORK_PARAMETERS}")
    estimate = {"policy_kwargs.net_arch": parameters * 4 * 4}  # weights, gradients, Adam's two moments
    if "n_steps" in data:
        samples = data["n_steps"] * data.get("n_envs", 1)
        if samples > MAX_ROLLOUT_SAMPLES:
            raise ValueError(f"{source}: n_steps × n_envs = {samples} samples per rollout, more than "
                             f"{MAX_ROLLOUT_SAMPLES}")
        estimate["n_steps"] = samples * (inputs + 8) * 4 * 2  # SB3's rollout buffer and its flattened copy
    if "buffer_size" in data:
        estimate["buffer_size"] = data["buffer_size"] * (2 * inputs + 5) * 4  # observations, next ones, the rest
    check_memory(estimate, source)


def load_model(path: str | Path, algo: str, env=None, hyperparams: dict[str, Any] | None = None):
    """Load a model file of ``algo`` with a clear error when it is missing, broken or not a model of
    ``algo``: an SB3 model, or for an algorithm trained outside SB3 (mappo) what its policy
    adapter's ``load_model`` reads (``env`` is then unused)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"model file {str(path)!r} does not exist")
    spec = get_algorithm(algo)
    if not spec.sb3:
        return spec.policy_adapter.load_model(path)
    cls = spec.load_class()
    check_model_file(path)
    objects = safe_custom_objects(path, cls, hyperparams)  # every pickled entry replaced: nothing from the file runs
    try:
        return cls.load(path, env=env, device="cpu", custom_objects=objects)
    except MemoryError:  # the sizes were bounded above: not the file's doing
        raise
    except Exception as exc:  # noqa: BLE001 - SB3 raises many kinds for settings a crafted file declares
        raise ValueError(f"cannot read model file {str(path)!r} as a {algo} model: {exc}") from exc
