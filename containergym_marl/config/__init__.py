"""Plant configurations: frozen, validated, loaded from our TOML files or the reference JSON format.

The package's face; each part does one job:

- :mod:`~containergym_marl.config.bounds`: the bounds every config is checked against (their table)
  and the checks and casts of one value;
- :mod:`~containergym_marl.config.schema`: :class:`PlantConfig` and :class:`ContainerSpec`, their
  validation, their TOML form, and :func:`config_from_dict`;
- :mod:`~containergym_marl.config.reference_format`: the earlier reference implementation's JSON format;
- :mod:`~containergym_marl.config.loading`: built-in configs and config files, :func:`load_config`.
"""

from containergym_marl.config.bounds import (
    MAX_CONTAINERS,
    MAX_EPISODE_LENGTH_STEPS,
    MAX_PROCESSING_UNITS,
    MAX_PU_DURATION_S,
    MAX_PU_TIME_S,
    MAX_RATE,
    MAX_REWARD_PEAKS,
    MAX_SIMS,
    MAX_TIMESTEP_S,
    MAX_VOLUME,
    MIN_OVERFLOW_REWARD,
    MIN_TIMESTEP_S,
    MIN_VOLUME,
    SAFE_NAME,
    ConfigError,
)
from containergym_marl.config.loading import (
    MAX_CONFIG_BYTES,
    MAX_CONFIG_DEPTH,
    PAPER_TEST_PROTOCOL,
    list_configs,
    load_config,
)
from containergym_marl.config.schema import ContainerSpec, PlantConfig, config_from_dict

# Every public name of the former single module config.py, so that no import of it breaks.
__all__ = [
    "MAX_SIMS",
    "MAX_CONTAINERS",
    "MAX_EPISODE_LENGTH_STEPS",
    "MAX_PROCESSING_UNITS",
    "MIN_TIMESTEP_S",
    "MAX_TIMESTEP_S",
    "MIN_OVERFLOW_REWARD",
    "MIN_VOLUME",
    "MAX_VOLUME",
    "MAX_RATE",
    "MAX_PU_DURATION_S",
    "MAX_PU_TIME_S",
    "MAX_REWARD_PEAKS",
    "SAFE_NAME",
    "MAX_CONFIG_BYTES",
    "MAX_CONFIG_DEPTH",
    "ConfigError",
    "ContainerSpec",
    "PlantConfig",
    "PAPER_TEST_PROTOCOL",
    "load_config",
    "list_configs",
    "config_from_dict",
]
