"""The run directory's segments across restarts: sealing a killed writer's file and opening
the log of a run again (`EpisodeLog.open`).

MCAP cannot be appended to after a torn tail or a footer, so each writer gets a fresh file.
The live segment is always `episodes.mcap`; `EpisodeLog.open` seals an unfinished one
(`seal_segment`: torn tail cut, summary rebuilt from the scan, footer, so Rerun and Foxglove
open it without a recovery mode), renames it `episodes.<n>.mcap` (000, 001, … in order) and
opens a new one. Readers read the numbered segments in order, then `episodes.mcap`; ids
continue across them. A bounded log deletes old segments, so its numbers start above 000 and
its ids above 0.
"""

from __future__ import annotations

import logging
import os
import zlib
from collections.abc import Iterator
from pathlib import Path

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import DataEnd, Footer, Statistics
from mcap.writer import MCAP0_MAGIC

from hercs.proto import hercs_pb2 as pb
from hercs.run.rundir import LIVE_NAME, RunDir
from hercs.run.runlog.format import (
    FOOTER_PREFIX,
    FOOTER_RECORD_BYTES,
    METADATA_NAME,
    RECORD_HEADER,
    START_TIME_KEY,
    EpisodeLogError,
    fsync_dir,
)
from hercs.run.runlog.pruning import latest_replay_state
from hercs.run.runlog.reader import (
    IndexParts,
    SegmentReader,
    SegmentScan,
    read_episode_messages,
    scan_segment,
    segment_paths,
)
from hercs.run.runlog.writer import EpisodeLogWriter

log = logging.getLogger(__name__)


def _is_finished(path: Path) -> bool:
    """Cheap check: the file ends in a footer record and the closing magic."""
    size = path.stat().st_size
    tail_len = FOOTER_RECORD_BYTES + len(MCAP0_MAGIC)
    if size < len(MCAP0_MAGIC) + tail_len:
        return False
    with open(path, "rb") as f:
        f.seek(size - tail_len)
        tail = f.read(tail_len)
    opcode, length = RECORD_HEADER.unpack_from(tail)
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
    reader = SegmentReader(path)
    scan = reader.read_through()
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


def _closing_bytes(parts: IndexParts, data_end_offset: int) -> bytes:
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
    summary_crc = zlib.crc32(FOOTER_PREFIX.pack(Opcode.FOOTER, 20, summary_start, 0),
                             zlib.crc32(summary))
    Footer(summary_start=summary_start, summary_offset_start=0,
           summary_crc=summary_crc).write(builder)
    return data_end + summary + builder.end() + MCAP0_MAGIC


def _read_metadata(path: Path) -> tuple[dict[str, str] | None, bool]:
    """The segment's `hercs.episode_log` metadata (None if absent) and whether a chunk was
    reached; stops at the first chunk (the writer puts the metadata before any)."""
    reader = SegmentReader(path, metadata_only=True)
    for _ in reader.messages():
        pass
    return reader.scan.metadata.get(METADATA_NAME), reader.reached_data


def run_start_ns(segments: list[Path]) -> int | None:
    """The run's start time kept by its earliest segment that has one (ns since the Unix
    epoch), for the next segment to continue the same timeline; 0 for a log written before
    the start was kept (its timeline starts at 0), None for a run with no segment yet."""
    for segment in segments:
        meta, _ = _read_metadata(segment)
        if meta is not None and meta.get(START_TIME_KEY, "").isdigit():
            return int(meta[START_TIME_KEY])
    return 0 if segments else None


