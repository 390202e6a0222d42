"""Loading configs: the built-in ones (package data, ``containergym_marl.configs``) and files in our
TOML or JSON format or the reference JSON format, read within size and nesting limits, refusing
duplicate keys and huge integers; then the test protocol and overrides.
"""

from __future__ import annotations

import json
import re
try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the same parser as the tomli package
    import tomli as tomllib
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

from containergym_marl.config.bounds import MAX_CONFIG_BYTES, MAX_CONFIG_DEPTH, ConfigError
from containergym_marl.config.reference_format import config_from_reference_json
from containergym_marl.config.schema import PlantConfig, config_from_dict

#: The paper's test protocol (section 6.1): every policy is evaluated with δ = 120 s and T = 600.
PAPER_TEST_PROTOCOL: Mapping[str, Any] = {"timestep_s": 120.0, "episode_length_steps": 600}
_PROTOCOLS = {"paper_test": PAPER_TEST_PROTOCOL}


# ---- files and built-ins -------------------------------------------------------------------
def _builtin_dir():
    return resources.files("containergym_marl.configs")


def list_configs() -> list[str]:
    """Names of the built-in configurations: the paper's eight rows, the 16-container plant and the
    larger plants built from it (``configs/scaled.py``), by containers, then PUs, then δ."""
    names = (p.name[: -len(".toml")] for p in _builtin_dir().iterdir() if p.name.endswith(".toml"))
    return sorted(names, key=config_sort_key)


def config_sort_key(name: str) -> tuple:
    """The paper's order of plant names: by containers, then PUs, then δ (n5_m2_dt60 < n5_m2_dt120 <
    n5_m5_dt60 < n11…); names of another form after them, alphabetically."""
    match = re.match(r"n(\d+)_m(\d+)_dt(\d+)", name)
    return (0, *map(int, match.groups()), name) if match else (1, 0, 0, 0, name)


class _HugeInteger:
    """A JSON integer too long to be any config value, kept as a marker so that the field that holds
    it is named when it is refused (int() itself refuses past 4300 digits, naming nothing)."""

    def __init__(self, digits: int):
        self.digits = digits

    def __repr__(self) -> str:
        return f"<an integer of {self.digits} digits>"


def _json_int(text: str) -> "int | _HugeInteger":
    return int(text) if len(text.lstrip("-")) <= 30 else _HugeInteger(len(text.lstrip("-")))


def _reject_duplicate_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    keys = [k for k, _ in pairs]
    dup = sorted({k for k in keys if keys.count(k) > 1})
    if dup:
        raise ConfigError(f"duplicate key(s) {dup} (the last value would silently win)")
    return dict(pairs)


def _nesting_depth(text: str, toml: bool = False) -> int:
    """The deepest nesting of a JSON or TOML text, outside strings (and TOML's comments): brackets,
    plus, for TOML, the dots of a dotted key or table name (``a.b.c = 1`` nests two tables). A cheap
    upper bound, read before the parser runs: json recurses per bracket, and tomllib needs memory that
    grows with the square of a key's parts (100,000 of them took 24 GB)."""
    depth = deepest = dots = 0
    i, size = 0, len(text)
    while i < size:
        ch = text[i]
        if ch == '"' or ch == "'":
            i = _string_end(text, i, toml)
            continue
        if ch == "#" and toml:
            i = text.find("\n", i)
            if i < 0:
                break
            continue
        if ch in "[{":
            depth += 1
            dots = 0
        elif ch in "]}":
            depth -= 1
            dots = 0
        elif ch in ",=\n":  # a key ends: a value, the next key or the next line follows
            dots = 0
        elif ch == "." and toml:  # a key of dots + 1 parts (a float's or a time's one dot: a slight overestimate)
            dots += 1
            deepest = max(deepest, depth + dots + 1)
        deepest = max(deepest, depth)
        i += 1
    return deepest


