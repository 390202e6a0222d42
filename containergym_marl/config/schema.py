"""Plant configurations: the frozen, validated :class:`PlantConfig` and :class:`ContainerSpec`, their
TOML form, and building one from a mapping in our format.

A :class:`PlantConfig` is the immutable description of one plant (the paper's "instance"):
its containers, its processing units (PUs) and the episode settings. The physics core never reads
a config directly: it reads :class:`~containergym_marl.core.params.PlantParams`, the array form
derived from it by ``PlantParams.from_config`` (the config knows nothing of the core).

Units: volumes in the plant's volume units, times in seconds, rates per second. Every config is
checked against the bounds of :mod:`containergym_marl.config.bounds` when it is built (loaded,
overridden or constructed by hand).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Mapping

from containergym_marl.config.bounds import (
    MAX_CONTAINERS,
    MAX_EPISODE_LENGTH_STEPS,
    MAX_PROCESSING_UNITS,
    MAX_PU_DURATION_S,
    MAX_PU_TIME_S,
    MAX_RATE,
    MAX_REWARD_PEAKS,
    MAX_TIMESTEP_S,
    MAX_VOLUME,
    MIN_OVERFLOW_REWARD,
    MIN_TIMESTEP_S,
    MIN_VOLUME,
    ConfigError,
    _cast,
    _check_finite,
    _check_name,
    _check_range,
)
from containergym_marl.config.pu_time import pu_time_s


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


# ---- validation ----------------------------------------------------------------------------
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

