"""Reading a run's episode log before a resume, in bounded time and changing nothing:
`survey_log` checks each episode it reads against the task, finds torn tails and says how many
episodes a tail cut and which it left unread.

Budget: a first read of each segment's records finds its episode chunks (the message indexes
after each chunk name its channels; only chunks defining a channel are decompressed). Then
the first and the last `END_BYTES` of them in every segment are read whatever the budget,
and the others, newest first (the episodes the buffer holds and samples), while
`BUDGET_BYTES` of them last. A chunk left unread is neither decompressed, CRC-checked nor
checked against the task; its indexes count its episodes.
"""

from __future__ import annotations

import dataclasses
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mcap.opcode import Opcode

from hercs.proto import hercs_pb2 as pb
from hercs.rl.task_spec import TaskSpec
from hercs.run.runlog.format import (
    METADATA_NAME,
    RECORD_HEADER,
    START_TIME_KEY,
    TOPIC_EPISODES,
    EpisodeLogError,
)
from hercs.run.runlog.reader import SegmentReader, SegmentScan
from hercs.run.runlog.scene import episode_span_ns
from hercs.wire.episode import expected_shapes

MiB = 2**20
END_BYTES = 256 * 2**10
"""Episode chunks read at each end of every segment whatever the budget: some 60 FetchReach
episodes."""
BUDGET_BYTES = 32 * MiB
"""Episode chunks read past the segments' ends: about 10,000 FetchReach episodes (3.3 KiB
each), some 1.4 s of one core (measured: 8,000 episodes, 25 MiB, in 1.06 s of CPU time,
0.15 s of it the first read)."""

MAX_SEQ = 2**63 - 1
"""The store keeps an episode's seq in an int64."""
CHUNK_TIMES = struct.Struct("<QQ")
"""The first fields of a chunk record's body: the log times of its first and last message."""


class BadEpisode(EpisodeLogError):
    """A logged episode the replay cannot store as the task's, or would store poisoned; the
    message names the segment, the episode and what is wrong with it."""


@dataclass(frozen=True)
class Unread:
    """Episodes of one segment the survey left unread (past its budget)."""

    segment: Path
    episodes: int
    after: int | None
    """The id of the episode read just before them (None: none)."""
    before: int | None
    """The id of the episode read just after them (None: none)."""

    def ids(self) -> str:
        low = "" if self.after is None else f"{self.after + 1:,}"
        high = "" if self.before is None else f"{self.before - 1:,}"
        return f"ids {low}-{high} of {self.segment.name}" if low or high else self.segment.name


@dataclass(frozen=True)
class TornTail:
    """A segment that ends in a record cut short (or a chunk that fails its CRC), which the
    replay cuts off when it reopens the log (`seal_segment`)."""

    segment: Path
    offset: int
    """Where its intact records end."""
    cut_bytes: int
    cut_short: bool
    """The first record past `offset` runs past the file's end (else it is a whole chunk that
    fails its CRC or does not decompress)."""
    cut_episodes: int | None
    """Episodes in the cut record (None: its head is cut too, or is no record)."""
    last_whole: int | None
    """The newest episode id before it (None: none)."""

    def describe(self) -> str:
        whole = ("no whole episode comes before it" if self.last_whole is None
                 else f"every episode up to id {self.last_whole:,} is whole")
        if self.cut_episodes is None:
            held = "how many episodes the cut record held cannot be read from it"
        elif self.cut_episodes == 0:
            held = "the cut record held no episode"
        else:
            first = 0 if self.last_whole is None else self.last_whole + 1
            held = (f"the cut record held {self.cut_episodes:,} episode"
                    f"{'s' if self.cut_episodes != 1 else ''} (ids {first:,}-"
                    f"{first + self.cut_episodes - 1:,}), which the run no longer has")
        what = "a record cut short" if self.cut_short else "a chunk that fails its check"
        return (f"{self.segment} ends in a torn tail ({self.cut_bytes:,} bytes after offset "
                f"{self.offset:,}, {what}): the replay cuts them off as it reopens the log; "
                f"{held}, and {whole}")


