"""Evaluation: episode records, the paper's test protocol, statistics and figures."""

from containergym_marl.evaluation.protocol import (
    PAPER,
    EpisodeMetrics,
    EvalProtocol,
    EvaluationResult,
    evaluate,
)
from containergym_marl.evaluation.records import EpisodeRecord, EpisodeRecorder

__all__ = [
    "PAPER",
    "EpisodeMetrics",
    "EpisodeRecord",
    "EpisodeRecorder",
    "EvalProtocol",
    "EvaluationResult",
    "evaluate",
]
