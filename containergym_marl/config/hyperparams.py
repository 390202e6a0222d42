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

Settings may depend on the plant's size, where a search found that what suits the small plants loses
on the large ones (rl-baselines3-zoo keeps settings per environment for the same reason). Each
``[[by_size]]`` entry holds a ``min_containers``, its own ``source`` and ``[by_size.settings]``; a plant of
n containers takes the entry of the largest ``min_containers`` <= n, in place of ``[settings]``
(whole settings, not merged: a setting is one point of the search)::

    [[by_size]]
    min_containers = 11
    source = "studies/native_ppo_tuning.py, trial 8 on the plants of 11 and 16 containers"

    [by_size.settings]
    learning_rate = 0.0002

An entry may also name the plant's decision interval ``timestep_s`` or its number of PUs
``num_processing_units``; it then applies only to plants of that value (rl-baselines3-zoo keeps settings
per environment: a setting chosen on one row, e.g. how far ahead an agent's own check looks where two PUs
serve eleven containers at δ = 60 s, need not suit another). A plant takes, of the entries that apply to
it, the one naming the most of these two, then the one of the largest ``min_containers`` (then the later
in the file)::

    [[by_size]]
    min_containers = 11
    num_processing_units = 2
    timestep_s = 60.0
    source = "studies/own_check_screen.py on n11_m2_dt60"

    [by_size.settings]
    own_check_lead_steps = 2

A run records the settings it trained with in its ``args.json``; a resumed run takes them from
there, not from the file as it is now. Methods without a file train at their algorithm's defaults
(the SB3 methods: the paper's settings).
"""

from __future__ import annotations

import math
from importlib import resources
from pathlib import Path
from typing import Any

from containergym_marl.config.bounds import MAX_CONFIG_DEPTH, MAX_TIMESTEP_S, MIN_TIMESTEP_S, SAFE_NAME
from containergym_marl.config.loading import _nesting_depth, tomllib
from containergym_marl.files import atomic_write_text, open_file

_MAX_FILE_BYTES = 64 * 1024
#: the plant fields a [[by_size]] entry may name besides min_containers (the PlantConfig's names)
PLANT_KEYS = ("timestep_s", "num_processing_units")


def hyperparams_dir() -> Path:
    """The folder of the files (``configs/hyperparams``, package data of ``containergym_marl.configs``)."""
    return Path(str(resources.files("containergym_marl.configs") / "hyperparams"))


def settings_file(method: str) -> Path:
    """The file of ``method``'s settings (it need not exist)."""
    if not SAFE_NAME.fullmatch(method):
        raise ValueError(f"method: {method!r} is not a method name")
    return hyperparams_dir() / f"{method}.toml"


def read_settings(path: str | Path, n_containers: int | None = None, *, timestep_s: float | None = None,
                  num_processing_units: int | None = None) -> tuple[dict[str, Any], str]:
    """The settings and source of one file for a plant of ``n_containers``, ``timestep_s`` and
    ``num_processing_units`` (its ``[[by_size]]`` entry where one applies; None: the ``[settings]`` table);
    a ValueError naming the file and the offending key. Every entry is checked, whichever applies."""
    return _pick(read_settings_file(path), n_containers, {"timestep_s": timestep_s,
                                                           "num_processing_units": num_processing_units})


def read_settings_file(path: str | Path) -> dict[str, Any]:
    """The whole file: ``{"settings", "source", "by_size": [{"min_containers", "timestep_s",
    "num_processing_units", "source", "settings"}]}`` (None where an entry names no timestep_s or
    num_processing_units), ``by_size`` sorted by ``min_containers``; a ValueError naming the file and the
    offending key."""
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
    unknown = sorted(set(data) - {"source", "settings", "by_size"})
    if unknown:
        raise ValueError(f"{path}: unknown key(s) {unknown}; expected 'source', a [settings] table and "
                         f"[[by_size]] entries")
    source, settings = _table(path, data, "")
    entries = data.get("by_size", [])
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise ValueError(f"{path}: 'by_size' must be a list of tables ([[by_size]])")
    by_size = []
    for k, entry in enumerate(entries):
        where = f"by_size[{k}]"
        unknown = sorted(set(entry) - {"min_containers", *PLANT_KEYS, "source", "settings"})
        if unknown:
            raise ValueError(f"{path}: {where}: unknown key(s) {unknown}; expected 'min_containers', "
                             f"'timestep_s', 'num_processing_units', 'source' and 'settings'")
        size = entry.get("min_containers")
        if isinstance(size, bool) or not isinstance(size, int) or size < 1:
            raise ValueError(f"{path}: {where}.min_containers must be an integer >= 1, got {size!r}")
        if "settings" not in entry:
            raise ValueError(f"{path}: {where}: no settings table")
        timestep, pus = entry.get("timestep_s"), entry.get("num_processing_units")
        if timestep is not None and (isinstance(timestep, bool) or not isinstance(timestep, (int, float))
                                     or not MIN_TIMESTEP_S <= timestep <= MAX_TIMESTEP_S):
            raise ValueError(f"{path}: {where}.timestep_s must be a number of seconds in "
                             f"[{MIN_TIMESTEP_S}, {MAX_TIMESTEP_S}], got {timestep!r}")
        if pus is not None and (isinstance(pus, bool) or not isinstance(pus, int) or pus < 1):
            raise ValueError(f"{path}: {where}.num_processing_units must be an integer >= 1, got {pus!r}")
        entry_source, entry_settings = _table(path, entry, f"{where}.")
        by_size.append({"min_containers": size, "timestep_s": None if timestep is None else float(timestep),
                        "num_processing_units": pus, "source": entry_source, "settings": entry_settings})
    keys = [(e["min_containers"], e["timestep_s"], e["num_processing_units"]) for e in by_size]
    if len(set(keys)) != len(keys):
        raise ValueError(f"{path}: by_size: min_containers {sorted(e[0] for e in keys)} names a size twice "
                         f"(for the same timestep_s and num_processing_units)")
    return {"settings": settings, "source": source, "by_size": sorted(by_size, key=lambda e: e["min_containers"])}


def _table(path: Path, data: dict[str, Any], where: str) -> tuple[str, dict[str, Any]]:
    """(source, settings) of the file's top level or of one by_size entry, every value checked."""
    source, settings = data.get("source", ""), data.get("settings", {})
    if not isinstance(source, str) or not isinstance(settings, dict):
        raise ValueError(f"{path}: '{where}source' must be a string and '{where}settings' a table")
    for key, value in settings.items():
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"{path}: {where}settings.{key} = {value} is not a finite number")
        if not isinstance(value, (bool, int, float, str)) and not (
                isinstance(value, list) and all(isinstance(v, int) and not isinstance(v, bool) for v in value)):
            raise ValueError(f"{path}: {where}settings.{key} must be a number, a boolean, a string or a list of "
                             f"integers, got {value!r}")
    return source, dict(settings)


