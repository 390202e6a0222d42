"""Shared test helpers."""

from __future__ import annotations

import numpy as np
import pytest

from containergym_marl import load_config
from containergym_marl.core import PlantState

PAPER_CONFIGS = (
    "n5_m2_dt60",
    "n5_m2_dt120",
    "n5_m5_dt60",
    "n5_m5_dt120",
    "n11_m2_dt60",
    "n11_m2_dt120",
    "n11_m11_dt60",
    "n11_m11_dt120",
)


def make_state(volumes, timers, step_count=0) -> PlantState:
    """A one-simulation state from plain lists."""
    v = np.atleast_2d(np.asarray(volumes, dtype=np.float64))
    p = np.atleast_2d(np.asarray(timers, dtype=np.float64))
    return PlantState(v, p, np.full(v.shape[0], step_count, dtype=np.int64))


@pytest.fixture
def cfg5():
    return load_config("n5_m2_dt120")
