"""The replay's durable episode log: `runs/<run>/episodes.mcap` and its sealed segments.

Contents (protobuf, schemas embedded):
    /episodes        hercs.Episode        MCAP message sequence = episode id (uint32)
    /cluster_model   hercs.ClusterModel   sequence = model version
    /eval_result     hercs.EvalResult     sequence = epoch
    /scene           foxglove.SceneUpdate gripper, object, goal per observation (Foxglove)
    /scene/points    foxglove.PointCloud  the same as coloured points (Rerun, Foxglove)
plus one metadata record `hercs.episode_log` {run, task, schema_version} at the start.

Timeline: log_time is synthetic (see `hercs.runlog.scene`): episode k's observations sit at
k·span + t·40 ms, span = (T+2)·40 ms, so episodes never overlap; its Episode message sits at
k·span. A ClusterModel or EvalResult sits in the gap after the last episode written by this
writer (0 before the first). publish_time of Episode, ClusterModel and EvalResult is the
wall-clock time of the append (ns since the Unix epoch); scene messages repeat their log_time.

Durability (docs/DESIGN.md §3, "durable before ack"): an append writes its messages as one zstd
chunk (mcap 1.6 `Writer.flush()` closes the chunk and writes it and its message indexes), then
`os.fsync`s the file; the replay acks only after the append returns. `append_many` is the
group commit: several episodes, one chunk, one fsync. An episode whose chunk reached the disk
but whose append never returned (killed between write and ack) is recovered too: delivery is
at-least-once and the replay deduplicates on (actor_id, seq).

Crash recovery: a killed writer leaves a file with no summary or footer and possibly a torn
last record. mcap 1.6 does not read such a file: `make_reader` on a seekable file reads the
footer first and raises (EndOfFile, struct.error or RecordLengthLimitExceeded, depending on
where the cut is) before yielding anything; `StreamReader` / `NonSeekingReader` yield the
complete records and then raise one of those same errors at the tail. This module therefore
walks the top-level records itself: a record whose 9-byte header or body extends past the end
of the file, or whose opcode is no MCAP opcode, is the torn tail and ends the scan quietly;
complete chunks are decoded with mcap's own record classes and their CRC checked. A chunk
that fails its CRC or does not decompress is the torn tail too, unless an intact chunk
follows it: then the file is damaged in the middle and `EpisodeLogError` is raised rather
than silently dropping acked data.

Segments: MCAP cannot be appended to after a torn tail or a footer, so each writer gets a
fresh file. The live segment is always `episodes.mcap`. `EpisodeLog.open` seals the previous
live segment if it was not finished (`seal_segment`: cut the torn tail, append DataEnd, a
summary rebuilt from the scan, footer and magic, so Rerun and Foxglove open it without a
recovery mode), renames it to `episodes.<n>.mcap` (n = 000, 001, … in order of writing), then
opens a new `episodes.mcap`. Readers of a run directory read the numbered segments in order,
then `episodes.mcap`. Episode ids continue across segments (the caller assigns them: one more
than the last recovered id).
"""

from __future__ import annotations

import io
import logging
import os
import re
import struct
import threading
import time
import zlib
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, NamedTuple, TypeVar

from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf.message import DecodeError, Message
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
)
from mcap.records import Message as McapMessage
from mcap.stream_reader import breakup_chunk
from mcap.well_known import MessageEncoding
from mcap.writer import LIBRARY_IDENTIFIER, MCAP0_MAGIC, CompressionType
from mcap.writer import Writer as McapWriter
from mcap_protobuf.schema import register_schema
from zstandard import ZstdError

from hercs.codec import msg_to_array
from hercs.errors import HercsError
from hercs.runlog import scene
from hercs.tasks import task_spec
from proto import hercs_pb2 as pb
from proto.schema import SCHEMA_VERSION

log = logging.getLogger(__name__)

TOPIC_EPISODES = "/episodes"
TOPIC_CLUSTER_MODEL = "/cluster_model"
TOPIC_EVAL_RESULT = "/eval_result"
TOPIC_SCENE = "/scene"
TOPIC_SCENE_POINTS = "/scene/points"

