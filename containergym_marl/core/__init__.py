"""The shared physics core: batched over simulations, no environment API.

:mod:`.dynamics` is the one definition of a step (compiled with numba) with the registry of
arbitration rules; :mod:`.rng` the per-simulation random streams, :mod:`.simulator`
a batch of simulations that the views hold, and :mod:`.whatif` many futures of one state (for
look-ahead planning).
"""

from containergym_marl.core.dynamics import (
    ARBITRATION_RULES,
    DEFAULT_ARBITRATION,
    ArbitrationRule,
    PlantState,
    StepOutcome,
    emptying_reward,
    emptying_rewards,
    get_rule,
    overflow_probabilities,
    pu_busy_time_s,
    reset_state,
    step,
)
from containergym_marl.core.params import PlantParams
from containergym_marl.core.rng import BLOCK_ROWS, NoiseStreams
from containergym_marl.core.simulator import EpisodeFinishedError, PlantSimulator
from containergym_marl.core.whatif import Futures, simulate_futures

__all__ = [
    "ARBITRATION_RULES",
    "ArbitrationRule",
    "BLOCK_ROWS",
    "DEFAULT_ARBITRATION",
    "EpisodeFinishedError",
    "Futures",
    "NoiseStreams",
    "PlantParams",
    "PlantSimulator",
    "PlantState",
    "StepOutcome",
    "emptying_reward",
    "emptying_rewards",
    "get_rule",
    "overflow_probabilities",
    "pu_busy_time_s",
    "reset_state",
    "simulate_futures",
    "step",
]
