"""The run log: `runs/<run>/episodes.mcap` and its sealed segments, written by the replay and
read by the views and benchmarks.

Modules: `format` (topics, constants, the error), `writer`, `reader`, `segments` (sealing and
recovery), `recovering` (outlives a full disk), `pruning` (a bounded log), `survey` (a bounded
read before a resume), `scene` (Foxglove).
The names below are the package's public interface; import them from `hercs.run.runlog`.
"""

from hercs.run.rundir import LIVE_NAME
from hercs.run.runlog.format import (
    MAX_SEQUENCE,
    METADATA_NAME,
    TOPIC_CLUSTER_MODEL,
    TOPIC_EPISODES,
    TOPIC_EVAL_RESULT,
    TOPIC_REPLAY_STATE,
    TOPIC_SCENE,
    TOPIC_SCENE_POINTS,
    EpisodeLogError,
)
from hercs.run.runlog.pruning import (
    SegmentHead,
    latest_replay_state,
    prune_log,
    read_head,
    segments_to_delete,
)
from hercs.run.runlog.reader import (
    LoggedMessage,
    SegmentScan,
    read_cluster_models,
    read_episode_messages,
    read_eval_results,
    read_messages,
    scan_segment,
    segment_paths,
)
from hercs.run.runlog.recovering import RecoveringLogWriter
from hercs.run.runlog.segments import EpisodeLog, RecoveredLog, run_start_ns, seal_segment
from hercs.run.runlog.survey import BadEpisode, LogSurvey, TornTail, survey_log
from hercs.run.runlog.writer import EpisodeLogWriter

__all__ = [
    "LIVE_NAME", "MAX_SEQUENCE", "METADATA_NAME", "TOPIC_CLUSTER_MODEL", "TOPIC_EPISODES",
    "TOPIC_EVAL_RESULT", "TOPIC_REPLAY_STATE", "TOPIC_SCENE", "TOPIC_SCENE_POINTS", "BadEpisode",
    "EpisodeLog", "EpisodeLogError", "EpisodeLogWriter", "LogSurvey", "LoggedMessage",
    "RecoveredLog", "RecoveringLogWriter", "SegmentHead", "SegmentScan", "TornTail",
    "latest_replay_state", "prune_log", "read_cluster_models", "read_episode_messages",
    "read_eval_results", "read_head", "read_messages", "run_start_ns", "scan_segment",
    "seal_segment", "segment_paths", "segments_to_delete", "survey_log",
]