LIVE_NAME = "episodes.mcap"
_SEGMENT_RE = re.compile(r"^episodes\.(\d+)\.mcap$")
METADATA_NAME = "hercs.episode_log"
MAX_SEQUENCE = 2**32 - 1
"""MCAP's message sequence is a uint32: the largest episode id the log can hold."""

CHUNK_BYTES = 8 * 2**20
"""Size cap of a chunk; in practice each append's flush closes the chunk well before it."""

_DECODABLE: dict[str, type[Message]] = {
    cls.DESCRIPTOR.full_name: cls
    for cls in (pb.Episode, pb.ClusterModel, pb.EvalResult, SceneUpdate, PointCloud)
}
_HEADER = struct.Struct("<BQ")
_UNREADABLE_CHUNK = (McapError, ValueError, struct.error, ZstdError)
"""What mcap raises on a chunk that fails its CRC (a ValueError) or does not decompress."""
_FOOTER_RECORD_BYTES = _HEADER.size + 20
_OPCODES = frozenset(Opcode)
_FOOTER_PREFIX = struct.Struct("<BQQQ")  # what the summary CRC covers of the footer


M = TypeVar("M", bound=Message)

if not hasattr(McapWriter, "flush"):  # durability rests on it: fail at import, not at an ack
    raise ImportError("hercs.runlog.episode_log needs mcap.writer.Writer.flush() "
                      "(mcap >= 1.6); upgrade the mcap package")


class EpisodeLogError(HercsError):
    """The episode log cannot be written or read as asked; the message says which file and
    what the caller should do."""


# --------------------------------------------------------------------------------------------
# Writing


class _PreparedEpisode(NamedTuple):
    episode_id: int
    msg: pb.Episode
    updates: list[SceneUpdate]
    clouds: list[PointCloud]
    times_ns: list[int]


