"""Plant configurations: frozen, validated, loaded from our TOML files or the reference JSON format
(read by :mod:`containergym_marl.reference_format`).

A :class:`PlantConfig` is the immutable description of one plant (the paper's "instance"):
its containers, its processing units (PUs) and the episode settings. The physics core never reads
a config directly: it reads :class:`~containergym_marl.core.params.PlantParams`, the array form
derived from it by ``PlantParams.from_config`` (the config knows nothing of the core).

Units: volumes in the plant's volume units, times in seconds, rates per second.

Bounds
------
Every config is checked against these bounds when it is built (loaded, overridden or constructed
by hand); a value outside them raises :class:`ConfigError` naming the field (and the container for
per-container fields). They keep every volume, timer, reward and observation bound finite, and
leave room far beyond the paper's plants (n ≤ 16, v_max = 40, δ ≤ 120 s, T ≤ 1500).

==========================  ====================================================  ==================
field                       bound                                                 constant
==========================  ====================================================  ==================
containers (n)              1 ≤ n ≤ 1024, distinct non-empty names                MAX_CONTAINERS
num_processing_units (m)    integer, 1 ≤ m ≤ 1024 (m > n is allowed)              MAX_PROCESSING_UNITS
timestep_s (δ)              1e-3 ≤ δ ≤ 1e7 s                                      MIN/MAX_TIMESTEP_S
episode_length_steps (T)    integer, 1 ≤ T ≤ 10**9                                MAX_EPISODE_LENGTH_STEPS
penalty_reward (r_pen)      r_min < r_pen < 0                                     –
overflow_reward (r_min)     -1e6 ≤ r_min < r_pen                                  MIN_OVERFLOW_REWARD
initial_volume_min/max      0 ≤ min ≤ max < every container's max_volume          –
max_volume (v_max)          1e-3 ≤ v_max ≤ 1e12                                   MIN/MAX_VOLUME
product_size (b)            1e-3 ≤ b ≤ 1e12                                       MIN/MAX_VOLUME
fill_rate_per_s (μ)         0 ≤ μ ≤ 1e12 per second                               MAX_RATE
fill_noise_per_sqrt_s (σ)   0 ≤ σ ≤ 1e12 per √second                              MAX_RATE
pu_offset_s (β)             0 < β ≤ 1e9 s                                         MAX_PU_DURATION_S
pu_time_per_product_s (λ)   0 < λ ≤ 1e9 s                                         MAX_PU_DURATION_S
longest PU time             β + λ·⌊v_max / b⌋ ≤ 1e12 s (named as λ's error)        MAX_PU_TIME_S
reward_peaks (v*_k)         0 < v*_k ≤ v_max, at least one                        –
reward_heights (h_k)        0 < h_k ≤ 1                                           –
reward_widths (w_k)         1e-3 ≤ w_k ≤ 1e12                                     MIN/MAX_VOLUME
simulations B (num_sims)   integer, 1 ≤ B ≤ 2**24 (checked by PlantSimulator     MAX_SIMS
                            and the vector envs: ValueError naming the argument)
==========================  ====================================================  ==================

Every number must be a finite real (bools and strings are refused). Integer fields take integral
values of any numeric type (``600``, ``600.0``, ``np.int64(600)``, ``np.float32(600)``) and refuse
non-integral ones (``600.5``). Why these limits: with tiny widths 2w² underflows to 0 and
``exp(-d²/2w²)`` became NaN (w = 1e-160) or a ZeroDivisionError (1e-200); timers up to 1e12 s
still count down by δ ≥ 1e-3 s (float64 resolves 1.2e-4 s at 1e12); volumes, rates and durations
within these limits keep volumes and the float32 observation bounds finite; r_min ≥ -1e6 keeps
sums of n penalties finite; m, n and B bound memory.
"""

from __future__ import annotations

import dataclasses
import json
import math
import operator
import re
try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the same parser as the tomli package
    import tomli as tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

__all__ = [
    "MAX_SIMS",
    "MAX_CONTAINERS",
    "MAX_EPISODE_LENGTH_STEPS",
    "MAX_PROCESSING_UNITS",
    "ConfigError",
    "ContainerSpec",
    "PlantConfig",
    "PAPER_TEST_PROTOCOL",
    "load_config",
    "list_configs",
    "config_from_dict",
]