@dataclass
class LogSurvey:
    """What `survey_log` read: the episodes it checked, those it left unread, torn tails."""

    checked: int = 0
    unread: list[Unread] = dataclasses.field(default_factory=list)
    torn: list[TornTail] = dataclasses.field(default_factory=list)
    budget_bytes: int = BUDGET_BYTES
    end_bytes: int = END_BYTES

    def notes(self) -> list[str]:
        """What a user resuming the run is told: each torn tail, and what was left unread."""
        notes = [tail.describe() for tail in self.torn]
        if self.unread:
            left = sum(u.episodes for u in self.unread)
            notes.append(
                f"the episode log was checked in part: {self.checked:,} episodes read and "
                f"checked, {left:,} left unread ({', '.join(u.ids() for u in self.unread)}), "
                f"past the pre-check's budget of {_size(self.budget_bytes)} beyond the first "
                f"and last {_size(self.end_bytes)} of each segment; the replay stores them "
                "unchecked")
        return notes


def survey_log(segments: Sequence[Path], *, spec: TaskSpec, budget_bytes: int = BUDGET_BYTES,
               end_bytes: int = END_BYTES) -> LogSurvey:
    """Read `segments` (a run's, in order) as the module docstring says; raises `BadEpisode`
    for the first episode read that `episode_problem` finds wrong, `EpisodeLogError` for a
    segment that is no MCAP file or is damaged in the middle."""
    survey = LogSurvey(budget_bytes=budget_bytes, end_bytes=end_bytes)
    chunks = {path: _episode_chunks(path) for path in segments}
    chosen = {path: _ends(found, end_bytes) for path, found in chunks.items()}
    left = budget_bytes
    for path in reversed(segments):  # the newest episodes first
        for offset, length in reversed(chunks[path]):
            if offset not in chosen[path]:
                if length > left:
                    break
                chosen[path].add(offset)
                left -= length
    last_whole: int | None = None
    for path in segments:
        newest, scan = _read_segment(path, spec, chosen[path], survey)
        last_whole = newest if newest is not None else last_whole
        if not scan.finished and scan.dropped_bytes:
            survey.torn.append(_torn_tail(scan, last_whole, spec.episode_steps))
    return survey


def _episode_chunks(path: Path) -> list[tuple[int, int]]:
    """(offset, length) of the segment's chunks whose message indexes name the episodes'
    channel, in order, from a read of its records that decompresses only the chunks that
    define a channel (or whose indexes are cut short)."""
    reader = SegmentReader(path, topics=())
    for _ in reader.messages():
        pass
    ids = {c.id for c in reader.parts.channels.values() if c.topic == TOPIC_EPISODES}
    return [(c.chunk_start_offset, c.chunk_length) for c in reader.parts.chunk_indexes
            if ids & set(c.message_index_offsets)]


def _ends(chunks: list[tuple[int, int]], end_bytes: int) -> set[int]:
    """The offsets of the first and the last chunks of `chunks` up to `end_bytes` each (one
    at least at each end)."""
    chosen: set[int] = set()
    for ordered in (chunks, chunks[::-1]):
        taken = 0
        for offset, length in ordered:
            if taken and taken + length > end_bytes:
                break
            chosen.add(offset)
            taken += length
    return chosen


def _read_segment(path: Path, spec: TaskSpec, chosen: set[int], survey: LogSurvey
                  ) -> tuple[int | None, SegmentScan]:
    """Check the episodes of the segment's `chosen` chunks (and of those a read cannot skip);
    the id of the newest episode read, and the scan."""
    reader = SegmentReader(path, topics=[TOPIC_EPISODES],
                           read_chunk=lambda offset, _: offset in chosen)
    last: int | None = None
    skipped = 0
    for message in reader.messages():
        if reader.skipped[TOPIC_EPISODES] > skipped:
            survey.unread.append(Unread(path, reader.skipped[TOPIC_EPISODES] - skipped,
                                        after=last, before=message.sequence))
            skipped = reader.skipped[TOPIC_EPISODES]
        problem = episode_problem(message.decode_as(pb.Episode), spec, message.sequence)
        if problem is not None:
            raise BadEpisode(f"{path}: {problem}")
        last = message.sequence
        survey.checked += 1
    if reader.skipped[TOPIC_EPISODES] > skipped:
        survey.unread.append(Unread(path, reader.skipped[TOPIC_EPISODES] - skipped,
                                    after=last, before=None))
    return last, reader.scan


