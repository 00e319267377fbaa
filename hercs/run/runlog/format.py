"""The run log's format, shared by its writer (the replay) and its readers (views, bench).

The one definition of the topics, MCAP sequence numbers, metadata record and synthetic timeline
of docs/DESIGN.md §6 ("The MCAP log"): episode k's observations at S + k·span + t·40 ms,
span = (T+2)·40 ms, from the run's real start S, so episodes never overlap.
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
