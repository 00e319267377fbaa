"""Reading the run log back: messages of one segment or of a whole run directory, in file
order, tolerant of a writer that was killed.

mcap's own readers refuse a file with no summary or footer, which a killed writer leaves, so the
top-level records are walked here (with `struct`: a restarted replay reads its whole buffer
back). A torn tail (a record cut short, a chunk failing its CRC or not decompressing) ends the
scan quietly; a bad chunk followed by an intact one raises `EpisodeLogError` rather than drop
acked data. Chunks holding only topics not asked for, or that the caller's `read_chunk`
declines, are neither read nor decompressed (their message indexes say what they hold).
"""

from __future__ import annotations

import io
import logging
import os
import struct
from collections import Counter
from collections.abc import Callable, Collection, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, TypeVar

from google.protobuf.message import DecodeError, Message
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, ChunkIndex, Metadata, MetadataIndex, Schema
from mcap.stream_reader import get_chunk_data_stream
from mcap.writer import MCAP0_MAGIC

from hercs.proto import hercs_pb2 as pb
from hercs.run.rundir import RunDir
from hercs.run.runlog.format import (
    DECODABLE,
    OPCODES,
    RECORD_HEADER,
    TOPIC_CLUSTER_MODEL,
    TOPIC_EPISODES,
    TOPIC_EVAL_RESULT,
    UNREADABLE_CHUNK,
    EpisodeLogError,
)

log = logging.getLogger(__name__)

M = TypeVar("M", bound=Message)


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
        cls = DECODABLE.get(self.schema_name)
        if cls is None:
            raise EpisodeLogError(f"{self.topic}: no decoder for schema {self.schema_name!r}; "
                                  f"known: {sorted(DECODABLE)}")
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
class IndexParts:
    """What a summary needs, gathered while scanning a segment's intact records."""

    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    chunk_indexes: list[ChunkIndex] = field(default_factory=list)
    metadata_indexes: list[MetadataIndex] = field(default_factory=list)
    channel_message_counts: dict[int, int] = field(default_factory=dict)
    start_time: int | None = None
    end_time: int = 0


