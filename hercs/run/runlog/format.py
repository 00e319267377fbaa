"""The run log's format, shared by its writer (the replay) and its readers (views, bench).

Contents (protobuf, schemas embedded):
    /episodes        hercs.Episode        MCAP message sequence = episode id (uint32)
    /cluster_model   hercs.ClusterModel   sequence = model version
    /eval_result     hercs.EvalResult     sequence = epoch
    /scene           foxglove.SceneUpdate gripper, object, goal per observation (Foxglove)
    /scene/points    foxglove.PointCloud  the same as coloured points (Rerun, Foxglove)
    /replay_state    hercs.ReplayState    sequence = next episode id; the first message of a
                                          segment the replay started while running (`pruning`)
plus one metadata record `hercs.episode_log` {run, task, schema_version, start_time_ns} at the
start.

Timeline: log_time is synthetic (see `hercs.run.runlog.scene`) from the run's real start S
(`start_time_ns`, ns since the Unix epoch, the same in every segment of a run): episode k's
observations sit at S + k·span + t·40 ms, span = (T+2)·40 ms, so episodes never overlap and a
viewer's clock starts at the day and hour the run started; its Episode message sits at
S + k·span. A ClusterModel or EvalResult sits in the gap after the last episode written by
this writer (S before the first). The synthetic clock runs ahead of the real one (an episode
takes (T+2)·40 ms on it, well under that in a run): publish_time of Episode, ClusterModel and
EvalResult is the real wall-clock time of the append; scene messages repeat their log_time.
Logs written before `start_time_ns` existed start at 0 (1970 in a viewer).

The log is split by job: this module (topics, constants, the error), `writer` (appends that
are durable before an ack), `reader` (messages back, tolerant of a torn tail), `segments`
(the run directory's segments across restarts: sealing and recovery) and `pruning` (which
old segments a bounded log deletes).
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf.message import Message
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from zstandard import ZstdError

from hercs.errors import HercsError
from hercs.proto import hercs_pb2 as pb

TOPIC_EPISODES = "/episodes"
TOPIC_CLUSTER_MODEL = "/cluster_model"
TOPIC_EVAL_RESULT = "/eval_result"
TOPIC_SCENE = "/scene"
TOPIC_SCENE_POINTS = "/scene/points"
TOPIC_REPLAY_STATE = "/replay_state"

METADATA_NAME = "hercs.episode_log"
START_TIME_KEY = "start_time_ns"
"""Metadata key: the run's start, the origin of the synthetic timeline (ns since the epoch)."""
MAX_SEQUENCE = 2**32 - 1
"""MCAP's message sequence is a uint32: the largest episode id the log can hold."""

CHUNK_BYTES = 8 * 2**20
"""Size cap of a chunk; in practice each append's flush closes the chunk well before it."""

DECODABLE: dict[str, type[Message]] = {
    cls.DESCRIPTOR.full_name: cls
    for cls in (pb.Episode, pb.ClusterModel, pb.EvalResult, pb.ReplayState, SceneUpdate,
                PointCloud)
}
RECORD_HEADER = struct.Struct("<BQ")
UNREADABLE_CHUNK = (McapError, ValueError, struct.error, ZstdError)
"""What mcap raises on a chunk that fails its CRC (a ValueError) or does not decompress."""
FOOTER_RECORD_BYTES = RECORD_HEADER.size + 20
OPCODES = frozenset(Opcode)
FOOTER_PREFIX = struct.Struct("<BQQQ")  # what the summary CRC covers of the footer


class EpisodeLogError(HercsError):
    """The episode log cannot be written or read as asked; the message says which file and
    what the caller should do."""


def u32(value: int, what: str) -> int:
    if not 0 <= value <= MAX_SEQUENCE:
        raise ValueError(f"{what}={value} does not fit the uint32 MCAP sequence")
    return int(value)


def fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
