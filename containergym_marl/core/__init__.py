"""The shared physics core: batched over simulations, no environment API.

:mod:`.dynamics` defines the physics as pure numpy functions; :mod:`.compiled` runs the same step
compiled with numba when it is installed (``backend="auto"``), with identical states.
"""

from containergym_marl.core.dynamics import (
    ARBITRATION_RULES,
    PlantState,
    StepOutcome,
    arbitrate,
    emptying_reward,
    priority_keys,
    pu_busy_time_s,
    reset_state,
    step,
)
from containergym_marl.core.params import PlantParams
from containergym_marl.core.rng import BLOCK_ROWS, NoiseStreams
from containergym_marl.core.simulator import EpisodeFinishedError, PlantSimulator

__all__ = [
    "ARBITRATION_RULES",
    "BLOCK_ROWS",
    "EpisodeFinishedError",
    "NoiseStreams",
    "PlantParams",
    "PlantSimulator",
    "PlantState",
    "StepOutcome",
    "arbitrate",
    "emptying_reward",
    "priority_keys",
    "pu_busy_time_s",
    "reset_state",
    "step",
]