#: The paper's test protocol (section 6.1): every policy is evaluated with δ = 120 s and T = 600.
PAPER_TEST_PROTOCOL: Mapping[str, Any] = {"timestep_s": 120.0, "episode_length_steps": 600}
_PROTOCOLS = {"paper_test": PAPER_TEST_PROTOCOL}

# ---- bounds (the table in the module docstring) ----------------------------------------------
MAX_CONTAINERS = 1024
MAX_PROCESSING_UNITS = 1024
MIN_TIMESTEP_S = 1e-3
MAX_TIMESTEP_S = 1e7
MAX_EPISODE_LENGTH_STEPS = 10**9
MIN_OVERFLOW_REWARD = -1e6
#: smallest and largest v_max, product size and reward width (volume units)
MIN_VOLUME = 1e-3
MAX_VOLUME = 1e12
#: largest fill rate μ (per s) and fill noise σ (per √s)
MAX_RATE = 1e12
#: largest β and λ (s)
MAX_PU_DURATION_S = 1e9
#: largest PU busy time β + λ·⌊v_max / b⌋ (s)
MAX_PU_TIME_S = 1e12
#: largest number of simulations B (num_sims) of a simulator or vector env (checked there, not in the config)
MAX_SIMS = 2**24


class ConfigError(ValueError):
    """An invalid plant configuration. The message names the offending field and container."""


def _field(toml_comment: str):
    """A required numeric field; its comment (symbol and unit) is written beside it by ``to_toml``.
    (Required: ``dataclasses.MISSING`` default, so a field left out is a TypeError, as without it.)"""
    return dataclasses.field(metadata={"toml": toml_comment})


@dataclass(frozen=True)
class ContainerSpec:
    """One container and how its material is processed.

    Attributes:
        name: container name, e.g. ``"C1-20"``; also the agent name in the decentralised view.
        fill_rate_per_s: drift μ of the fill random walk (volume units per second).
        fill_noise_per_sqrt_s: σ of the fill random walk; a step of δ seconds adds N(μδ, σ²δ).
        max_volume: capacity v_max; reaching it ends the episode with the overflow reward.
        product_size: volume b of one product (bale).
        pu_offset_s: β, time to actuate a PU before products are made (s).
        pu_time_per_product_s: λ, PU time per product (s); a PU is busy β + λ⌊v/b⌋ seconds.
        reward_peaks: optimal emptying volumes v*_k.
        reward_heights: heights h_k ∈ (0, 1] of the reward peaks.
        reward_widths: widths w_k > 0 of the reward peaks.
    """

    name: str
    fill_rate_per_s: float = _field("mu, volume units per second")
    fill_noise_per_sqrt_s: float = _field("sigma; a step adds N(mu*delta, sigma^2*delta)")
    max_volume: float = _field("v_max, volume units")
    product_size: float = _field("b, volume units per product")
    pu_offset_s: float = _field("beta, seconds to actuate a PU")
    pu_time_per_product_s: float = _field("lambda, seconds per product")
    reward_peaks: tuple[float, ...] = _field("optimal emptying volumes v*")
    reward_heights: tuple[float, ...] = _field("h in (0, 1]")
    reward_widths: tuple[float, ...] = _field("w > 0")

    @property
    def target_volume(self) -> float:
        """The global optimum: the peak with the greatest height (first one on ties)."""
        best = max(range(len(self.reward_heights)), key=lambda k: (self.reward_heights[k], -k))
        return self.reward_peaks[best]