class SegmentReader:
    """Reads one MCAP segment's messages in file order, stopping quietly at a torn tail, and
    gathers what `seal_segment` needs to write the segment's summary.

    Why not mcap's readers (mcap 1.6): `make_reader` on a seekable file reads the footer first
    and raises (EndOfFile, struct.error or RecordLengthLimitExceeded, depending on where the
    cut is) before yielding anything; `StreamReader` / `NonSeekingReader` yield the complete
    records and then raise one of those same errors at the tail. Here a record whose 9-byte
    header or body extends past the end of the file ends the scan.

    A read for some topics skips a chunk only when its message indexes are complete (another
    record follows them) and name channels already defined, and while no chunk was found
    unreadable; its CRC is then not checked: a damaged chunk among those skipped is not
    noticed, one that holds a topic asked for always is."""

    def __init__(self, path: Path, *, metadata_only: bool = False,
                 topics: Collection[str] | None = None,
                 read_chunk: Callable[[int, int], bool] | None = None) -> None:
        """`topics`: yield only their messages (None: every message), and skip the chunks
        that hold none (module docstring); `scan` and `parts` then cover the chunks read.
        `read_chunk(offset, length)`, given `topics`: False skips a chunk that holds some of
        them as well, on the same conditions (its messages are counted in `skipped`)."""
        self.scan = SegmentScan(path=path)
        self.parts = IndexParts()
        self._metadata_only = metadata_only
        self._topics = None if topics is None else frozenset(topics)
        self._skip_chunks = topics is not None
        self._read_chunk = read_chunk
        self.reached_data = False
        """A chunk was found (a metadata-only read stops there)."""
        self.chunks_skipped = 0
        """Chunks neither read nor decompressed: their indexes named no channel of `topics`,
        or `read_chunk` declined them."""
        self.skipped: Counter[str] = Counter()
        """Messages of `topics`, by topic, in the chunks `read_chunk` declined."""
        self._chunk_channels: set[int] = set()  # channels with messages in the last chunk
        self._index_open = False  # the last chunk's message indexes may still follow

    def read_through(self) -> SegmentScan:
        """Read every record, every chunk decompressed and its CRC checked, counting the
        messages without handing them out (`seal_segment`, `scan_segment`); returns `scan`."""
        self._topics, self._skip_chunks = frozenset(), False
        for _ in self.messages():
            pass
        return self.scan

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
            header = f.read(RECORD_HEADER.size)
            if len(header) < RECORD_HEADER.size:
                return  # end of file, or a torn record header
            opcode, length = RECORD_HEADER.unpack(header)
            if opcode not in OPCODES or length > scan.size - pos - RECORD_HEADER.size:
                return  # torn record (body past the end of the file) or bytes that are no record
            end = pos + RECORD_HEADER.size + length
            unread = (self._skippable_channels(f, pos, length)  # the file stays where it is
                      if opcode == Opcode.CHUNK and self._skip_chunks and bad_chunk_at is None
                      and not (self._metadata_only or data_ended) else None)
            body = b"" if unread is not None else f.read(length)
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
                    if unread is not None:
                        index = _unread_chunk_index(f, pos, length)
                    else:
                        chunk = Chunk.read(ReadDataStream(io.BytesIO(body)))
                        records = _chunk_records(chunk)
                        index = ChunkIndex(
                            message_start_time=chunk.message_start_time,
                            message_end_time=chunk.message_end_time, chunk_start_offset=pos,
                            chunk_length=end - pos, message_index_offsets={},
                            message_index_length=0, compression=chunk.compression,
                            compressed_size=len(chunk.data),
                            uncompressed_size=chunk.uncompressed_size)
                except UNREADABLE_CHUNK as exc:
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
                    self.parts.chunk_indexes.append(index)
                    self._index_open = True
                    if unread is not None:  # skipped: its indexes name its channels
                        self._chunk_channels = unread
                        self.chunks_skipped += 1
            elif opcode == Opcode.MESSAGE_INDEX:
                self._add_message_index(body, pos, end)
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                records = [_read_record(opcode, body)]
            elif opcode == Opcode.MESSAGE:  # outside a chunk (the hercs writer puts none there)
                records = [(*MESSAGE_HEAD.unpack_from(body), body, MESSAGE_HEAD.size, length)]
            elif opcode == Opcode.METADATA:
                meta = Metadata.read(ReadDataStream(io.BytesIO(body)))
                scan.metadata[meta.name] = dict(meta.metadata)
                self.parts.metadata_indexes.append(
                    MetadataIndex(offset=pos, length=end - pos, name=meta.name))
            pos = end
            if bad_chunk_at is None and not data_ended:
                scan.valid_end = end
            for record in records:
                if isinstance(record, tuple):
                    message = self._message(*record)
                    if message is not None:
                        yield message
                elif isinstance(record, Schema):
                    self.parts.schemas[record.id] = record
                elif isinstance(record, Channel):
                    self.parts.channels[record.id] = record

    def _skippable_channels(self, f: IO[bytes], offset: int, length: int) -> set[int] | None:
        """The channels of the chunk at `offset`, whose `length` bytes the file is at the
        start of, if its message indexes (the records after it, read ahead and then read
        again by the scan) are complete and name only defined channels, of topics not asked
        for or in a chunk `read_chunk` declines; else None (the chunk must be read)."""
        assert self._topics is not None
        start = f.tell()
        size = self.scan.size
        counts: dict[int, int] = {}
        try:
            f.seek(length, os.SEEK_CUR)
            while True:
                header = f.read(RECORD_HEADER.size)
                if len(header) < RECORD_HEADER.size:
                    return None  # the indexes may be cut short: read the chunk
                opcode, length = RECORD_HEADER.unpack(header)
                if opcode != Opcode.MESSAGE_INDEX:
                    break  # another record: the writer wrote every index of the chunk before it
                if length < INDEX_HEAD.size or length > size - f.tell():
                    return None
                channel_id, pairs = INDEX_HEAD.unpack(f.read(INDEX_HEAD.size))
                counts[channel_id] = pairs // INDEX_PAIR_BYTES
                f.seek(length - INDEX_HEAD.size, os.SEEK_CUR)
        finally:
            f.seek(start)
        known = self.parts.channels
        if opcode not in OPCODES or not counts or not all(c in known for c in counts):
            return None
        wanted = {known[c].topic: n for c, n in counts.items() if known[c].topic in self._topics}
        if wanted and (self._read_chunk is None or self._read_chunk(offset, length)):
            return None
        self.skipped.update(wanted)
        return set(counts)

    def _add_message_index(self, body: bytes, pos: int, end: int) -> None:
        """Message indexes follow their chunk; kept only if they cover all its channels."""
        if not self.parts.chunk_indexes or len(body) < 2:
            return
        index = self.parts.chunk_indexes[-1]
        (channel_id,) = struct.unpack_from("<H", body)
        index.message_index_offsets[channel_id] = pos
        index.message_index_length += end - pos

    def _close_chunk_index(self) -> None:
        """A chunk's message indexes are usable only if all were written before a kill;
        checked once, at the first record after them (or the file's end)."""
        if self._index_open:
            index = self.parts.chunk_indexes[-1]
            if set(index.message_index_offsets) != self._chunk_channels:
                index.message_index_offsets, index.message_index_length = {}, 0
        self._index_open = False
        self._chunk_channels = set()

    def _message(self, channel_id: int, sequence: int, log_time: int, publish_time: int,
                 data: bytes, start: int, end: int) -> LoggedMessage | None:
        """Count message `data[start:end]`; it, if its topic is asked for, else None."""
        parts = self.parts
        channel = parts.channels.get(channel_id)
        if channel is None:
            raise EpisodeLogError(f"{self.scan.path}: message on unknown channel "
                                  f"{channel_id}; the file is damaged")
        self.scan.messages = (self.scan.messages or 0) + 1
        self._chunk_channels.add(channel_id)
        counts = parts.channel_message_counts
        counts[channel_id] = counts.get(channel_id, 0) + 1
        if parts.start_time is None or log_time < parts.start_time:
            parts.start_time = log_time
        if log_time > parts.end_time:
            parts.end_time = log_time
        if self._topics is not None and channel.topic not in self._topics:
            return None
        schema = parts.schemas.get(channel.schema_id)
        return LoggedMessage(topic=channel.topic, schema_name=schema.name if schema else "",
                             sequence=sequence, log_time_ns=log_time,
                             publish_time_ns=publish_time, data=data[start:end])


