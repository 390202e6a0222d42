"""Training glue: the algorithm registry, run directories and the training loop (SB3 / sb3-contrib /
SuperSuit, imported only when a run starts)."""

from containergym_marl.algorithms import (
    ALGORITHMS,
    REGISTRY,
    AlgorithmSpec,
    get_algorithm,
    paper_budget,
)
from containergym_marl.extras import MissingExtraError
from containergym_marl.rundir import RunError, RunWarning, read_metrics, run_status
from containergym_marl.training.loop import train
from containergym_marl.training.train_args import TrainArgs

__all__ = [
    "ALGORITHMS",
    "REGISTRY",
    "AlgorithmSpec",
    "MissingExtraError",
    "RunError",
    "RunWarning",
    "TrainArgs",
    "get_algorithm",
    "paper_budget",
    "read_metrics",
    "run_status",
    "train",
]