class EpisodeLogWriter:
    """Appends episodes (with their Foxglove scene), cluster models and eval results to a new
    MCAP file; every append is on disk (fsync) when it returns.

    Thread-safe: appends are serialised by a lock. If an append raises after it started
    writing, the file may end in a torn record: the writer refuses further appends (reopen the
    log with `EpisodeLog.open`, which recovers everything appended before). Invalid input
    (bad arrays, an episode id not above the last one) raises before anything is written and
    leaves the writer usable.
    """

    def __init__(self, path: str | os.PathLike[str], *, run: str, task: str,
                 compression: CompressionType = CompressionType.ZSTD) -> None:
        self.path = Path(path)
        self.run = run
        self.task = task
        self._spec = task_spec(task)
        self._lock = threading.Lock()
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._last_episode_id: int | None = None
        self._state = "open"
        try:
            self._file: IO[bytes] = open(self.path, "xb")  # noqa: SIM115 (closed in close())
        except FileExistsError:
            raise EpisodeLogError(
                f"{self.path} already exists; an episode log is never overwritten. Use "
                "EpisodeLog.open(run_dir) to recover it and continue in a new segment"
            ) from None
        self._mcap = McapWriter(self._file, chunk_size=CHUNK_BYTES, compression=compression)
        self._mcap.start(library=f"hercs episode_log, {LIBRARY_IDENTIFIER}")
        self._mcap.add_metadata(METADATA_NAME, {"run": run, "task": task,
                                                "schema_version": str(SCHEMA_VERSION)})
        self._sync()
        _fsync_dir(self.path.parent)

    @property
    def last_episode_id(self) -> int | None:
        return self._last_episode_id

    def append_episode(self, msg: pb.Episode, *, episode_id: int,
                       log_time_ns: int | None = None) -> None:
        """Log one episode and its per-step scene; durable when this returns.

        `log_time_ns` is the wall-clock time of the insert (default now), stored as the
        messages' publish_time; their log_time is the synthetic timeline (module docstring).
        """
        self.append_many([(episode_id, msg)], log_time_ns=log_time_ns)

    def append_many(self, episodes: Sequence[tuple[int, pb.Episode]], *,
                    log_time_ns: int | None = None) -> None:
        """Group commit: log `(episode_id, Episode)` pairs, ids strictly increasing, as one
        chunk with one fsync; all are durable when this returns, none may be acked before."""
        wall = time.time_ns() if log_time_ns is None else int(log_time_ns)
        with self._lock:
            self._check_writable()
            prepared = self._prepare(episodes)
            self._write_durably(record for episode in prepared
                                for record in self._episode_records(episode, wall))
            if prepared:
                self._last_episode_id = prepared[-1].episode_id

    def append_cluster_model(self, msg: pb.ClusterModel, *, log_time_ns: int | None = None
                             ) -> None:
        """Log a cluster model (sequence = its version); durable when this returns."""
        self._append_other(TOPIC_CLUSTER_MODEL, msg, _u32(msg.version, "ClusterModel.version"),
                           log_time_ns)

    def append_eval_result(self, msg: pb.EvalResult, *, log_time_ns: int | None = None) -> None:
        """Log an evaluation result (sequence = its epoch); durable when this returns."""
        self._append_other(TOPIC_EVAL_RESULT, msg, _u32(msg.epoch, "EvalResult.epoch"),
                           log_time_ns)

    def close(self) -> None:
        """Write the summary (index, statistics) and footer, fsync and close. Idempotent. A
        writer that failed mid-append is closed without a footer (recovery seals it)."""
        with self._lock:
            if self._state == "closed":
                return
            failed, self._state = self._state == "failed", "closed"
            if failed:
                try:
                    self._file.close()  # may retry the write that failed
                except OSError as exc:
                    log.warning("%s: closing after a failed append: %s", self.path, exc)
                return
            try:
                self._mcap.finish()
                self._file.flush()
                os.fsync(self._file.fileno())
            finally:
                self._file.close()

    def __enter__(self) -> EpisodeLogWriter:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- internals ---------------------------------------------------------------------------

    def _check_writable(self) -> None:
        if self._state == "closed":
            raise EpisodeLogError(f"{self.path}: append after close(); nothing was written")
        if self._state == "failed":
            raise EpisodeLogError(
                f"{self.path}: an earlier append failed while writing, so the file may end in "
                "a torn record; nothing more is appended. Reopen with EpisodeLog.open(run_dir)")

    def _prepare(self, episodes: Sequence[tuple[int, pb.Episode]]) -> list[_PreparedEpisode]:
        """Check ids and build every message before the first byte is written."""
        T = self._spec.episode_steps
        prepared = []
        last = self._last_episode_id
        for episode_id, msg in episodes:
            episode_id = int(episode_id)
            if not 0 <= episode_id <= MAX_SEQUENCE:
                raise ValueError(f"episode_id={episode_id}: must be in [0, {MAX_SEQUENCE}] "
                                 "(it is stored as the uint32 MCAP message sequence)")
            if last is not None and episode_id <= last:
                raise ValueError(f"episode_id={episode_id}: ids must increase, the last logged "
                                 f"id is {last}; nothing was written")
            if (msg.run, msg.task) != (self.run, self.task):
                raise ValueError(f"episode_id={episode_id}: Episode of run {msg.run!r} task "
                                 f"{msg.task!r} in the log of run {self.run!r} task "
                                 f"{self.task!r}; nothing was written")
            last = episode_id
            obs = msg_to_array(msg.obs, where="Episode.obs")
            positions = scene.episode_positions(
                obs, msg_to_array(msg.ag, where="Episode.ag"),
                msg_to_array(msg.g, where="Episode.g"), self._spec)
            times = scene.step_times_ns(episode_id, len(obs), T)
            labels = {"episode_id": str(episode_id), "actor_id": msg.actor_id,
                      "seq": str(msg.seq), "success": str(bool(msg.success)).lower()}
            updates = scene.scene_updates(positions, times,
                                          goal_diameter=2 * self._spec.distance_threshold,
                                          labels=labels)
            prepared.append(_PreparedEpisode(episode_id, msg, updates,
                                             scene.point_clouds(positions, times), times))
        return prepared

    def _episode_records(self, episode: _PreparedEpisode, wall: int
                         ) -> Iterator[tuple[str, Message, int, int, int]]:
        """(topic, message, log_time, publish_time, sequence) of one episode, in time order."""
        start = scene.episode_start_ns(episode.episode_id, self._spec.episode_steps)
        yield TOPIC_EPISODES, episode.msg, start, wall, episode.episode_id
        for update, cloud, t in zip(episode.updates, episode.clouds, episode.times_ns,
                                    strict=True):
            yield TOPIC_SCENE, update, t, t, episode.episode_id
            yield TOPIC_SCENE_POINTS, cloud, t, t, episode.episode_id

    def _append_other(self, topic: str, msg: Message, sequence: int,
                      log_time_ns: int | None) -> None:
        wall = time.time_ns() if log_time_ns is None else int(log_time_ns)
        with self._lock:
            self._check_writable()
            self._write_durably([(topic, msg, self._gap_time_ns(), wall, sequence)])

    def _gap_time_ns(self) -> int:
        """The empty slot after the last episode written here: between it and the next one."""
        if self._last_episode_id is None:
            return 0
        return (scene.episode_start_ns(self._last_episode_id + 1, self._spec.episode_steps)
                - scene.STEP_NS)

    def _write_durably(self, records: Iterable[tuple[str, Message, int, int, int]]) -> None:
        try:
            for topic, msg, log_time, publish_time, sequence in records:
                self._mcap.add_message(channel_id=self._channel(topic, msg), log_time=log_time,
                                       data=msg.SerializeToString(),
                                       publish_time=publish_time, sequence=sequence)
            self._sync()
        except BaseException:
            self._state = "failed"
            raise

    def _channel(self, topic: str, msg: Message) -> int:
        channel_id = self._channels.get(topic)
        if channel_id is None:
            name = msg.DESCRIPTOR.full_name
            schema_id = self._schemas.get(name)
            if schema_id is None:
                schema_id = self._schemas[name] = register_schema(self._mcap, type(msg))
            channel_id = self._channels[topic] = self._mcap.register_channel(
                topic=topic, message_encoding=MessageEncoding.Protobuf, schema_id=schema_id)
        return channel_id

    def _sync(self) -> None:
        self._mcap.flush()  # closes the chunk, writes it and flushes the Python buffer
        os.fsync(self._file.fileno())