def _string_end(text: str, start: int, toml: bool) -> int:
    """The index after the string that starts at ``start``, as the parser reads it: TOML's multi-line
    strings (three quotes; up to two more quotes belong to the content) and literal strings (no
    escapes); a one-line string ends at the line's end at the latest (the parser refuses it there)."""
    quote = text[start]
    if toml and text.startswith(quote * 3, start):
        i = start + 3
        while True:
            i = text.find(quote * 3, i)
            if i < 0:
                return len(text)
            if quote == '"' and _escaped(text, i):
                i += 1
                continue
            end = i + 3
            while end < min(i + 5, len(text)) and text[end] == quote:
                end += 1
            return end
    i = start + 1
    while i < len(text):
        ch = text[i]
        if ch == "\n":
            return i
        if ch == "\\" and quote == '"':
            i += 2
            continue
        if ch == quote:
            return i + 1
        i += 1
    return i


def _escaped(text: str, i: int) -> bool:
    """The character at ``i`` follows an odd number of backslashes."""
    j = i
    while j > 0 and text[j - 1] == "\\":
        j -= 1
    return (i - j) % 2 == 1


def _read_file(path: Path) -> PlantConfig:
    if path.suffix not in (".toml", ".json"):  # before reading: a device or a huge file is never read
        raise ConfigError(f"config file {str(path)!r}: expected a .toml or .json file")
    try:
        if path.exists() and not path.is_file():
            raise ConfigError(f"cannot read config file {str(path)!r}: not a regular file")
        size = path.stat().st_size
        if size > MAX_CONFIG_BYTES:
            raise ConfigError(f"config file {str(path)!r}: {size} bytes, more than the {MAX_CONFIG_BYTES} a "
                              f"config may have")
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"cannot read config file {str(path)!r}: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"config file {str(path)!r} is not UTF-8 text (byte {exc.start}: {exc.reason})"
        ) from exc
    if _nesting_depth(text, toml=path.suffix == ".toml") > MAX_CONFIG_DEPTH:
        raise ConfigError(f"config file {str(path)!r}: lists, tables or dotted keys nested deeper than "
                          f"{MAX_CONFIG_DEPTH} levels")
    try:
        if path.suffix == ".toml":
            data = tomllib.loads(text)  # TOML itself refuses a key defined twice
        else:
            data = json.loads(text, object_pairs_hook=_reject_duplicate_keys, parse_int=_json_int)
    except ConfigError as exc:
        raise ConfigError(f"config file {str(path)!r}: {exc}") from None
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"config file {str(path)!r} is not valid {path.suffix[1:].upper()}: {exc}") from exc
    except (RecursionError, ValueError) as exc:  # a 5000-digit integer: Python's digit limit
        raise ConfigError(f"config file {str(path)!r}: unreadable ({exc})") from None
    if isinstance(data, Mapping) and "ENABLED_CONTAINERS" in data:
        return config_from_reference_json(data, name=path.stem)
    return config_from_dict(data, default_name=path.stem)


def load_config(
    name_or_path: "str | Path | PlantConfig",
    *,
    protocol: str | None = None,
    **overrides: Any,
) -> PlantConfig:
    """Load a validated, immutable config.

    Args:
        name_or_path: a built-in name (see :func:`list_configs`), a path to a ``.toml`` file in our
            format or a ``.json`` file in ours or the reference format, or a :class:`PlantConfig`.
        protocol: ``"paper_test"`` applies the paper's test protocol (δ = 120 s, T = 600).
        **overrides: plant-level fields to replace, e.g. ``timestep_s=60``; applied after
            ``protocol``.
    """
    if isinstance(name_or_path, PlantConfig):
        cfg = name_or_path
    else:
        text = str(name_or_path)
        builtin = _builtin_dir() / f"{text}.toml"
        if isinstance(name_or_path, str) and "/" not in text and builtin.is_file():
            cfg = config_from_dict(tomllib.loads(builtin.read_text(encoding="utf-8")), default_name=text)
        else:
            path = Path(text)
            if not path.exists():
                raise ConfigError(
                    f"unknown config {text!r}: not a built-in name ({', '.join(list_configs())}) "
                    f"and no such file"
                )
            cfg = _read_file(path)
    if protocol is not None:
        if protocol not in _PROTOCOLS:
            raise ConfigError(f"protocol: unknown protocol {protocol!r}; known: {sorted(_PROTOCOLS)}")
        cfg = cfg.replace(**_PROTOCOLS[protocol])
    if overrides:
        cfg = cfg.replace(**overrides)
    return cfg