def _pick(whole: dict[str, Any], n_containers: int | None,
          plant: dict[str, float | int | None]) -> tuple[dict[str, Any], str]:
    """(settings, source) for a plant of ``n_containers`` and ``plant``'s PLANT_KEYS values: of the by_size
    entries of min_containers <= n whose PLANT_KEYS are none or the plant's, the one naming the most of
    them, then the largest min_containers; else the [settings] table."""
    def applies(e):
        same = all(e[k] is None or (plant.get(k) is not None and math.isclose(e[k], plant[k])) for k in PLANT_KEYS)
        return n_containers is not None and e["min_containers"] <= n_containers and same

    chosen = sorted((e for e in whole["by_size"] if applies(e)),
                    key=lambda e: (sum(e[k] is not None for k in PLANT_KEYS), e["min_containers"]))
    entry = chosen[-1] if chosen else whole
    return dict(entry["settings"]), entry["source"]


def _file_settings(method: str, n_containers: int | None, **plant_keys) -> dict[str, Any]:
    path = settings_file(method)
    return read_settings(path, n_containers, **plant_keys)[0] if path.is_file() else {}


def method_settings(method: str, n_containers: int | None = None) -> dict[str, Any]:
    """``method``'s settings from its file for a plant of ``n_containers`` (None: its [settings] table,
    for any size; entries naming a plant's timestep_s or PUs apply only through :func:`plant_settings`);
    {} when it has none."""
    return _file_settings(method, n_containers)


def plant_settings(method: str, plant) -> dict[str, Any]:
    """``method``'s settings from its file for the plant ``plant`` (a PlantConfig); {} when it has none."""
    return _file_settings(method, plant.n_containers, timestep_s=plant.timestep_s,
                          num_processing_units=plant.num_processing_units)


def write_settings(path: str | Path, settings: dict[str, Any], source: str,
                   by_size: list[tuple] = ()) -> None:
    """Write a settings file (crash-safe): ``source`` and the ``[settings]`` table, keys sorted, then
    one ``[[by_size]]`` entry per (min_containers, settings, source[, {PLANT_KEYS key: value}]) of
    ``by_size``."""
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
    for size, entry_settings, entry_source, *plant in sorted(by_size, key=lambda e: e[0]):
        lines += ["", "[[by_size]]", f"min_containers = {int(size)}"]
        lines += [f"{k} = {value(v)}" for k, v in sorted((plant[0] if plant else {}).items())]
        lines += [f"source = {value(entry_source)}", "", "[by_size.settings]"]
        lines += [f"{key} = {value(entry_settings[key])}" for key in sorted(entry_settings)]
    atomic_write_text(Path(path), "\n".join(lines) + "\n")
    read_settings_file(path)  # what was written reads back


__all__ = ["PLANT_KEYS", "hyperparams_dir", "method_settings", "plant_settings", "read_settings", "read_settings_file", "settings_file",
           "write_settings"]
