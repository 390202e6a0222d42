"""The shared physics core: batched over simulations, no environment API.

:mod:`.dynamics` is the one definition of a step (compiled with numba) with the registry of
arbitration rules; :mod:`.rng` the per-simulation random streams and :mod:`.simulator`
a batch of simulations that the views hold.
"""

from containergym_marl.core.dynamics import (
    ARBITRATION_RULES,
    ArbitrationRule,
    PlantState,
    StepOutcome,
    emptying_reward,
    emptying_rewards,
    get_rule,
    pu_busy_time_s,
    reset_state,
    step,
)
from containergym_marl.core.params import PlantParams
from containergym_marl.core.rng import BLOCK_ROWS, NoiseStreams
from containergym_marl.core.simulator import EpisodeFinishedError, PlantSimulator

__all__ = [
    "ARBITRATION_RULES",
    "ArbitrationRule",
    "BLOCK_ROWS",
    "EpisodeFinishedError",
    "NoiseStreams",
    "PlantParams",
    "PlantSimulator",
    "PlantState",
    "StepOutcome",
    "emptying_reward",
    "emptying_rewards",
    "get_rule",
    "pu_busy_time_s",
    "reset_state",
    "step",
]
