"""Many MCAP messages into a writer's open chunk at once: the scene's 102 per episode.

`Writer.add_message` builds a record object and packs its header fields one by one, per
message: ~0.4 ms of the replay's CPU for a FetchPush episode's scene, as much as drawing it.
`add_message_rows` writes the same bytes (a test compares whole files) with headers packed by
numpy and records joined once. It reaches into mcap 1.6's private chunk builder; where a later
mcap moved it, it falls back to `add_message` (`has_bulk_internals`). `reuse_zstd_contexts`
gives the writer one zstd compressor per thread instead of a new one per chunk (~0.15 ms each).
"""

from __future__ import annotations

import itertools
import struct
import threading
from collections.abc import Sequence

import mcap.writer
import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import MessageIndex, Statistics
from mcap.writer import Writer as McapWriter

_HEADER = np.dtype([("opcode", "u1"), ("length", "<u8"), ("channel", "<u2"),
                    ("sequence", "<u4"), ("log_time", "<u8"), ("publish_time", "<u8")])
"""A Message record's opcode, record length and fields before the data (packed: 31 bytes)."""
_AFTER_LENGTH = _HEADER.itemsize - 9  # the record length counts what follows opcode and length


class _PackedIndex(MessageIndex):
    """A chunk's message index for one channel, its entries packed in one call."""

    def write(self, stream: RecordBuilder) -> None:
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write2(self.channel_id)
        stream.write4(len(self.records) * 16)
        stream.write(struct.pack(f"<{2 * len(self.records)}Q",
                                 *itertools.chain.from_iterable(self.records)))
        stream.finish_record()


class _ZstdPerThread:
    """Stands in for the `zstandard` module in `mcap.writer`, whose chunks are compressed with
    `zstandard.compress(data)`: that builds a new compressor (and its context) per call; this
    keeps one per thread. Same bytes (`compress` is `ZstdCompressor(level).compress`)."""

    def __init__(self) -> None:
        self._local = threading.local()

    def compress(self, data: bytes, level: int = 3) -> bytes:
        compressors = self._local.__dict__.setdefault("by_level", {})
        compressor = compressors.get(level)
        if compressor is None:
            compressor = compressors[level] = zstandard.ZstdCompressor(level=level)
        return compressor.compress(data)

    def __getattr__(self, name: str) -> object:
        return getattr(zstandard, name)


def reuse_zstd_contexts() -> None:
    """Make every `mcap.writer.Writer` of this process reuse its thread's zstd compressor."""
    if getattr(mcap.writer, "zstandard", None) is zstandard:
        mcap.writer.zstandard = _ZstdPerThread()  # type: ignore[assignment]


def has_bulk_internals(writer: McapWriter) -> bool:
    """Whether this mcap's Writer has the internals `add_message_rows` writes into (mcap 1.6's
    chunk builder and statistics); without them it writes message by message instead."""
    builder = getattr(writer, "_Writer__chunk_builder", None)
    statistics = getattr(writer, "_Writer__statistics", None)
    return (isinstance(statistics, Statistics)
            and isinstance(getattr(builder, "message_indices", None), dict)
            and isinstance(getattr(builder, "record_writer", None), RecordBuilder)
            and hasattr(builder, "num_messages"))


def add_message_rows(writer: McapWriter, channel_ids: Sequence[int], times_ns: Sequence[int],
                     sequence: int, columns: Sequence[Sequence[bytes]]) -> None:
    """As `writer.add_message(channel_ids[c], times_ns[i], columns[c][i], times_ns[i],
    sequence)` for each step i and, within it, each channel c in order (log and publish time
    equal), into the open chunk; the caller closes it (`flush`) before it nears the writer's
    chunk size, which is not checked here."""
    n, width = len(times_ns), len(channel_ids)
    if not n:
        return
    data = [message for row in zip(*columns, strict=True) for message in row]
    if len(data) != n * width:
        raise ValueError(f"{len(data)} messages for {n} steps of {width} channels")
    if not has_bulk_internals(writer):  # another mcap: its own, slower, public path
        for i, time_ns in enumerate(times_ns):
            for channel, message in zip(channel_ids, data[i * width:(i + 1) * width],
                                        strict=True):
                writer.add_message(channel, time_ns, message, time_ns, sequence)
        return
    builder = writer._Writer__chunk_builder  # type: ignore[attr-defined]
    statistics: Statistics = writer._Writer__statistics  # type: ignore[attr-defined]
    times = np.asarray(times_ns, dtype=np.uint64)
    lengths = np.fromiter(map(len, data), dtype=np.uint64, count=len(data))
    headers = np.empty(len(data), dtype=_HEADER)
    headers["opcode"] = Opcode.MESSAGE
    headers["length"] = lengths + _AFTER_LENGTH
    headers["channel"] = np.tile(np.asarray(channel_ids, dtype=np.uint16), n)
    headers["sequence"] = sequence
    headers["log_time"] = headers["publish_time"] = np.repeat(times, width)
    packed, size = headers.tobytes(), _HEADER.itemsize
    starts = builder.count + np.concatenate(
        [[0], np.cumsum(lengths + size)[:-1]]).astype(np.int64).reshape(n, width)
    builder.record_writer.write(b"".join(itertools.chain.from_iterable(zip(
        (packed[i:i + size] for i in range(0, len(packed), size)), data, strict=True))))
    time_list = times.tolist()
    for c, channel in enumerate(channel_ids):
        index = builder.message_indices.get(channel)
        if not isinstance(index, _PackedIndex):
            index = builder.message_indices[channel] = _PackedIndex(
                channel_id=channel, records=[] if index is None else index.records)
        index.records.extend(zip(time_list, starts[:, c].tolist(), strict=True))
        statistics.channel_message_counts[channel] += n
    first, last = min(time_list), max(time_list)
    builder.message_start_time = (first if builder.num_messages == 0
                                  else min(first, builder.message_start_time))
    builder.message_end_time = max(last, builder.message_end_time)
    builder.num_messages += len(data)
    statistics.message_start_time = (first if statistics.message_count == 0
                                     else min(first, statistics.message_start_time))
    statistics.message_end_time = max(last, statistics.message_end_time)
    statistics.message_count += len(data)