INDEX_HEAD = struct.Struct("<HI")
"""A message index's channel id and the byte length of its (log time, offset) pairs."""
INDEX_PAIR_BYTES = 16
CHUNK_HEAD = struct.Struct("<QQQII")
"""A chunk's message start and end times, uncompressed size and CRC, and the length of the
name of its compression (which follows; then the data's u64 length, then the data)."""


def _unread_chunk_index(f: IO[bytes], offset: int, length: int) -> ChunkIndex:
    """The summary's entry for the chunk at `offset` (the file at its body, `length` bytes,
    left at its end), its data not read. Raises struct.error for a head cut short."""
    start = f.tell()
    try:
        began, ended, uncompressed, _, name_length = CHUNK_HEAD.unpack(f.read(CHUNK_HEAD.size))
        compression = f.read(name_length).decode()
        (compressed,) = struct.unpack("<Q", f.read(8))
    finally:
        f.seek(start + length)
    return ChunkIndex(message_start_time=began, message_end_time=ended,
                      chunk_start_offset=offset, chunk_length=RECORD_HEADER.size + length,
                      message_index_offsets={}, message_index_length=0,
                      compression=compression, compressed_size=compressed,
                      uncompressed_size=uncompressed)


MessageFields = tuple[int, int, int, int, bytes, int, int]
"""A message record's channel id, sequence, log and publish times, and where its data lies:
(buffer, start, end)."""
MESSAGE_HEAD = struct.Struct("<HIQQ")


def _chunk_records(chunk: Chunk) -> list[Schema | Channel | MessageFields]:
    """The records of a chunk (decompressed, its CRC checked), as mcap's `breakup_chunk`
    gives them, but a message as its fields (`MessageFields`), its data not copied. Raises
    one of `UNREADABLE_CHUNK` if the chunk is damaged."""
    stream, size = get_chunk_data_stream(chunk, validate_crc=True)
    data = stream.read(size)
    records: list[Schema | Channel | MessageFields] = []
    pos = 0
    while pos < size:
        opcode, length = RECORD_HEADER.unpack_from(data, pos)
        start = pos + RECORD_HEADER.size
        pos = start + length
        if pos > size:
            raise ValueError(f"a record of {length} bytes runs past the end of its chunk")
        if opcode == Opcode.MESSAGE:
            if length < MESSAGE_HEAD.size:
                raise ValueError(f"a message record of {length} bytes")
            records.append((*MESSAGE_HEAD.unpack_from(data, start), data,
                            start + MESSAGE_HEAD.size, pos))
        elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
            records.append(_read_record(opcode, data[start:pos]))
    return records


def _read_record(opcode: int, body: bytes) -> Schema | Channel:
    stream = ReadDataStream(io.BytesIO(body))
    return Schema.read(stream) if opcode == Opcode.SCHEMA else Channel.read(stream)


def scan_segment(path: str | os.PathLike[str]) -> SegmentScan:
    """Read a whole segment and report whether it is finished and where its valid data ends."""
    return SegmentReader(Path(path)).read_through()


def segment_paths(run_dir: str | os.PathLike[str]) -> list[Path]:
    """The run's segments in order of writing: episodes.000.mcap, …, then episodes.mcap."""
    return RunDir(run_dir).log_segments()


def _paths(path: str | os.PathLike[str]) -> list[Path]:
    path = Path(path)
    return segment_paths(path) if path.is_dir() else [path]


def read_messages(path: str | os.PathLike[str], topics: Iterable[str] | None = None
                  ) -> Iterator[LoggedMessage]:
    """Messages of a segment file, or of every segment of a run directory, in file order.

    Works on a file whose writer was killed: stops at the last complete record."""
    wanted = None if topics is None else frozenset(topics)
    for segment in _paths(path):
        yield from SegmentReader(segment, topics=wanted).messages()


def read_episode_messages(path: str | os.PathLike[str]) -> Iterator[tuple[int, pb.Episode]]:
    """(episode_id, Episode) in the order logged, from a segment or a run directory."""
    for message in read_messages(path, [TOPIC_EPISODES]):
        yield message.sequence, message.decode_as(pb.Episode)


def read_cluster_models(path: str | os.PathLike[str]) -> Iterator[pb.ClusterModel]:
    for message in read_messages(path, [TOPIC_CLUSTER_MODEL]):
        yield message.decode_as(pb.ClusterModel)


def read_eval_results(path: str | os.PathLike[str]) -> Iterator[pb.EvalResult]:
    for message in read_messages(path, [TOPIC_EVAL_RESULT]):
        yield message.decode_as(pb.EvalResult)
