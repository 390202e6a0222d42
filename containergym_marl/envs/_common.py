"""Helpers shared by the environment views: action checking, the normalised global state.

Rendering, shared by both views, is in :mod:`containergym_marl.render`.
"""

from __future__ import annotations

import numbers

import numpy as np
from gymnasium import spaces

from containergym_marl.core.observations import VOLUME_BOUND_FACTOR


def discrete_action(action, n_actions: int, who: str) -> int:
    """``action`` as a Python int in ``[0, n_actions)``; a clear error for anything else.

    Accepts Python and numpy integers and integer arrays holding one value (shape ``()`` as SB3's
    ``predict`` returns for one observation, or ``(1,)``). Floats and bools are rejected rather
    than silently truncated or cast.
    """
    if type(action) is int and 0 <= action < n_actions:  # the common case, checked cheaply
        return action
    value = action
    if isinstance(value, np.ndarray):
        if value.shape not in ((), (1,)):
            raise ValueError(f"{who}: expected a single integer action, got an array of shape {value.shape}")
        value = value.reshape(()).item() if np.issubdtype(value.dtype, np.integer) else value
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{who}: expected an integer action in [0, {n_actions - 1}], got {action!r} "
                        f"({type(action).__name__})")
    value = int(value)
    if not 0 <= value < n_actions:
        raise ValueError(f"{who}: action {value} out of range [0, {n_actions - 1}]")
    return value


# ---- seeds ------------------------------------------------------------------------------------------
def is_integer(value) -> bool:
    """A Python or numpy integer, not a bool."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def check_seed(value, name: str = "seed") -> int | None:
    """None or a non-negative integer (Python or numpy) as a Python int, for every view alike;
    anything else (``2.7``, ``"5"``, True, -1) is refused with a ValueError rather than cast."""
    if value is None:
        return None
    if not is_integer(value) or value < 0:
        raise ValueError(f"{name}: expected None or a non-negative integer, got {value!r} "
                         f"({type(value).__name__})")
    return int(value)


# ---- the normalised global state ------------------------------------------------------------------
def normalised_state_scale(params) -> np.ndarray:
    """(n + m,) float32 divisors of the global state ``[v, p]``: v_max,i for the volumes and the
    largest possible PU time for the timers (1 where that is 0, a plant whose PUs take no time)."""
    pu_time = float(params.max_pu_time_s) or 1.0
    scale = np.concatenate([np.asarray(params.max_volume, dtype=np.float64),
                            np.full(params.n_pus, pu_time)]).astype(np.float32)
    scale.setflags(write=False)
    return scale


def normalised_state_bounds(params) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the normalised state: volumes / v_max in [0, 2], timers / max PU time in [0, 1]."""
    low = np.zeros(params.n_containers + params.n_pus, dtype=np.float32)
    high = np.ones_like(low)
    high[: params.n_containers] = VOLUME_BOUND_FACTOR
    return low, high


def normalised_state(state: np.ndarray, scale: np.ndarray, space: spaces.Box) -> np.ndarray:
    """The physical float32 global state divided by ``scale``, clipped into ``space`` (a no-op for
    states within the physical bounds: the quotient of a bound by its scale is exact in float32)."""
    out = np.divide(state, scale, dtype=np.float32)
    return out.clip(space.low, space.high, out=out)
