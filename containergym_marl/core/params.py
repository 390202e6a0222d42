"""Immutable array form of a plant config: what the compiled physics step reads.

``PlantParams`` is a named tuple of read-only arrays and plain numbers, so compiled code reads its
fields by name (gymnax's ``EnvParams``, kept apart from the state). It is derived from a
:class:`~containergym_marl.config.PlantConfig` by :meth:`PlantParams.from_config`; the config knows
nothing about it.

Every field lives in one of three storage arrays, and compiled functions take those three arrays
(``PlantParams.kernel_arrays()``) and rebuild the named tuple inside with :func:`unpack_params`:
numba unboxes each argument of a call, and three arrays cost far less than nineteen fields. The
table :data:`STORAGE` says where each field is stored; packing (:meth:`PlantParams.from_config`)
and unpacking (:func:`unpack_params`, generated from the table) both follow it, so no index is
written anywhere else.

The bound ``max_pu_time_s`` is the largest g(v), the PU time (paper eq. 2) of
:mod:`containergym_marl.config.pu_time`, the one definition that the step and the config's
validation also call.
"""

from __future__ import annotations

import operator
from typing import Callable, NamedTuple, get_type_hints

import numba
import numpy as np

from containergym_marl.config.pu_time import JIT_OPTIONS, pu_time_s


