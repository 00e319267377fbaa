"""A read of some topics of the episode log (what a restarted replay does) skips the chunks
that hold none of them, decided from the message indexes after each chunk, and yields exactly
what a read of every message yields for those topics: on a whole log, on a log cut at any
record boundary (a killed writer), and with a damaged chunk of a topic it reads."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap.opcode import Opcode
from mcap.records import ChunkIndex

from bench.synthetic_episodes import random_episode
from hercs.proto import hercs_pb2 as pb
from hercs.rl.task_registry import task_spec
from hercs.run.rundir import RunDir
from hercs.run.runlog import (
    TOPIC_CLUSTER_MODEL,
    TOPIC_EPISODES,
    TOPIC_SCENE,
    TOPIC_SCENE_POINTS,
    EpisodeLogError,
    EpisodeLogWriter,
    read_messages,
    scan_segment,
)
from hercs.run.runlog.format import RECORD_HEADER
from hercs.run.runlog.reader import SegmentReader
from hercs.wire.codec import episode_to_msg

RUN = "t"


def write_log(path: Path, episodes: int, *, close: bool) -> None:
    """Episodes with their scenes, a cluster model after the second; closed, or left as a
    killed writer leaves it."""
    spec = task_spec("push")
    writer = EpisodeLogWriter(path, run=RUN, task="push")
    for i in range(episodes):
        episode = random_episode(spec, np.random.default_rng(i), seq=i)
        writer.append_episode(episode_to_msg(episode, run=RUN, task="push"), episode_id=i)
        writer.flush_scenes()
        if i == 1:
            writer.append_cluster_model(pb.ClusterModel(version=1, fitted_on=150))
    if close:
        writer.close()


def by_topic(path: Path, topic: str) -> list[tuple[int, bytes]]:
    """What a read of every message yields on `topic`."""
    return [(m.sequence, m.data) for m in read_messages(path) if m.topic == topic]


def filtered(path: Path, topic: str) -> list[tuple[int, bytes]]:
    return [(m.sequence, m.data) for m in read_messages(path, [topic])]


def record_spans(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, end, opcode) of each top-level record after the magic."""
    out, pos = [], 8
    while pos + RECORD_HEADER.size <= len(data):
        opcode, length = RECORD_HEADER.unpack_from(data, pos)
        end = pos + RECORD_HEADER.size + length
        if end > len(data):
            break
        out.append((pos, end, opcode))
        if opcode == Opcode.FOOTER:
            break
        pos = end
    return out


@pytest.mark.parametrize("close", [True, False], ids=["closed", "killed"])
def test_a_read_of_episodes_skips_the_scene_chunks_and_misses_nothing(
        tmp_path: Path, close: bool) -> None:
    path = RunDir(tmp_path).episode_log
    write_log(path, 6, close=close)
    for topic in (TOPIC_EPISODES, TOPIC_CLUSTER_MODEL):
        assert filtered(path, topic) == by_topic(path, topic)
    assert [i for i, _ in filtered(path, TOPIC_EPISODES)] == list(range(6))
    reader = SegmentReader(path, topics=[TOPIC_EPISODES])
    assert sum(1 for _ in reader.messages()) == 6
    # each episode's scene is a chunk of its own; the first defines the scene channels, and
    # the last one's indexes are followed by nothing in a killed file: those two are read
    assert reader.chunks_skipped >= 6 - 2, reader.chunks_skipped
    # sealing reads everything: a read of some topics must not change what it finds
    assert scan_segment(path).messages == sum(1 for _ in read_messages(path))


def test_a_log_cut_at_any_record_boundary_reads_the_same_episodes(tmp_path: Path) -> None:
    """Cut inside or between a chunk and its message indexes: a chunk whose indexes are not
    all there is read, never skipped on their word."""
    full = tmp_path / "full.mcap"
    write_log(full, 3, close=False)
    data = full.read_bytes()
    cuts = {c for start, end, _ in record_spans(data) for b in (start, end)
            for c in (b - 1, b, b + 1, b + RECORD_HEADER.size + 1) if 0 <= c <= len(data)}
    cut = tmp_path / "cut.mcap"
    for at in sorted(cuts):
        cut.write_bytes(data[:at])
        assert filtered(cut, TOPIC_EPISODES) == by_topic(cut, TOPIC_EPISODES), f"cut at {at}"


def test_a_damaged_episode_chunk_is_refused_and_a_damaged_skipped_one_is_not_read(
        tmp_path: Path) -> None:
    path = RunDir(tmp_path).episode_log
    write_log(path, 6, close=True)
    data = path.read_bytes()
    reader = SegmentReader(path)
    reader.read_through()
    channel_of = {c.id: c.topic for c in reader.parts.channels.values()}
    chunks = [c for c in reader.parts.chunk_indexes if c.message_index_offsets]
    episode_chunks = [c for c in chunks
                      if {channel_of[i] for i in c.message_index_offsets} == {TOPIC_EPISODES}]
    scene_only = [c for c in chunks if {channel_of[i] for i in c.message_index_offsets}
                  <= {TOPIC_SCENE, TOPIC_SCENE_POINTS}]
    assert len(episode_chunks) == 6 and len(scene_only) >= 4

    def damaged(chunk: ChunkIndex) -> Path:
        out = tmp_path / "damaged.mcap"
        copy = bytearray(data)
        copy[chunk.chunk_start_offset + chunk.chunk_length - 20] ^= 0xFF  # in its data
        out.write_bytes(bytes(copy))
        return out

    # an episode's chunk in the middle, damaged: refused, however the chunks around are read
    with pytest.raises(EpisodeLogError, match="damaged in the middle"):
        filtered(damaged(episode_chunks[2]), TOPIC_EPISODES)
    # a scene chunk in the middle, damaged: a read of every message refuses the file, a read of
    # the episodes does not decompress it and gets every episode, intact
    scene = damaged(scene_only[3])
    with pytest.raises(EpisodeLogError, match="damaged in the middle"):
        by_topic(scene, TOPIC_EPISODES)
    assert filtered(scene, TOPIC_EPISODES) == filtered(path, TOPIC_EPISODES)


@pytest.mark.parametrize("close", [True, False], ids=["closed", "killed"])
def test_every_chunk_keeps_its_message_indexes_and_a_declined_one_is_counted_unread(
        tmp_path: Path, close: bool) -> None:
    """The last chunk of a closed file too (its indexes checked once, at the DataEnd after
    them); `read_chunk` declining every episode chunk leaves only the one a read cannot skip
    (it defines the channel) and counts the others as skipped."""
    path = RunDir(tmp_path).episode_log
    write_log(path, 6, close=close)
    reader = SegmentReader(path)
    reader.read_through()
    assert all(c.message_index_offsets for c in reader.parts.chunk_indexes)
    declining = SegmentReader(path, topics=[TOPIC_EPISODES], read_chunk=lambda *_: False)
    read = [m.sequence for m in declining.messages()]
    assert read == [0], read
    assert declining.skipped[TOPIC_EPISODES] == 6 - len(read)
