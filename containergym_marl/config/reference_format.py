"""The earlier reference implementation's JSON config format, read into a :class:`PlantConfig`.

``load_config`` reads a ``.json`` file with this reader when it holds ``ENABLED_CONTAINERS``. The
reference names map onto ours as ``_REFERENCE_PER_CONTAINER`` and the plant-level keys below say;
everything read is validated as any config is
(:func:`~containergym_marl.config.schema.config_from_dict`).
"""

from __future__ import annotations

from typing import Any, Mapping

from containergym_marl.config.bounds import MAX_CONTAINERS, ConfigError
from containergym_marl.config.schema import PlantConfig, config_from_dict

__all__ = ["config_from_reference_json"]

_REFERENCE_KEYS = {
    "MAX_EPISODE_LENGTH",
    "TIMESTEP",
    "ENABLED_CONTAINERS",
    "N_PRESSES",
    "MIN_STARTING_VOLUME",
    "MAX_STARTING_VOLUME",
    "FAILURE_PENALTY",
    "RW_MUS",
    "RW_SIGMAS",
    "MAX_VOLUMES",
    "BALE_SIZES",
    "PRESS_OFFSETS",
    "PRESS_SLOPES",
    "REWARD_PARAMS",
    "MIN_REWARD",
}
_REFERENCE_PER_CONTAINER = {
    "RW_MUS": "fill_rate_per_s",
    "RW_SIGMAS": "fill_noise_per_sqrt_s",
    "MAX_VOLUMES": "max_volume",
    "BALE_SIZES": "product_size",
    "PRESS_OFFSETS": "pu_offset_s",
    "PRESS_SLOPES": "pu_time_per_product_s",
}


def config_from_reference_json(data: Mapping[str, Any], *, name: str = "reference") -> PlantConfig:
    """Build a config from the earlier reference implementation's JSON format.

    ``ENABLED_CONTAINERS`` is either a list of names (per-container fields are then dicts keyed by
    name) or a count (per-container fields are then lists in container order). Every key is
    required: the reference code's silent defaults are not reproduced.
    """
    unknown = sorted(set(data) - _REFERENCE_KEYS)
    if unknown:
        raise ConfigError(f"unknown reference-format key(s) {unknown}")
    missing = sorted(_REFERENCE_KEYS - set(data))
    if missing:
        raise ConfigError(f"missing reference-format key(s) {missing}")
    enabled = data["ENABLED_CONTAINERS"]
    if isinstance(enabled, list):
        names = [str(x) for x in enabled]
        keyed = True
    elif isinstance(enabled, int) and not isinstance(enabled, bool) and 0 < enabled <= MAX_CONTAINERS:
        names = [f"C{i + 1}" for i in range(enabled)]
        keyed = False
    else:
        raise ConfigError(f"ENABLED_CONTAINERS: expected a list of names or a count in "
                          f"[1, {MAX_CONTAINERS}], got {enabled!r}")

    def per_container(key: str, idx: int, cname: str) -> Any:
        table = data[key]
        if keyed:
            if not isinstance(table, Mapping):
                raise ConfigError(f"{key}: expected a mapping from container name to value")
            if cname not in table:
                raise ConfigError(f"{key}: missing value for container {cname!r}")
            return table[cname]
        if not isinstance(table, (list, tuple)) or len(table) != len(names):
            raise ConfigError(
                f"{key}: expected a list of {len(names)} values (one per container), got {table!r}"
            )
        return table[idx]

    containers = []
    for i, cname in enumerate(names):
        entry: dict[str, Any] = {"name": cname}
        for key, ours in _REFERENCE_PER_CONTAINER.items():
            entry[ours] = per_container(key, i, cname)
        rp = per_container("REWARD_PARAMS", i, cname)
        if isinstance(rp, Mapping):
            try:
                entry["reward_peaks"], entry["reward_heights"], entry["reward_widths"] = (
                    rp["peaks"], rp["heights"], rp["widths"])
            except KeyError as exc:
                raise ConfigError(f"REWARD_PARAMS: container {cname!r} lacks {exc.args[0]!r}") from None
        elif isinstance(rp, (list, tuple)):  # [(peak, height, width), ...]
            if not all(isinstance(t, (list, tuple)) and len(t) == 3 for t in rp):
                raise ConfigError(f"REWARD_PARAMS: container {cname!r}: expected a list of "
                                  f"(peak, height, width) triples, got {rp!r}")
            entry["reward_peaks"] = [t[0] for t in rp]
            entry["reward_heights"] = [t[1] for t in rp]
            entry["reward_widths"] = [t[2] for t in rp]
        else:
            raise ConfigError(f"REWARD_PARAMS: container {cname!r}: unreadable entry {rp!r}")
        containers.append(entry)
    return config_from_dict(
        {
            "name": name,
            "description": f"read from reference-format JSON {name!r}",
            "num_processing_units": data["N_PRESSES"],
            "timestep_s": data["TIMESTEP"],
            "episode_length_steps": data["MAX_EPISODE_LENGTH"],
            "initial_volume_min": data["MIN_STARTING_VOLUME"],
            "initial_volume_max": data["MAX_STARTING_VOLUME"],
            "overflow_reward": data["FAILURE_PENALTY"],
            "penalty_reward": data["MIN_REWARD"],
            "containers": containers,
        }
    )