@dataclass(frozen=True)
class PlantConfig:
    """A whole plant: containers, PUs and episode settings. Immutable and validated on creation.

    Derived quantities (``n_containers``, ``container_names``) are computed, never
    stored, so an override can never leave them stale.
    """

    name: str
    containers: tuple[ContainerSpec, ...]
    num_processing_units: int = _field("m, identical PUs")
    timestep_s: float = _field("delta, seconds per step")
    episode_length_steps: int = _field("T, steps before truncation")
    initial_volume_min: float = _field("v(0) ~ U[min, max], volume units")
    initial_volume_max: float = _field("must be below every max_volume")
    overflow_reward: float = _field("r_min, reward when a container reaches max_volume")
    penalty_reward: float = _field("r_pen, emptying with no free PU or an empty container")
    description: str = ""

    def __post_init__(self) -> None:
        _validate(self)

    # ---- derived -------------------------------------------------------------------------
    @property
    def n_containers(self) -> int:
        return len(self.containers)

    @property
    def container_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.containers)

    def replace(self, **overrides: Any) -> "PlantConfig":
        """A new, re-validated config with plant-level fields overridden.

        Per-container fields are changed through ``containers=``. Unknown names raise
        :class:`ConfigError`; values are cast to the field's type.
        """
        allowed = {f.name for f in dataclasses.fields(self) if f.init}
        unknown = sorted(set(overrides) - allowed)
        if unknown:
            raise ConfigError(
                f"unknown config override(s) {unknown}; valid names: {sorted(allowed)}"
            )
        types = _field_types(PlantConfig)
        cast = {key: tuple(value) if key == "containers" else _cast(types[key], value, key)
                for key, value in overrides.items()}
        return dataclasses.replace(self, **cast)

    def to_toml(self) -> str:
        """This config in our TOML format (what ``configs/*.toml`` hold), with units as comments."""
        def row(key: str, value: str, comment: str) -> str:
            return f"{key} = {value}".ljust(48) + f"# {comment}"

        def floats(xs) -> str:
            return "[" + ", ".join(_fmt(x) for x in xs) + "]"

        def rows(obj) -> list[str]:
            out = []
            for f in dataclasses.fields(obj):
                value = getattr(obj, f.name)
                if "toml" in f.metadata:
                    text = floats(value) if isinstance(value, tuple) else (
                        str(value) if isinstance(value, int) else _fmt(value))
                    out.append(row(f.name, text, f.metadata["toml"]))
                elif isinstance(value, str):
                    out.append(f"{f.name} = {_toml_str(value)}")
            return out

        # A TOML comment ends at a line break and may not hold control characters.
        header = "".join(ch if ch.isprintable() else " " for ch in self.description)
        lines = [f"# {header}" if header else "# plant configuration", ""]
        plant = rows(self)
        lines += [plant[0], plant[-1], *plant[1:-1]]  # name and description first
        for c in self.containers:
            lines += ["", "[[containers]]", *rows(c)]
        return "\n".join(lines) + "\n"


def _field_types(cls) -> dict[str, str]:
    """Field name -> its annotation as written (``int``, ``float``, ``str``, ``tuple[float, ...]``):
    the one list of fields that reading, casting and writing configs use."""
    return {f.name: f.type for f in dataclasses.fields(cls)}


def _cast(type_name: str, value: Any, where: str) -> Any:
    """``value`` as a field of type ``type_name`` (a ConfigError naming ``where`` otherwise)."""
    if type_name == "int":
        return _as_int(value, where)
    if type_name == "float":
        return _as_float(value, where)
    if type_name == "tuple[float, ...]":
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where} must be a list of numbers, got {value!r}")
        return tuple(_as_float(v, where) for v in value)
    return str(value)


def _fmt(x: float) -> str:
    return repr(float(x)) if not float(x).is_integer() else f"{float(x):.1f}"


def _toml_str(s: str) -> str:
    """A TOML basic string: escape quote, backslash and control characters, keep the rest as is
    (json.dumps would write characters outside the BMP as surrogate pairs, which TOML rejects)."""
    def esc(ch: str) -> str:
        if ch in '"\\':
            return "\\" + ch
        return f"\\u{ord(ch):04x}" if ord(ch) < 0x20 or ord(ch) == 0x7F else ch

    return '"' + "".join(esc(ch) for ch in s) + '"'


def _as_float(value: Any, where: str) -> float:
    if isinstance(value, (bool, str, bytes) + _np_bool_types()) or not hasattr(value, "__float__"):
        raise ConfigError(f"{where}: expected a number, got {value!r}")
    try:
        out = float(value)
    except OverflowError:
        raise ConfigError(f"{where}: must be finite (and within the documented bounds), got {value!r}") from None
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: expected a number, got {value!r}") from exc
    if not math.isfinite(out):
        raise ConfigError(f"{where}: must be finite, got {value!r}")
    return out