def _u32(value: int, what: str) -> int:
    if not 0 <= value <= MAX_SEQUENCE:
        raise ValueError(f"{what}={value} does not fit the uint32 MCAP sequence")
    return int(value)


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


# --------------------------------------------------------------------------------------------
# Reading (tolerant of a torn tail)


@dataclass
class LoggedMessage:
    """One message read back from the log; `decode()` parses it with the project's class."""

    topic: str
    schema_name: str
    sequence: int
    log_time_ns: int
    publish_time_ns: int
    data: bytes

    def decode(self) -> Message:
        """Parse with the class the schema names (hercs or Foxglove messages)."""
        cls = _DECODABLE.get(self.schema_name)
        if cls is None:
            raise EpisodeLogError(f"{self.topic}: no decoder for schema {self.schema_name!r}; "
                                  f"known: {sorted(_DECODABLE)}")
        return self.decode_as(cls)

    def decode_as(self, cls: type[M]) -> M:
        if self.schema_name != cls.DESCRIPTOR.full_name:
            raise EpisodeLogError(f"{self.topic} message {self.sequence} has schema "
                                  f"{self.schema_name!r}, not {cls.DESCRIPTOR.full_name!r}")
        msg = cls()
        try:
            msg.ParseFromString(self.data)
        except DecodeError as exc:
            raise EpisodeLogError(f"{self.topic} message {self.sequence} does not parse as "
                                  f"{self.schema_name}: {exc}") from None
        return msg