def _check_metadata(path: Path, *, run: str | None, task: str | None) -> None:
    meta, reached_data = _read_metadata(path)
    if meta is None and not reached_data and path.name == LIVE_NAME:
        return  # killed before its first fsync: the writer syncs metadata before any episode
    if meta is None:
        raise EpisodeLogError(f"{path} has no {METADATA_NAME!r} metadata: it is not a hercs "
                              "episode log; move it out of the run directory")
    if run is not None and (meta.get("run") != run or meta.get("task") != task):
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
        return RunDir(self.run_dir).episode_log

    def segments(self) -> list[Path]:
        return segment_paths(self.run_dir)

    def episodes(self) -> Iterator[tuple[int, pb.Episode]]:
        return read_episode_messages(self.run_dir)

    @classmethod
    def open(cls, run_dir: str | os.PathLike[str], *, run: str, task: str
             ) -> tuple[EpisodeLogWriter, RecoveredLog]:
        """Recover the run's log and start a new live segment.

        Seals and renames a previous `episodes.mcap` (deleted instead if it holds no message),
        checks every segment was written for this run and task, and opens a writer on a new
        `episodes.mcap`. Returns it with a lazy iterator over the recovered (episode_id,
        Episode) pairs of the sealed segments, in order (`RecoveredLog`); those files no
        longer change, so the iterator may be consumed while the writer appends. Consume it
        before assigning new episode ids (they must exceed the last recovered one).
        """
        sealed = cls.retire(run_dir, run=run, task=task)
        writer = EpisodeLogWriter(cls(run_dir).live_path, run=run, task=task,
                                  start_time_ns=run_start_ns(sealed))
        return writer, cls.recovered(sealed)

    @classmethod
    def check(cls, run_dir: str | os.PathLike[str], *, run: str | None = None,
              task: str | None = None) -> list[Path]:
        """The run's segments, in order, once each is known to be a hercs episode log (an
        MCAP file holding hercs's metadata) and, given `run` and `task`, one written for
        them; else `EpisodeLogError` naming the first that is not. Reads each file's head
        only and changes nothing."""
        segments = cls(run_dir).segments()
        for segment in segments:
            _check_metadata(segment, run=run, task=task)
        return segments

    @classmethod
    def retire(cls, run_dir: str | os.PathLike[str], *, run: str, task: str) -> list[Path]:
        """Everything `open` does before it starts the new live segment: check every
        segment's run and task, seal and number the previous live segment, seal numbered
        segments that an earlier full disk left unsealed. Returns the segments, in order.

        Needs no free space to succeed: a segment that cannot be sealed now (a full disk)
        keeps its torn tail, which every reader tolerates, and is sealed by a later call.
        """
        log_dir = cls(run_dir)
        log_dir.run_dir.mkdir(parents=True, exist_ok=True)
        for segment in cls.check(run_dir, run=run, task=task):  # before changing anything
            if segment.name != LIVE_NAME and not _is_finished(segment):
                _seal_if_space(segment)
        live = log_dir.live_path
        if live.exists():
            cls._retire_live(live)
        return log_dir.segments()

    @staticmethod
    def recovered(segments: list[Path]) -> RecoveredLog:
        """The (episode_id, Episode) pairs of `segments`, in order, read lazily, with the
        replay state a restarted replay starts from."""
        return RecoveredLog(segments)

    @staticmethod
    def _retire_live(live: Path) -> None:
        """Seal the previous live segment and give it the next segment number; a segment with
        no message at all (killed before its first append) is deleted instead."""
        scan = _seal_if_space(live)
        if scan.messages == 0:
            live.unlink()
        else:
            os.rename(live, next_segment_path(live.parent))
        fsync_dir(live.parent)


def next_segment_path(run_dir: Path) -> Path:
    """The name the live segment takes when it is sealed: one number above the highest."""
    return RunDir(run_dir).next_segment()


class RecoveredLog(Iterator[tuple[int, pb.Episode]]):
    """The (episode_id, Episode) pairs of a run's sealed segments, in order, read lazily, and
    `replay_state`: the newest `/replay_state` among them, which a restarted replay starts
    from (None: none, it replays every episode from id 0; `hercs.run.runlog.pruning`)."""

    def __init__(self, segments: list[Path]) -> None:
        self.segments = list(segments)
        self.replay_state: pb.ReplayState | None = latest_replay_state(self.segments)
        self._pairs = (pair for segment in self.segments for pair in read_episode_messages(segment))

    def __iter__(self) -> RecoveredLog:
        return self

    def __next__(self) -> tuple[int, pb.Episode]:
        return next(self._pairs)


def _seal_if_space(path: Path) -> SegmentScan:
    """`seal_segment`, or only a scan when the disk has no room for the summary."""
    try:
        return seal_segment(path)
    except OSError as exc:
        log.warning("%s: cannot seal it now (%s); it keeps a torn tail, which readers skip, "
                    "until the log is opened again with free space", path, exc)
        return scan_segment(path)