def _as_int(value: Any, where: str) -> int:
    """An integral number of any numeric type (int, numpy integer, a float such as 600.0 or
    ``np.float32(600)``) as a Python int; bools, strings and non-integral values are refused."""
    if isinstance(value, (bool, str, bytes) + _np_bool_types()):
        raise ConfigError(f"{where}: expected an integer, got {value!r}")
    if hasattr(value, "__index__"):
        return operator.index(value)
    if hasattr(value, "__float__"):
        try:
            as_float = float(value)
        except (TypeError, ValueError, OverflowError):
            as_float = math.nan
        if math.isfinite(as_float) and as_float.is_integer():
            return int(as_float)
    raise ConfigError(f"{where}: expected an integer, got {value!r}")


def _np_bool_types() -> tuple[type, ...]:
    """numpy's bool type, if numpy is importable (the config itself does not need numpy)."""
    try:
        import numpy
    except ImportError:  # pragma: no cover - numpy is a dependency of the package
        return ()
    return (numpy.bool_,)


# ---- validation ----------------------------------------------------------------------------
def _check_finite(value: Any, where: str) -> None:
    """Direct construction bypasses the loaders' casting: still insist on finite real numbers."""
    if (isinstance(value, (bool, str, bytes) + _np_bool_types())
            or not isinstance(value, (int, float)) and not hasattr(value, "__float__")):
        raise ConfigError(f"{where}: expected a number, got {value!r}")
    try:
        finite = math.isfinite(float(value))
    except OverflowError:
        finite = False
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: expected a number, got {value!r}") from None
    if not finite:
        raise ConfigError(f"{where}: must be finite, got {value!r}")


def _check_range(value: float, lo: float, hi: float, where: str, what: str = "",
                 lo_open: bool = False) -> None:
    """lo ≤ value ≤ hi (lo < value with ``lo_open``), else a ConfigError naming ``where``."""
    ok = (value > lo if lo_open else value >= lo) and value <= hi
    if not ok:
        left = "(" if lo_open else "["
        raise ConfigError(f"{where} must lie in {left}{lo!r}, {hi!r}]{what}, got {value!r}")


#: Plant and container names: they name agents, files and figures, so no path separators, no
#: "..", no control characters (a letter or digit first, then letters, digits, '_', '.', '+', '-').
SAFE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]{0,63}$")
#: Most reward peaks per container (the paper's containers have one to three).
MAX_REWARD_PEAKS = 16


def _check_name(name: Any, where: str) -> None:
    if not isinstance(name, str) or not SAFE_NAME.match(name) or ".." in name:
        raise ConfigError(f"{where}: {name!r} is not a safe name (1-64 characters: a letter or digit, then "
                          f"letters, digits, '_', '.', '+' or '-'; no '..')")


def _validate(cfg: PlantConfig) -> None:
    _check_name(cfg.name, "name")
    if not isinstance(cfg.containers, tuple) or len(cfg.containers) == 0:
        raise ConfigError("containers: a plant needs at least one container")
    if len(cfg.containers) > MAX_CONTAINERS:
        raise ConfigError(f"containers: at most {MAX_CONTAINERS} containers are supported, "
                          f"got {len(cfg.containers)}")
    for c in cfg.containers:
        if not isinstance(c, ContainerSpec):
            raise ConfigError(f"containers: expected ContainerSpec entries, got {type(c).__name__}")
    for key, type_name in _field_types(PlantConfig).items():
        if type_name == "float":
            _check_finite(getattr(cfg, key), key)
    names = [c.name for c in cfg.containers]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ConfigError(f"containers: duplicate container name(s) {dup}")
    m = cfg.num_processing_units
    if isinstance(m, bool) or not isinstance(m, int) or not 1 <= m <= MAX_PROCESSING_UNITS:
        raise ConfigError(
            f"num_processing_units: need an integer 1 <= m <= {MAX_PROCESSING_UNITS} "
            f"(at least one processing unit), got {m!r}"
        )
    _check_range(cfg.timestep_s, MIN_TIMESTEP_S, MAX_TIMESTEP_S, "timestep_s", " seconds")
    t = cfg.episode_length_steps
    if isinstance(t, bool) or not isinstance(t, int) or not 1 <= t <= MAX_EPISODE_LENGTH_STEPS:
        raise ConfigError(
            f"episode_length_steps: must be a positive integer <= {MAX_EPISODE_LENGTH_STEPS}, got {t!r}"
        )
    if not (cfg.penalty_reward < 0):
        raise ConfigError(
            f"penalty_reward: r_pen must be < 0 (paper: r_min < r_pen < 0), got {cfg.penalty_reward!r}"
        )
    if not (cfg.overflow_reward < cfg.penalty_reward):
        raise ConfigError(
            f"overflow_reward: r_min must be < penalty_reward r_pen={cfg.penalty_reward!r}, "
            f"got {cfg.overflow_reward!r}"
        )
    if not cfg.overflow_reward >= MIN_OVERFLOW_REWARD:
        raise ConfigError(f"overflow_reward: r_min must be >= {MIN_OVERFLOW_REWARD!r}, got {cfg.overflow_reward!r}")
    if not (0 <= cfg.initial_volume_min <= cfg.initial_volume_max):
        raise ConfigError(
            f"initial_volume_min: need 0 <= initial_volume_min <= initial_volume_max, got "
            f"[{cfg.initial_volume_min!r}, {cfg.initial_volume_max!r}]"
        )
    for c in cfg.containers:
        _validate_container(c)
        if not cfg.initial_volume_max < c.max_volume:
            raise ConfigError(
                f"initial_volume_max: must be below every container's max_volume; container "
                f"{c.name!r} has max_volume={c.max_volume!r} <= {cfg.initial_volume_max!r}"
            )