@dataclass
class SegmentScan:
    """What a full read of one segment found."""

    path: Path
    size: int = 0
    finished: bool = False
    """Footer and closing magic present: the writer called close() (or the file was sealed)."""
    valid_end: int = 0
    """Offset just past the last complete, intact data-section record."""
    messages: int | None = 0
    """Messages read (None: not counted, the file was found finished and left unread)."""
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)

    @property
    def dropped_bytes(self) -> int:
        """Bytes after `valid_end` that are not a complete record (0 for a finished file)."""
        return 0 if self.finished else self.size - self.valid_end


@dataclass
class _IndexParts:
    """What a summary needs, gathered while scanning a segment's intact records."""

    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    chunk_indexes: list[ChunkIndex] = field(default_factory=list)
    metadata_indexes: list[MetadataIndex] = field(default_factory=list)
    channel_message_counts: dict[int, int] = field(default_factory=dict)
    start_time: int | None = None
    end_time: int = 0


class _SegmentReader:
    """Reads one MCAP segment's messages in file order, stopping quietly at a torn tail, and
    gathers what `seal_segment` needs to write the segment's summary."""

    def __init__(self, path: Path, *, metadata_only: bool = False) -> None:
        self.scan = SegmentScan(path=path)
        self.parts = _IndexParts()
        self._metadata_only = metadata_only
        self.reached_data = False
        """A chunk was found (a metadata-only read stops there)."""
        self._chunk_channels: set[int] = set()  # channels with messages in the last chunk

    def messages(self) -> Iterator[LoggedMessage]:
        scan = self.scan
        with open(scan.path, "rb") as f:
            scan.size = os.fstat(f.fileno()).st_size
            magic = f.read(len(MCAP0_MAGIC))
            if magic != MCAP0_MAGIC:
                if len(magic) < len(MCAP0_MAGIC) and MCAP0_MAGIC.startswith(magic):
                    return  # killed before the magic was complete: an empty log
                raise EpisodeLogError(f"{scan.path} is not an MCAP file (starts with {magic!r})")
            scan.valid_end = len(MCAP0_MAGIC)
            yield from self._records(f)
        self._close_chunk_index()

    def _records(self, f: IO[bytes]) -> Iterator[LoggedMessage]:
        scan = self.scan
        pos = scan.valid_end
        bad_chunk_at: int | None = None
        data_ended = False
        while True:
            header = f.read(_HEADER.size)
            if len(header) < _HEADER.size:
                return  # end of file, or a torn record header
            opcode, length = _HEADER.unpack(header)
            if opcode not in _OPCODES or length > scan.size - pos - _HEADER.size:
                return  # torn record (body past the end of the file) or bytes that are no record
            body = f.read(length)
            end = pos + _HEADER.size + length
            if opcode == Opcode.FOOTER:
                scan.finished = bad_chunk_at is None and f.read(len(MCAP0_MAGIC)) == MCAP0_MAGIC
                return
            if opcode != Opcode.MESSAGE_INDEX:
                self._close_chunk_index()
            records: list[Any] = []
            if opcode == Opcode.DATA_END:
                data_ended = True  # the summary repeats schemas and channels: skip it
            elif data_ended or (bad_chunk_at is not None and opcode != Opcode.CHUNK):
                pass
            elif opcode == Opcode.CHUNK:
                self.reached_data = True
                if self._metadata_only:
                    return
                try:
                    chunk = Chunk.read(ReadDataStream(io.BytesIO(body)))
                    records = breakup_chunk(chunk, validate_crc=True)
                except _UNREADABLE_CHUNK as exc:
                    if bad_chunk_at is None:
                        log.warning("%s: chunk at offset %d is unreadable (%s); treating it as "
                                    "the torn tail", scan.path, pos, exc)
                        bad_chunk_at = pos
                else:
                    if bad_chunk_at is not None:
                        raise EpisodeLogError(
                            f"{scan.path}: the chunk at offset {bad_chunk_at} is corrupt but "
                            f"an intact chunk follows at {pos}: the file is damaged in the "
                            "middle, not torn at the end; nothing is recovered from it. Keep "
                            "the file for inspection and restore it from a copy")
                    self.parts.chunk_indexes.append(ChunkIndex(
                        message_start_time=chunk.message_start_time,
                        message_end_time=chunk.message_end_time, chunk_start_offset=pos,
                        chunk_length=end - pos, message_index_offsets={},
                        message_index_length=0, compression=chunk.compression,
                        compressed_size=len(chunk.data),
                        uncompressed_size=chunk.uncompressed_size))
            elif opcode == Opcode.MESSAGE_INDEX:
                self._add_message_index(body, pos, end)
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE):
                records = [_read_record(opcode, body, length)]
            elif opcode == Opcode.METADATA:
                meta = Metadata.read(ReadDataStream(io.BytesIO(body)))
                scan.metadata[meta.name] = dict(meta.metadata)
                self.parts.metadata_indexes.append(
                    MetadataIndex(offset=pos, length=end - pos, name=meta.name))
            pos = end
            if bad_chunk_at is None and not data_ended:
                scan.valid_end = end
            for record in records:
                if isinstance(record, Schema):
                    self.parts.schemas[record.id] = record
                elif isinstance(record, Channel):
                    self.parts.channels[record.id] = record
                elif isinstance(record, McapMessage):
                    yield self._message(record)

    def _add_message_index(self, body: bytes, pos: int, end: int) -> None:
        """Message indexes follow their chunk; kept only if they cover all its channels."""
        if not self.parts.chunk_indexes or len(body) < 2:
            return
        index = self.parts.chunk_indexes[-1]
        (channel_id,) = struct.unpack_from("<H", body)
        index.message_index_offsets[channel_id] = pos
        index.message_index_length += end - pos

    def _close_chunk_index(self) -> None:
        """A chunk's message indexes are usable only if all were written before a kill."""
        if self.parts.chunk_indexes:
            index = self.parts.chunk_indexes[-1]
            if set(index.message_index_offsets) != self._chunk_channels:
                index.message_index_offsets, index.message_index_length = {}, 0
        self._chunk_channels = set()

    def _message(self, record: McapMessage) -> LoggedMessage:
        parts = self.parts
        channel = parts.channels.get(record.channel_id)
        if channel is None:
            raise EpisodeLogError(f"{self.scan.path}: message on unknown channel "
                                  f"{record.channel_id}; the file is damaged")
        schema = parts.schemas.get(channel.schema_id)
        self.scan.messages = (self.scan.messages or 0) + 1
        self._chunk_channels.add(record.channel_id)
        parts.channel_message_counts[record.channel_id] = (
            parts.channel_message_counts.get(record.channel_id, 0) + 1)
        parts.start_time = (record.log_time if parts.start_time is None
                            else min(parts.start_time, record.log_time))
        parts.end_time = max(parts.end_time, record.log_time)
        return LoggedMessage(topic=channel.topic, schema_name=schema.name if schema else "",
                             sequence=record.sequence, log_time_ns=record.log_time,
                             publish_time_ns=record.publish_time, data=record.data)