def episode_problem(msg: pb.Episode, spec: TaskSpec, episode_id: int) -> str | None:
    """What keeps the replay from storing logged episode `msg` as one of `spec`'s task, or
    makes it poison what it stores, in words (None: nothing): it is of the task, each array
    float32 of the task's shape, every value finite."""
    def consequence(poisoned: bool) -> str:
        return ("; the replay would store it and every batch drawn from it would carry that "
                "value to the learner" if poisoned else
                "; the replay cannot store it as one of the task's and would stop the run")

    if msg.task != spec.name:
        return f"episode {episode_id} is of task {msg.task!r}, not {spec.name!r}" + \
            consequence(False)
    if msg.seq > MAX_SEQ:
        return f"episode {episode_id}'s seq {msg.seq} is above 2**63 - 1" + consequence(False)
    for field, shape in expected_shapes(spec).items():
        array = getattr(msg, field)
        got = tuple(int(d) for d in array.shape)
        what = f"episode {episode_id}'s {field}"
        if got != shape:
            return (f"{what} have shape {got}, the task's are {shape} (task {spec.name}: "
                    f"obs_dim {spec.obs_dim}, goal_dim {spec.goal_dim}, action_dim "
                    f"{spec.action_dim}, episode_steps {spec.episode_steps})"
                    + consequence(False))
        if array.dtype != "float32" or len(array.data) != 4 * math.prod(shape):
            return (f"{what} are {len(array.data)} bytes of {array.dtype or 'no dtype'}, not "
                    f"the {4 * math.prod(shape)} of float32 their shape {shape} takes"
                    + consequence(False))
        values = np.frombuffer(array.data, dtype="<f4")
        finite = np.isfinite(values)
        if not finite.all():
            flat = int(np.argmin(finite))
            step, index = divmod(flat, shape[1])
            return (f"{what} hold {values[flat]} at step {step}, index {index}: not a finite "
                    "number" + consequence(True))
    return None


def _size(n: int) -> str:
    return f"{n / MiB:g} MiB" if n >= MiB else f"{n:,} bytes"


def _torn_tail(scan: SegmentScan, last_whole: int | None, episode_steps: int) -> TornTail:
    """The torn tail of `scan`'s segment, with the episodes its cut record held: those after
    `last_whole` up to the one its last message's log time falls in (episode k's messages
    lie in [S + k·span, S + (k+1)·span), `hercs.run.runlog.format`)."""
    with open(scan.path, "rb") as f:
        f.seek(scan.valid_end)
        head = f.read(RECORD_HEADER.size + CHUNK_TIMES.size)
    cut: int | None = None
    short = True
    if len(head) >= RECORD_HEADER.size:
        opcode, length = RECORD_HEADER.unpack_from(head)
        short = RECORD_HEADER.size + length > scan.size - scan.valid_end
        if opcode == Opcode.MESSAGE_INDEX:
            cut = 0  # the indexes of a whole chunk
        elif opcode == Opcode.CHUNK and len(head) == RECORD_HEADER.size + CHUNK_TIMES.size:
            began, ended = CHUNK_TIMES.unpack_from(head, RECORD_HEADER.size)
            kept = scan.metadata.get(METADATA_NAME, {}).get(START_TIME_KEY, "")
            start = int(kept) if kept.isdigit() else 0
            if start <= began <= ended:
                newest = (ended - start) // episode_span_ns(episode_steps)
                cut = max(0, newest - (-1 if last_whole is None else last_whole))
    return TornTail(segment=scan.path, offset=scan.valid_end, cut_bytes=scan.dropped_bytes,
                    cut_short=short, cut_episodes=cut, last_whole=last_whole)