def _validate_container(c: ContainerSpec) -> None:
    where = f"container {c.name!r}"
    if not isinstance(c.name, str) or not c.name:
        raise ConfigError(f"name: container names must be non-empty strings, got {c.name!r}")
    _check_name(c.name, "containers: name")
    if len(c.reward_peaks) > MAX_REWARD_PEAKS:
        raise ConfigError(f"{where}: reward_peaks: at most {MAX_REWARD_PEAKS} peaks, got {len(c.reward_peaks)}")
    types = _field_types(ContainerSpec)
    for key in (k for k, t in types.items() if t == "float"):
        _check_finite(getattr(c, key), f"{where}: {key}")
    for key in (k for k, t in types.items() if t.startswith("tuple")):
        if not isinstance(getattr(c, key), (tuple, list)):
            raise ConfigError(f"{where}: {key} must be a sequence of numbers, got {getattr(c, key)!r}")
        for x in getattr(c, key):
            _check_finite(x, f"{where}: {key}")
    if not c.fill_rate_per_s >= 0:
        raise ConfigError(f"{where}: fill_rate_per_s must be >= 0 (containers only fill), got {c.fill_rate_per_s!r}")
    _check_range(c.fill_rate_per_s, 0.0, MAX_RATE, f"{where}: fill_rate_per_s", " per second")
    if not c.fill_noise_per_sqrt_s >= 0:
        raise ConfigError(f"{where}: fill_noise_per_sqrt_s must be >= 0, got {c.fill_noise_per_sqrt_s!r}")
    _check_range(c.fill_noise_per_sqrt_s, 0.0, MAX_RATE, f"{where}: fill_noise_per_sqrt_s", " per sqrt(second)")
    for key in ("max_volume", "product_size", "pu_offset_s", "pu_time_per_product_s"):
        value = getattr(c, key)
        if not value > 0:
            raise ConfigError(f"{where}: {key} must be > 0, got {value!r}")
    _check_range(c.max_volume, MIN_VOLUME, MAX_VOLUME, f"{where}: max_volume", " volume units")
    _check_range(c.product_size, MIN_VOLUME, MAX_VOLUME, f"{where}: product_size", " volume units")
    for key in ("pu_offset_s", "pu_time_per_product_s"):
        _check_range(getattr(c, key), 0.0, MAX_PU_DURATION_S, f"{where}: {key}", " seconds", lo_open=True)
    # imported here: the core imports this module (a cycle at import time)
    from containergym_marl.core.params import pu_time_s

    longest = pu_time_s(float(c.max_volume), float(c.pu_offset_s), float(c.pu_time_per_product_s),
                        float(c.product_size))
    if not longest <= MAX_PU_TIME_S:
        raise ConfigError(
            f"{where}: pu_time_per_product_s: the longest PU time pu_offset_s + pu_time_per_product_s "
            f"* floor(max_volume / product_size) = {longest!r} s exceeds {MAX_PU_TIME_S!r} s"
        )
    lengths = {k: len(getattr(c, k)) for k, t in _field_types(ContainerSpec).items() if t.startswith("tuple")}
    if lengths["reward_peaks"] == 0:
        raise ConfigError(f"{where}: reward_peaks must list at least one optimum")
    if len(set(lengths.values())) != 1:
        raise ConfigError(
            f"{where}: reward_peaks, reward_heights and reward_widths must have equal lengths, "
            f"got {lengths}"
        )
    for h in c.reward_heights:
        if not 0 < h <= 1:
            raise ConfigError(f"{where}: reward_heights must lie in (0, 1], got {h!r}")
    for w in c.reward_widths:
        if not w > 0:
            raise ConfigError(f"{where}: reward_widths must be > 0, got {w!r}")
        _check_range(w, MIN_VOLUME, MAX_VOLUME, f"{where}: reward_widths", " volume units")
    for p in c.reward_peaks:
        if not p > 0:
            raise ConfigError(f"{where}: reward_peaks must be > 0, got {p!r}")
        if not p <= c.max_volume:
            raise ConfigError(
                f"{where}: reward_peaks must be <= max_volume={c.max_volume!r} (a container is "
                f"emptied below v_max), got {p!r}"
            )


