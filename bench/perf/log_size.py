"""What a run's episode log takes on disk, and a longer run's with each `replay.log_max_bytes`.

    python -m bench.perf.log_size runs/push-v1-her-s1 [--epochs 200] [--bounds=-1,0,250e6]

Splits a run's log by what it holds and plays a longer run through the bounded log's rules
(used for the Disk table of docs/GUIDE.md)."""

from __future__ import annotations

import argparse
import io
import math
import sys
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Schema
from mcap.records import Message as McapMessage
from mcap.stream_reader import breakup_chunk
from mcap.writer import MCAP0_MAGIC

from hercs.config import HercsConfig, load_yaml
from hercs.run.rundir import RunDir
from hercs.run.runlog import (
    TOPIC_EPISODES,
    TOPIC_REPLAY_STATE,
    TOPIC_SCENE,
    TOPIC_SCENE_POINTS,
    SegmentHead,
    segment_paths,
    segments_to_delete,
)
from hercs.run.runlog.format import RECORD_HEADER

SCENE_TOPICS = (TOPIC_SCENE, TOPIC_SCENE_POINTS)
SCHEMAS = "(schemas)"
"""What a chunk's schema records are counted as: bytes once per segment."""
MB = 1e6
STATE_BYTES = 4_000.0
"""A replay state's bytes when the log holds none to measure (an object task's: 150 failed
goals, two normalisers, a cluster model; about 3 kB serialised)."""


@dataclass
class LogBytes:
    """A log's bytes on disk by what they hold."""

    by_topic: Counter[str]
    fixed: float
    """Bytes once per segment: magic, header, metadata, schemas and channels (in chunks and
    again in the summary)."""
    summary: float
    """Bytes from DataEnd on: the summary (an index entry per chunk, so it grows with the
    episodes) and the footer."""
    segments: int
    messages: Counter[str]
    """Messages per topic."""

    @property
    def episodes(self) -> int:
        return self.messages[TOPIC_EPISODES]

    @property
    def other_records(self) -> int:
        """Messages other than episodes and scenes."""
        return sum(n for t, n in self.messages.items()
                   if t != TOPIC_EPISODES and t not in SCENE_TOPICS)

    @property
    def total(self) -> float:
        return sum(self.by_topic.values()) + self.fixed + self.summary

    def per_episode(self, *topics: str) -> float:
        return sum(self.by_topic[t] for t in topics) / max(self.episodes, 1)

    @property
    def other(self) -> float:
        return sum(n for t, n in self.by_topic.items()
                   if t != TOPIC_EPISODES and t not in SCENE_TOPICS)


def measure(run_dir: Path) -> LogBytes:
    out = LogBytes(by_topic=Counter(), fixed=0.0, summary=0.0, segments=0,
                   messages=Counter())
    for path in segment_paths(run_dir):
        out.segments += 1
        _measure_segment(path, out)
    return out


def _measure_segment(path: Path, out: LogBytes) -> None:
    topics: dict[int, str] = {}
    shares: dict[str, float] = {}  # the last chunk's topics, for its message indexes
    data = path.read_bytes()
    pos = len(MCAP0_MAGIC)
    out.fixed += pos
    in_summary = False
    while pos + RECORD_HEADER.size <= len(data):
        opcode, length = RECORD_HEADER.unpack_from(data, pos)
        end = pos + RECORD_HEADER.size + length
        if end > len(data):
            break  # a torn tail (a live segment): not on disk for long
        body = data[pos + RECORD_HEADER.size:end]
        size = end - pos
        if opcode == Opcode.CHUNK:
            shares = _chunk_shares(body, topics, out)
            for topic, share in shares.items():
                _add(out, topic, size * share)
        elif opcode == Opcode.MESSAGE_INDEX and shares:
            for topic, share in shares.items():
                _add(out, topic, size * share)
        elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.HEADER, Opcode.METADATA):
            if opcode == Opcode.CHANNEL:
                channel = Channel.read(ReadDataStream(io.BytesIO(body)))
                topics[channel.id] = channel.topic
            out.fixed += size  # once per segment (the summary repeats schemas and channels)
        else:
            in_summary = in_summary or opcode == Opcode.DATA_END
            if in_summary:  # chunk indexes, statistics, footer: they grow with the chunks
                out.summary += size
            else:
                out.fixed += size
        pos = end
    out.summary += len(data) - pos  # the closing magic


def _chunk_shares(body: bytes, topics: dict[int, str], out: LogBytes) -> dict[str, float]:
    """Each topic's share of a chunk's uncompressed bytes (schemas and channels as SCHEMAS)."""
    payload: Counter[str] = Counter()
    for record in breakup_chunk(Chunk.read(ReadDataStream(io.BytesIO(body))),
                                validate_crc=False):
        if isinstance(record, Schema):
            payload[SCHEMAS] += len(record.data)
        elif isinstance(record, Channel):
            topics[record.id] = record.topic
        elif isinstance(record, McapMessage):
            topic = topics[record.channel_id]
            payload[topic] += len(record.data)
            out.messages[topic] += 1
    total = sum(payload.values()) or 1
    return {topic: n / total for topic, n in payload.items()}


def _add(out: LogBytes, topic: str, size: float) -> None:
    if topic == SCHEMAS:
        out.fixed += size
    else:
        out.by_topic[topic] += size


