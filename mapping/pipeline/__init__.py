"""The one run pipeline over a source of frames (simulated or a data set).

    source       the ``Source`` protocol: streams, vocabulary, ground truth, sensor views
    settings     RunSettings: how a run goes (the ``run`` node of the configuration tree)
    runner       run_team(source, record, config, schedule) -> RunResult; rounds, evaluation, outputs
    scoring      every agent's map against the ground truth (three cullings), team semantics
    records      atomic JSON, settings records, stale checkpoints
    plots        the run's pictures
    summary      the results table a run prints
"""

from mapping.pipeline.runner import RunConfig, RunResult, Schedule, run_team
from mapping.pipeline.settings import RunSettings
from mapping.pipeline.source import CameraViews, GroundTruth, Source, SourceRecord

__all__ = ["CameraViews", "GroundTruth", "RunConfig", "RunResult", "RunSettings", "Schedule", "Source", "SourceRecord",
           "run_team"]
