"""A bounded log: which old segments may be deleted, and the replay state resume starts from.

`segments_to_delete` (pure): a segment may be deleted iff it comes before the newest segment
that starts with a state and every episode it holds has an id below that state's
first_held_id; only the oldest go, so the log stays one contiguous run of ids, which readers
and recovery rely on, even after a crash part way (docs/DESIGN.md §6, "A bounded log"). Ids
increase along the log, so reading each segment's head (up to its first episode) is enough:
no segment is read whole.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from hercs.proto import hercs_pb2 as pb
from hercs.run.runlog.format import TOPIC_EPISODES, TOPIC_REPLAY_STATE, fsync_dir
from hercs.run.runlog.reader import SegmentReader, segment_paths

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SegmentHead:
    """What pruning needs to know of one segment."""

    path: Path
    size: int
    first_episode_id: int | None
    """The lowest id an episode of this segment may have: its state's next_episode_id, else
    its first episode's id; None: no state and no episode."""
    first_held_id: int | None
    """The first_held_id of the state the segment starts with; None: it starts with none."""


def read_head(path: Path) -> tuple[SegmentHead, pb.ReplayState | None]:
    """The segment's head and the state it starts with (None: none), read up to its first
    episode (the whole file only if it holds none)."""
    size = path.stat().st_size
    state: pb.ReplayState | None = None
    first_id: int | None = None
    for index, message in enumerate(SegmentReader(path).messages()):
        if index == 0 and message.topic == TOPIC_REPLAY_STATE:
            state = message.decode_as(pb.ReplayState)
            first_id = int(state.next_episode_id)
            break
        if message.topic == TOPIC_EPISODES:
            first_id = message.sequence
            break
    head = SegmentHead(path=path, size=size, first_episode_id=first_id,
                       first_held_id=None if state is None else int(state.first_held_id))
    return head, state


def latest_replay_state(segments: Sequence[Path]) -> pb.ReplayState | None:
    """The state the newest segment that starts with one starts with (what a restarted
    replay starts from), or None."""
    for path in reversed(segments):
        _, state = read_head(path)
        if state is not None:
            return state
    return None


def segments_to_delete(segments: Sequence[SegmentHead], *, max_bytes: int) -> list[Path]:
    """The oldest segments to delete, in order, so that the log gets under `max_bytes` (-1:
    none) without losing what resume needs (the rule of the module docstring). `segments`
    are the log's, in order, the live one last."""
    if max_bytes < 0:
        return []
    newest_state = max((i for i, s in enumerate(segments) if s.first_held_id is not None),
                       default=None)
    if newest_state is None:
        return []
    keep_from = segments[newest_state].first_held_id
    assert keep_from is not None
    total = sum(s.size for s in segments)
    doomed: list[Path] = []
    for i in range(newest_state):
        if total <= max_bytes:
            break
        after = next(s.first_episode_id for s in segments[i + 1:]
                     if s.first_episode_id is not None)  # the newest state's at the latest
        if after > keep_from:  # this segment may hold an episode the buffer still needs
            break
        doomed.append(segments[i].path)
        total -= segments[i].size
    return doomed


def prune_log(run_dir: str | os.PathLike[str], *, max_bytes: int) -> tuple[list[Path], int]:
    """Delete the segments `segments_to_delete` names, oldest first; returns them and the
    log's size after. Call it only while no writer is closing a numbered segment and nobody
    recovers from the log (the replay calls it after each segment it starts)."""
    heads = [read_head(path)[0] for path in segment_paths(run_dir)]
    doomed = segments_to_delete(heads, max_bytes=max_bytes)
    for path in doomed:
        path.unlink()
    if doomed:
        fsync_dir(Path(run_dir))
        log.info("%s: deleted %d old log segment(s) (%s), every episode in them out of the "
                 "buffer", run_dir, len(doomed), ", ".join(p.name for p in doomed))
    gone = set(doomed)
    return doomed, sum(h.size for h in heads if h.path not in gone)