def _read_record(opcode: int, body: bytes, length: int) -> Any:
    stream = ReadDataStream(io.BytesIO(body))
    if opcode == Opcode.SCHEMA:
        return Schema.read(stream)
    if opcode == Opcode.CHANNEL:
        return Channel.read(stream)
    return McapMessage.read(stream, length)


def scan_segment(path: str | os.PathLike[str]) -> SegmentScan:
    """Read a whole segment and report whether it is finished and where its valid data ends."""
    reader = _SegmentReader(Path(path))
    for _ in reader.messages():
        pass
    return reader.scan


def segment_paths(run_dir: str | os.PathLike[str]) -> list[Path]:
    """The run's segments in order of writing: episodes.000.mcap, …, then episodes.mcap."""
    run_dir = Path(run_dir)
    numbered = sorted(
        (int(m.group(1)), p) for p in run_dir.iterdir()
        if (m := _SEGMENT_RE.match(p.name)) is not None
    ) if run_dir.is_dir() else []
    paths = [p for _, p in numbered]
    if (run_dir / LIVE_NAME).exists():
        paths.append(run_dir / LIVE_NAME)
    return paths


def _paths(path: str | os.PathLike[str]) -> list[Path]:
    path = Path(path)
    return segment_paths(path) if path.is_dir() else [path]