# ---- building from mappings ----------------------------------------------------------------
def _check_keys(data: Mapping[str, Any], cls, where: str, what: str, optional: set[str]) -> dict[str, str]:
    """The field types of ``cls`` once ``data`` holds every required one and nothing else."""
    types = _field_types(cls)
    unknown = sorted(set(data) - set(types))
    if unknown:
        raise ConfigError(f"{where}unknown {what}key(s) {unknown}; valid keys: {sorted(types)}")
    missing = sorted(set(types) - optional - set(data))
    if missing:
        raise ConfigError(f"{where}missing {what}key(s) {missing}")
    return types


def config_from_dict(data: Mapping[str, Any], *, default_name: str = "custom") -> PlantConfig:
    """Build a config from a mapping in our format (the TOML files' structure)."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"config: expected a table/mapping, got {type(data).__name__}")
    types = _check_keys(data, PlantConfig, "", "config ", {"name", "description"})
    raw_containers = data["containers"]
    if not isinstance(raw_containers, (list, tuple)):
        raise ConfigError("containers: expected a list of container tables")
    containers = []
    for i, rc in enumerate(raw_containers):
        if not isinstance(rc, Mapping):
            raise ConfigError(f"containers[{i}]: expected a table, got {type(rc).__name__}")
        where = f"container {rc.get('name', f'#{i}')!r}: "
        container_types = _check_keys(rc, ContainerSpec, where, "", set())
        containers.append(ContainerSpec(**{key: _cast(t, rc[key], f"{where}{key}")
                                           for key, t in container_types.items()}))
    plant = {key: _cast(t, data[key], key) for key, t in types.items()
             if key in data and key not in ("containers", "name")}
    return PlantConfig(name=str(data.get("name", default_name)), containers=tuple(containers), **plant)


# ---- files and built-ins -------------------------------------------------------------------
def _builtin_dir():
    return resources.files("containergym_marl.configs")


def list_configs() -> list[str]:
    """Names of the built-in configurations (the paper's eight rows and the 16-container plant)."""
    return sorted(p.name[: -len(".toml")] for p in _builtin_dir().iterdir() if p.name.endswith(".toml"))


#: Largest config file read (the built-in ones are ~3 kB; a 16-container plant ~6 kB).
MAX_CONFIG_BYTES = 1_000_000
#: Deepest nesting of lists and tables in a config file (ours: 3).
MAX_CONFIG_DEPTH = 16


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


def _nesting_depth(text: str) -> int:
    """The deepest bracket nesting of a JSON or TOML text, outside strings (a cheap upper bound, read
    before the parser recurses)."""
    depth = deepest = 0
    quote = None
    escaped = False
    for ch in text:
        if quote:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == quote:
                quote = None
        elif ch in "\"'":
            quote = ch
        elif ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif ch in "]}":
            depth -= 1
    return deepest


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
    if _nesting_depth(text) > MAX_CONFIG_DEPTH:
        raise ConfigError(f"config file {str(path)!r}: lists or tables nested deeper than {MAX_CONFIG_DEPTH} levels")
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
        from containergym_marl.reference_format import config_from_reference_json

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
