"""Helpers shared by the environment views: action checking.

Rendering, shared by both views, is in :mod:`containergym_marl.render`.
"""

from __future__ import annotations

import numbers

import numpy as np


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