def read_messages(path: str | os.PathLike[str], topics: Iterable[str] | None = None
                  ) -> Iterator[LoggedMessage]:
    """Messages of a segment file, or of every segment of a run directory, in file order.

    Works on a file whose writer was killed: stops at the last complete record."""
    wanted = None if topics is None else set(topics)
    for segment in _paths(path):
        for message in _SegmentReader(segment).messages():
            if wanted is None or message.topic in wanted:
                yield message


def read_episodes(path: str | os.PathLike[str]) -> Iterator[tuple[int, pb.Episode]]:
    """(episode_id, Episode) in the order logged, from a segment or a run directory."""
    for message in read_messages(path, [TOPIC_EPISODES]):
        yield message.sequence, message.decode_as(pb.Episode)


def read_cluster_models(path: str | os.PathLike[str]) -> Iterator[pb.ClusterModel]:
    for message in read_messages(path, [TOPIC_CLUSTER_MODEL]):
        yield message.decode_as(pb.ClusterModel)


def read_eval_results(path: str | os.PathLike[str]) -> Iterator[pb.EvalResult]:
    for message in read_messages(path, [TOPIC_EVAL_RESULT]):
        yield message.decode_as(pb.EvalResult)


# --------------------------------------------------------------------------------------------
# Segments across restarts


def _is_finished(path: Path) -> bool:
    """Cheap check: the file ends in a footer record and the closing magic."""
    size = path.stat().st_size
    tail_len = _FOOTER_RECORD_BYTES + len(MCAP0_MAGIC)
    if size < len(MCAP0_MAGIC) + tail_len:
        return False
    with open(path, "rb") as f:
        f.seek(size - tail_len)
        tail = f.read(tail_len)
    opcode, length = _HEADER.unpack_from(tail)
    return opcode == Opcode.FOOTER and length == 20 and tail.endswith(MCAP0_MAGIC)


def seal_segment(path: str | os.PathLike[str]) -> SegmentScan:
    """Make a killed writer's file a complete MCAP file: cut the torn tail at the last intact
    record and append DataEnd, a summary (schemas, channels, statistics, chunk and metadata
    indexes) rebuilt from the scan, the footer and the magic, so that indexed readers
    (mcap's make_reader, Rerun, Foxglove) open it without a recovery mode.

    Idempotent; a finished file is left untouched. A crash while sealing leaves a torn tail
    again, which the next call cuts. Nothing acked is cut: an ack follows the fsync of
    complete records.
    """
    path = Path(path)
    if _is_finished(path):
        size = path.stat().st_size
        return SegmentScan(path=path, size=size, finished=True, valid_end=size, messages=None)
    reader = _SegmentReader(path)
    for _ in reader.messages():
        pass
    scan = reader.scan
    if scan.finished:
        return scan
    if scan.dropped_bytes:
        log.warning("%s: cutting a torn tail of %d bytes after offset %d", path,
                    scan.dropped_bytes, scan.valid_end)
    with open(path, "r+b") as f:
        if scan.valid_end < len(MCAP0_MAGIC):  # killed before the magic was complete
            f.seek(0)
            f.write(MCAP0_MAGIC)
            scan.valid_end = len(MCAP0_MAGIC)
        f.truncate(scan.valid_end)
        f.seek(scan.valid_end)
        f.write(_closing_bytes(reader.parts, scan.valid_end))
        f.flush()
        os.fsync(f.fileno())
    scan.size, scan.finished = path.stat().st_size, True
    return scan