class PlantParams(NamedTuple):
    """Per-container arrays (shape ``(n,)`` or ``(n, K)``) and plant scalars.

    Reward peaks are padded to the largest number of peaks ``K``; padded entries have a zero
    coefficient ``h - r_pen`` so they add nothing to the reward.
    """

    n_containers: int
    n_pus: int
    timestep_s: float  # δ
    episode_length_steps: int  # T
    initial_volume_min: float
    initial_volume_max: float
    overflow_reward: float  # r_min
    penalty_reward: float  # r_pen
    fill_mean_per_step: np.ndarray  # μ·δ, volume units per step
    fill_std_per_step: np.ndarray  # σ·√δ
    max_volume: np.ndarray  # v_max
    product_size: np.ndarray  # b, volume units per product
    pu_offset_s: np.ndarray  # β
    pu_time_per_product_s: np.ndarray  # λ
    reward_peaks: np.ndarray  # (n, K) v*_k
    reward_coef: np.ndarray  # (n, K): h_k - r_pen, 0 for padding
    reward_two_width_sq: np.ndarray  # (n, K): 2 w_k², 1 for padding
    target_volume: np.ndarray  # the global optimum v* of each container
    max_pu_time_s: float  # largest g_i(v) for v < v_max: an upper bound of every PU timer
    # The storage of every field above (see STORAGE); the arrays above are views of these.
    per_container: np.ndarray  # (n, columns)
    reward_table: np.ndarray  # (rows, n, K)
    scalars: np.ndarray  # (entries,)

    def kernel_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The storage arrays, the form in which compiled functions take a plant (see STORAGE)."""
        return _storage_arrays(self)

    @classmethod
    def from_config(cls, cfg) -> "PlantParams":
        n = cfg.n_containers
        k = max(len(c.reward_peaks) for c in cfg.containers)
        fields = {
            "n_containers": n,
            "n_pus": int(cfg.num_processing_units),
            "timestep_s": float(cfg.timestep_s),
            "episode_length_steps": int(cfg.episode_length_steps),
            "initial_volume_min": float(cfg.initial_volume_min),
            "initial_volume_max": float(cfg.initial_volume_max),
            "overflow_reward": float(cfg.overflow_reward),
            "penalty_reward": float(cfg.penalty_reward),
            "reward_peaks": np.zeros((n, k)),
            "reward_coef": np.zeros((n, k)),
            "reward_two_width_sq": np.ones((n, k)),
        }
        for i, c in enumerate(cfg.containers):
            p = len(c.reward_peaks)
            fields["reward_peaks"][i, :p] = c.reward_peaks
            fields["reward_coef"][i, :p] = np.asarray(c.reward_heights) - cfg.penalty_reward
            fields["reward_two_width_sq"][i, :p] = 2.0 * np.asarray(c.reward_widths) ** 2

        def column(attr: str) -> np.ndarray:
            return np.array([getattr(c, attr) for c in cfg.containers], dtype=np.float64)

        dt = fields["timestep_s"]
        fields.update(
            fill_mean_per_step=column("fill_rate_per_s") * dt,
            fill_std_per_step=column("fill_noise_per_sqrt_s") * np.sqrt(dt),
            max_volume=column("max_volume"),
            product_size=column("product_size"),
            pu_offset_s=column("pu_offset_s"),
            pu_time_per_product_s=column("pu_time_per_product_s"),
            target_volume=column("target_volume"),
        )
        # A container is only emptied while v < v_max (reaching v_max ends the episode), so
        # g(v_max) bounds every timer.
        columns = zip(fields["max_volume"], fields["pu_offset_s"], fields["pu_time_per_product_s"],
                      fields["product_size"])
        fields["max_pu_time_s"] = max(pu_time_s(vmax, beta, lam, b) for vmax, beta, lam, b in columns)
        return pack_params(fields)


#: Where each field of PlantParams is stored: storage array -> the fields it holds, in order
#: (``per_container[:, k]``, ``reward_table[k]``, ``scalars[k]``); the storage arrays in the order
#: that compiled functions take them (:meth:`PlantParams.kernel_arrays`). The named tuple's own
#: annotation says whether a scalar is an int or a float. Compiled callers of unpack_params are
#: cached by their own file (numba does not follow dependencies): after changing this table, delete
#: the package's ``__pycache__`` folders.
STORAGE: dict[str, tuple[str, ...]] = {
    "per_container": ("fill_mean_per_step", "fill_std_per_step", "max_volume", "product_size", "pu_offset_s",
                      "pu_time_per_product_s", "target_volume"),
    "reward_table": ("reward_peaks", "reward_coef", "reward_two_width_sq"),
    "scalars": ("n_containers", "n_pus", "timestep_s", "episode_length_steps", "initial_volume_min",
                "initial_volume_max", "overflow_reward", "penalty_reward", "max_pu_time_s"),
}
_storage_arrays = operator.attrgetter(*STORAGE)
_INDEXING = {"scalars": "scalars[{}]", "per_container": "per_container[:, {}]", "reward_table": "reward_table[{}]"}


def generated_function(name: str, arguments: tuple[str, ...], returned: str, namespace: dict) -> Callable:
    """``def name(*arguments): return returned``, compiled with ``namespace`` as its globals.

    Numba cannot build a named tuple from a table at compile time, so the few functions that name
    the kernel's arrays are written out from their tables as source. Generated functions have no
    file, so numba does not cache them; their compiled callers are cached with them inlined.
    """
    source = f"def {name}({', '.join(arguments)}):\n    return {returned}\n"
    exec(compile(source, f"<generated {name}>", "exec"), namespace)
    return numba.njit(error_model=JIT_OPTIONS["error_model"])(namespace[name])


def _unpacking_expression() -> str:
    stored = {name: (storage, k) for storage, names in STORAGE.items() for k, name in enumerate(names)}
    missing = set(PlantParams._fields) - set(stored) - set(STORAGE)
    if missing or len(stored) + len(STORAGE) != len(PlantParams._fields):
        raise TypeError(f"STORAGE must place every field of PlantParams exactly once; missing {sorted(missing)}")
    kinds = get_type_hints(PlantParams)
    values = []
    for name in PlantParams._fields:
        if name in STORAGE:
            values.append(f"{name}={name}")
            continue
        storage, k = stored[name]
        value = _INDEXING[storage].format(k)
        values.append(f"{name}={kinds[name].__name__}({value})" if storage == "scalars" else f"{name}={value}")
    return f"PlantParams({', '.join(values)})"


#: PlantParams from its storage arrays, in compiled code (and in Python as ``unpack_params.py_func``).
unpack_params = generated_function("unpack_params", tuple(STORAGE), _unpacking_expression(),
                                   {"PlantParams": PlantParams})


def _frozen(a) -> np.ndarray:
    out = np.array(a, dtype=np.float64)
    out.setflags(write=False)
    return out


def pack_params(fields: dict) -> PlantParams:
    """PlantParams of ``fields`` (name -> value, every field but the storage arrays): the values
    are copied into read-only storage arrays and the named tuple's fields are views of them."""
    storage = {"per_container": _frozen(np.stack([fields[name] for name in STORAGE["per_container"]], axis=1)),
               "reward_table": _frozen(np.stack([fields[name] for name in STORAGE["reward_table"]])),
               "scalars": _frozen([fields[name] for name in STORAGE["scalars"]])}
    return unpack_params.py_func(**storage)
