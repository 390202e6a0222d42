"""Training glue: the algorithm registry, run directories and the training loop (SB3 / sb3-contrib /
SuperSuit, imported only when a run starts)."""

from containergym_marl.training.algorithms import (
    ALGORITHMS,
    METHODS,
    REGISTRY,
    RULE_BASED,
    AlgorithmSpec,
    MissingExtraError,
    get_algorithm,
    paper_budget,
    view_of,
)
from containergym_marl.training.loop import train
from containergym_marl.training.runs import RunError, RunWarning, TrainArgs, read_metrics, run_status

__all__ = [
    "ALGORITHMS",
    "METHODS",
    "REGISTRY",
    "RULE_BASED",
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
    "view_of",
]
