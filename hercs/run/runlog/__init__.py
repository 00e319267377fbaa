"""The run log: `runs/<run>/episodes.mcap` and its sealed segments, written by the replay and
read by the views and benchmarks.

- `format`: topics, file names, constants and `EpisodeLogError`;
- `writer`: `EpisodeLogWriter`, appends that are durable (fsync) before the replay acks;
- `reader`: messages back from a segment or a run directory, tolerant of a torn tail;
- `segments`: sealing a killed writer's file and `EpisodeLog.open`, the recovery on restart;
- `recovering`: `RecoveringLogWriter`, the replay's writer that outlives a full disk and
  splits a bounded log into segments;
- `pruning`: which old segments a bounded log deletes, and the replay state resume starts from;
- `scene`: the Foxglove scene messages logged with each episode.

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
    read_episodes,
    read_eval_results,
    read_messages,
    scan_segment,
    segment_paths,
)
from hercs.run.runlog.recovering import RecoveringLogWriter
from hercs.run.runlog.segments import EpisodeLog, RecoveredLog, run_start_ns, seal_segment
from hercs.run.runlog.writer import EpisodeLogWriter

__all__ = [
    "LIVE_NAME", "MAX_SEQUENCE", "METADATA_NAME", "TOPIC_CLUSTER_MODEL", "TOPIC_EPISODES",
    "TOPIC_EVAL_RESULT", "TOPIC_REPLAY_STATE", "TOPIC_SCENE", "TOPIC_SCENE_POINTS", "EpisodeLog",
    "EpisodeLogError", "EpisodeLogWriter", "LoggedMessage", "RecoveredLog",
    "RecoveringLogWriter", "SegmentHead", "SegmentScan", "latest_replay_state", "prune_log",
    "read_cluster_models", "read_episodes", "read_eval_results", "read_head", "read_messages",
    "run_start_ns", "scan_segment", "seal_segment", "segment_paths", "segments_to_delete",
]