@dataclass(frozen=True)
class Projection:
    end_bytes: float
    peak_bytes: float
    segments_at_end: int


def project(*, episodes: int, capacity: int, segments_per_buffer: int, max_bytes: int,
            episode_bytes: float, segment_bytes: float, state_bytes: float) -> Projection:
    """The log of a run of `episodes` episodes under the replay's rules (module docstring):
    `episode_bytes` per episode (its share of every record), `segment_bytes` per file."""
    if max_bytes < 0:  # one segment, never split
        size = episodes * episode_bytes + segment_bytes
        return Projection(size, size, 1)
    per_segment = math.ceil(capacity / segments_per_buffer)
    closed: list[SegmentHead] = []
    first, held_from = 0, None  # the live segment's first id and its state's first held id

    def live_bytes(end: int) -> float:
        return ((end - first) * episode_bytes + segment_bytes
                + (state_bytes if held_from is not None else 0))

    peak = 0.0
    while first + per_segment <= episodes:  # the live segment fills: the next one starts
        full = live_bytes(first + per_segment)
        peak = max(peak, sum(s.size for s in closed) + full)
        closed.append(SegmentHead(path=Path(f"episodes.{first}.mcap"), size=round(full),
                                  first_episode_id=first, first_held_id=held_from))
        first += per_segment
        held_from = max(0, first - capacity)
        live = SegmentHead(path=Path("live"), size=round(live_bytes(first)),
                           first_episode_id=first, first_held_id=held_from)
        gone = set(segments_to_delete([*closed, live], max_bytes=max_bytes))
        closed = [s for s in closed if s.path not in gone]
    end = sum(s.size for s in closed) + live_bytes(episodes)
    return Projection(end, max(peak, end), len(closed) + 1)


def parse_bounds(text: str) -> list[int]:
    try:
        bounds = [int(float(item)) for item in text.split(",") if item]
    except ValueError:
        raise ValueError(f"--bounds: got {text!r}, must be numbers like -1,0,250e6") from None
    if not bounds or min(bounds) < -1:
        raise ValueError(f"--bounds: got {text!r}, each must be -1, 0 or a size in bytes")
    return bounds


def report(run_dir: Path, config: HercsConfig, measured: LogBytes, *, epochs: int,
           bounds: Sequence[int]) -> str:
    n = measured.episodes
    ep, scene = measured.per_episode(TOPIC_EPISODES), measured.per_episode(*SCENE_TOPICS)
    other = (measured.other + measured.summary) / max(n, 1)
    fixed = measured.fixed / measured.segments
    states = measured.messages[TOPIC_REPLAY_STATE]
    state = measured.by_topic[TOPIC_REPLAY_STATE] / states if states else STATE_BYTES
    per_epoch = config.training.episodes_per_epoch
    capacity = config.capacity_episodes
    k = config.replay.log_segments_per_buffer
    total_episodes = epochs * per_epoch
    digits = 0 if total_episodes * (ep + scene) > 100 * MB else 2
    lines = [
        f"Measured `{run_dir.name}`: {n:,} episodes in {measured.segments} segment(s), "
        f"{measured.total / MB:.1f} MB on disk: per episode {ep:,.0f} B episode + "
        f"{scene:,.0f} B scene + {other:,.0f} B other records ({measured.other_records} "
        "models/results/states) and index (the summary) = "
        f"{ep + scene + other:,.0f} B; {fixed:,.0f} B per segment (header, schemas).", "",
        f"A {epochs}-epoch run of it: {total_episodes:,} episodes ({per_epoch} an epoch), "
        f"buffer {capacity:,} episodes, a segment every {math.ceil(capacity / k):,}:", "",
        "| replay.log_max_bytes | with scenes: end / largest | without scenes: end / "
        "largest |", "|---|---|---|"]
    for bound in bounds:
        cells = []
        for per_episode in (ep + scene + other, ep + other):
            p = project(episodes=total_episodes, capacity=capacity, segments_per_buffer=k,
                        max_bytes=bound, episode_bytes=per_episode, segment_bytes=fixed,
                        state_bytes=state)
            cells.append(f"{p.end_bytes / MB:,.{digits}f} / {p.peak_bytes / MB:,.{digits}f} MB")
        name = {-1: "-1 (keep all)", 0: "0 (default)"}.get(bound, f"{bound:,}")
        lines.append(f"| {name} | {cells[0]} | {cells[1]} |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run_dir", type=Path, help="a run directory (config.yaml + its log)")
    p.add_argument("--epochs", type=int, default=200, help="the run length to project to")
    p.add_argument("--bounds", default="-1,0,300e6",
                   help="replay.log_max_bytes values, comma-separated")
    args = p.parse_args(argv)
    try:
        bounds = parse_bounds(args.bounds)
    except ValueError as exc:
        print(f"log_size: {exc}", file=sys.stderr)
        return 2
    if args.epochs < 1 or not RunDir(args.run_dir).config.is_file() or not segment_paths(
            args.run_dir):
        print(f"log_size: {args.run_dir} must be a run directory with config.yaml and an "
              "episode log, and --epochs >= 1", file=sys.stderr)
        return 2
    config = load_yaml(RunDir(args.run_dir).config)
    print(report(args.run_dir, config, measure(args.run_dir), epochs=args.epochs,
                 bounds=bounds), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
