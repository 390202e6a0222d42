"""A method's training settings from its file, ``configs/hyperparams/<method>.toml`` (rl-baselines3-zoo's
``hyperparams/`` folder is the model): what ``train`` and ``compare`` use for the method where the
command line gives no ``--hp``.

A file holds one ``[settings]`` table of the trainer's settings (``--hp`` keys: the fields of the
native trainers' ``PPOArgs``) and a ``source`` line saying where they come from (a search's trial,
or the trainer's defaults)::

    source = "studies/native_ppo_tuning.py, trial 7 (results/ppo_tuning/fast_shared_ppo/trials.md)"

    [settings]
    learning_rate = 0.0003
    n_epochs = 10

A run records the settings it trained with in its ``args.json``; a resumed run takes them from
there, not from the file as it is now. Methods without a file train at their algorithm's defaults
(the SB3 methods: the paper's settings).
"""

from __future__ import annotations

import math
from importlib import resources
from pathlib import Path
from typing import Any

from containergym_marl.config.bounds import MAX_CONFIG_DEPTH, SAFE_NAME
from containergym_marl.config.loading import _nesting_depth, tomllib
from containergym_marl.files import atomic_write_text, open_file

_MAX_FILE_BYTES = 64 * 1024


def hyperparams_dir() -> Path:
    """The folder of the files (``configs/hyperparams``, package data of ``containergym_marl.configs``)."""
    return Path(str(resources.files("containergym_marl.configs") / "hyperparams"))


def settings_file(method: str) -> Path:
    """The file of ``method``'s settings (it need not exist)."""
    if not SAFE_NAME.fullmatch(method):
        raise ValueError(f"method: {method!r} is not a method name")
    return hyperparams_dir() / f"{method}.toml"


def read_settings(path: str | Path) -> tuple[dict[str, Any], str]:
    """The settings and source of one file; a ValueError naming the file and the offending key."""
    path = Path(path)
    with open_file(path, "rb") as f:
        raw = f.read(_MAX_FILE_BYTES + 1)
    if len(raw) > _MAX_FILE_BYTES:
        raise ValueError(f"{path}: larger than {_MAX_FILE_BYTES} bytes; not a settings file")
    try:
        text = raw.decode("utf-8")
        if _nesting_depth(text, toml=True) > MAX_CONFIG_DEPTH:  # the plant configs' bound, before parsing
            raise ValueError(f"nested deeper than {MAX_CONFIG_DEPTH} levels")
        data = tomllib.loads(text)
    except (UnicodeDecodeError, ValueError) as exc:  # TOMLDecodeError is a ValueError
        raise ValueError(f"{path}: not a TOML file ({exc})") from None
    unknown = sorted(set(data) - {"source", "settings"})
    if unknown:
        raise ValueError(f"{path}: unknown key(s) {unknown}; expected 'source' and a [settings] table")
    source, settings = data.get("source", ""), data.get("settings", {})
    if not isinstance(source, str) or not isinstance(settings, dict):
        raise ValueError(f"{path}: 'source' must be a string and 'settings' a table")
    for key, value in settings.items():
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"{path}: settings.{key} = {value} is not a finite number")
        if not isinstance(value, (bool, int, float, str)) and not (
                isinstance(value, list) and all(isinstance(v, int) and not isinstance(v, bool) for v in value)):
            raise ValueError(f"{path}: settings.{key} must be a number, a boolean, a string or a list of "
                             f"integers, got {value!r}")
    return dict(settings), source


def method_settings(method: str) -> dict[str, Any]:
    """``method``'s settings from its file; {} when it has none."""
    path = settings_file(method)
    return read_settings(path)[0] if path.is_file() else {}


def write_settings(path: str | Path, settings: dict[str, Any], source: str) -> None:
    """Write a settings file (crash-safe): ``source`` and the ``[settings]`` table, keys sorted."""
    def value(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(str(int(x)) for x in v) + "]"
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        return repr(v)

    lines = [f"source = {value(source)}", "", "[settings]"]
    lines += [f"{key} = {value(settings[key])}" for key in sorted(settings)]
    atomic_write_text(Path(path), "\n".join(lines) + "\n")
    read_settings(path)  # what was written reads back


__all__ = ["hyperparams_dir", "method_settings", "read_settings", "settings_file", "write_settings"]