def _closing_bytes(parts: _IndexParts, data_end_offset: int) -> bytes:
    """DataEnd + summary + footer + magic for a data section ending at `data_end_offset`."""
    builder = RecordBuilder()
    DataEnd(data_section_crc=0).write(builder)
    data_end = builder.end()
    summary_start = data_end_offset + len(data_end)
    for schema in parts.schemas.values():
        schema.write(builder)
    for channel in parts.channels.values():
        channel.write(builder)
    Statistics(
        message_count=sum(parts.channel_message_counts.values()),
        schema_count=len(parts.schemas), channel_count=len(parts.channels),
        attachment_count=0, metadata_count=len(parts.metadata_indexes),
        chunk_count=len(parts.chunk_indexes),
        message_start_time=parts.start_time or 0, message_end_time=parts.end_time,
        channel_message_counts=dict(parts.channel_message_counts),
    ).write(builder)
    for chunk_index in parts.chunk_indexes:
        chunk_index.write(builder)
    for metadata_index in parts.metadata_indexes:
        metadata_index.write(builder)
    summary = builder.end()
    summary_crc = zlib.crc32(_FOOTER_PREFIX.pack(Opcode.FOOTER, 20, summary_start, 0),
                             zlib.crc32(summary))
    Footer(summary_start=summary_start, summary_offset_start=0,
           summary_crc=summary_crc).write(builder)
    return data_end + summary + builder.end() + MCAP0_MAGIC


def _check_metadata(path: Path, *, run: str, task: str) -> None:
    reader = _SegmentReader(path, metadata_only=True)
    for _ in reader.messages():
        pass
    meta = reader.scan.metadata.get(METADATA_NAME)
    if meta is None and not reader.reached_data and path.name == LIVE_NAME:
        return  # killed before its first fsync: the writer syncs metadata before any episode
    if meta is None:
        raise EpisodeLogError(f"{path} has no {METADATA_NAME!r} metadata: it is not a hercs "
                              "episode log; move it out of the run directory")
    if meta.get("run") != run or meta.get("task") != task:
        raise EpisodeLogError(
            f"{path} was written for run {meta.get('run')!r} task {meta.get('task')!r}; this "
            f"replay serves run {run!r} task {task!r}. Refusing to mix logs: use another run "
            "directory")


class EpisodeLog:
    """The episode log of one run directory: sealed segments plus the live `episodes.mcap`."""

    def __init__(self, run_dir: str | os.PathLike[str]) -> None:
        self.run_dir = Path(run_dir)

    @property
    def live_path(self) -> Path:
        return self.run_dir / LIVE_NAME

    def segments(self) -> list[Path]:
        return segment_paths(self.run_dir)

    def episodes(self) -> Iterator[tuple[int, pb.Episode]]:
        return read_episodes(self.run_dir)

    @classmethod
    def open(cls, run_dir: str | os.PathLike[str], *, run: str, task: str
             ) -> tuple[EpisodeLogWriter, Iterator[tuple[int, pb.Episode]]]:
        """Recover the run's log and start a new live segment.

        Seals and renames a previous `episodes.mcap` (deleted instead if it holds no message),
        checks every segment was written for this run and task, and opens a writer on a new
        `episodes.mcap`. Returns it with a lazy iterator over the recovered (episode_id,
        Episode) pairs of the sealed segments, in order; those files no longer change, so the
        iterator may be consumed while the writer appends. Consume it before assigning new
        episode ids (they must exceed the last recovered one).
        """
        log_dir = cls(run_dir)
        log_dir.run_dir.mkdir(parents=True, exist_ok=True)
        for segment in log_dir.segments():  # before changing anything
            _check_metadata(segment, run=run, task=task)
        live = log_dir.live_path
        if live.exists():
            cls._retire_live(live)
        sealed = log_dir.segments()
        writer = EpisodeLogWriter(live, run=run, task=task)

        def recovered() -> Iterator[tuple[int, pb.Episode]]:
            for segment in sealed:
                yield from read_episodes(segment)

        return writer, recovered()

    @staticmethod
    def _retire_live(live: Path) -> None:
        """Seal the previous live segment and give it the next segment number; a segment with
        no message at all (killed before its first append) is deleted instead."""
        scan = seal_segment(live)
        if scan.messages == 0:
            live.unlink()
        else:
            numbers = [int(m.group(1)) for p in live.parent.iterdir()
                       if (m := _SEGMENT_RE.match(p.name)) is not None]
            os.rename(live, live.parent / f"episodes.{max(numbers, default=-1) + 1:03d}.mcap")
        _fsync_dir(live.parent)
