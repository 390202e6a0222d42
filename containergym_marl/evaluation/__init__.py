"""Evaluation: episode records, the paper's test protocol, statistics and figures."""

from containergym_marl.evaluation.records import EpisodeRecord, EpisodeRecorder

__all__ = ["EpisodeRecord", "EpisodeRecorder"]
