"""The bounds every plant configuration is checked against, and the checks and casts of one value.

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
reward_peaks (v*_k)         0 < v*_k ≤ v_max, 1 to 16 of them                     MAX_REWARD_PEAKS
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

**Training settings and files handed over.** A run's settings (``--hp``, ``--n-envs``) and what a
model file, checkpoint, replay buffer or DAgger data set declares are checked against these bounds
before anything is allocated or a run directory is written (a ValueError naming the setting or the
file, its field and the rule); each leaves room far beyond the paper's runs ([64, 64] networks,
budgets of 5M samples) and the package's own searches (rollout_samples ≤ 16384, n_steps ≤ 256,
DAgger data sets of up to 6M samples).

===========================  ===================================================  ======================
what                         bound                                                constant
===========================  ===================================================  ======================
hidden (width of a layer)    integer, 1 ≤ width ≤ 4096 (paper: 64)                MAX_HIDDEN_WIDTH
hidden (number of layers)    1 ≤ layers ≤ 16 (paper: 2)                           MAX_HIDDEN_LAYERS
network parameters           ≤ 2**26 (268 MB of float32), policy and value        MAX_NETWORK_PARAMETERS
                             networks together (paper: ~10**4)
n_steps                      1 ≤ n_steps ≤ 2**16 per simulation and rollout       MAX_N_STEPS
rollout_samples              1 ≤ rollout_samples ≤ 2**20 samples per update       MAX_ROLLOUT_SAMPLES
                             (also n_steps × n_envs of an SB3 model file)
minibatch_size, batch_size   1 ≤ size ≤ 2**20 samples                             MAX_MINIBATCH
n_epochs                     1 ≤ n_epochs ≤ 1000                                  MAX_EPOCHS
dataset_size (DAgger)        1 ≤ size ≤ 2**26 samples                             MAX_DATASET_SIZE
buffer_size (SB3 replay)     1 ≤ size ≤ 2**24 samples (SB3's default: 10**6)      MAX_REPLAY_BUFFER
futures, horizon             1 ≤ K ≤ 1024, 1 ≤ H ≤ 1024 (DAgger's labelling       MAX_PLANNER_FUTURES,
                             planner; defaults 16, 8)                             MAX_PLANNER_HORIZON
own check's lead_steps       0 ≤ L ≤ 1024 fills (a learned container-agent        MAX_OWN_CHECK_LEAD_STEPS
                             policy's own deadline check)
overflow_reward_scale        0 < scale ≤ 1000 (the native PPO's reward at an      MAX_OVERFLOW_REWARD_SCALE
                             overflow, × r_min; 1: the plant's own)
memory of a run              its estimate (``training.train_args.memory_estimate``:     machine_memory()
                             buffers, data set, networks, simulations) ≤ the
                             machine's physical memory
config file                  ≤ 1,000,000 bytes                                    MAX_CONFIG_BYTES
config nesting               lists and tables ≤ 16 levels, a dotted key or table  MAX_CONFIG_DEPTH
                             name ≤ 16 parts (TOML's parser needs memory that
                             grows with the square of a key's parts)
tensor files, SB3 zips       members unpack to at most the file's own size        –
                             (torch.save and SB3 store them uncompressed)
replay buffer (.npz)         each array's header (shape, dtype) and declared      –
                             size are the buffer's; 0 ≤ pos < buffer_size,
                             actions within the action space
===========================  ===================================================  ======================
"""

from __future__ import annotations

import math
import operator
import os
import re
from typing import Any

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

# ---- training settings and files (the second table) ----------------------------------------------
MAX_HIDDEN_WIDTH = 4096
MAX_HIDDEN_LAYERS = 16
MAX_NETWORK_PARAMETERS = 2**26
MAX_N_STEPS = 2**16
MAX_ROLLOUT_SAMPLES = 2**20
MAX_MINIBATCH = 2**20
MAX_EPOCHS = 1000
MAX_DATASET_SIZE = 2**26
MAX_REPLAY_BUFFER = 2**24
MAX_PLANNER_FUTURES = 1024
MAX_PLANNER_HORIZON = 1024
MAX_OWN_CHECK_LEAD_STEPS = 1024
MAX_OVERFLOW_REWARD_SCALE = 1000.0
#: Largest config file read (the built-in ones are ~3 kB; a 16-container plant ~6 kB).
MAX_CONFIG_BYTES = 1_000_000
#: Deepest nesting of lists and tables in a config file, and most parts of a dotted key (ours: 3).
MAX_CONFIG_DEPTH = 16


class ConfigError(ValueError):
    """An invalid plant configuration. The message names the offending field and container."""


# ---- casts of one value (loaders and overrides) ----------------------------------------------
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


# ---- checks of one value (every config's validation) -----------------------------------------
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


# ---- checks of a training setting and of a run's memory ---------------------------------------
def check_count(value: Any, lo: int, hi: int, where: str) -> None:
    """``value`` is an integer (not a bool) with lo ≤ value ≤ hi, else a ValueError naming ``where``
    and the bound (a training setting or a size a file declares)."""
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ValueError(f"{where} must be an integer in [{lo}, {hi}], got {value!r}")


def machine_memory() -> int:
    """This machine's physical memory in bytes, what :func:`check_memory` compares with."""
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def check_memory(estimate: dict[str, int], what: str) -> None:
    """Refuse ``what`` (a ValueError) when the bytes of ``estimate``, one entry per setting that sizes
    them (``"dataset_size=1000000"``), add up to more than the machine's memory; the error names the
    setting of the largest entry."""
    total, available = sum(estimate.values()), machine_memory()
    if total > available:
        setting, largest = max(estimate.items(), key=lambda item: item[1])
        raise ValueError(f"{setting}: {what} needs about {total / 2**30:.1f} GiB of memory ({largest / 2**30:.1f} "
                         f"GiB for {setting}), more than this machine's {available / 2**30:.1f} GiB")


#: Plant and container names: they name agents, files and figures, so no path separators, no
#: "..", no control characters (a letter or digit first, then letters, digits, '_', '.', '+', '-').
SAFE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]{0,63}$")
#: Most reward peaks per container (the paper's containers have one to three).
MAX_REWARD_PEAKS = 16


def _check_name(name: Any, where: str) -> None:
    if not isinstance(name, str) or not SAFE_NAME.match(name) or ".." in name:
        raise ConfigError(f"{where}: {name!r} is not a safe name (1-64 characters: a letter or digit, then "
                          f"letters, digits, '_', '.', '+' or '-'; no '..')")

