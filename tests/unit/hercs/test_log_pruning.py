"""Which segments a bounded episode log may delete (`hercs.run.runlog.pruning`): the pure rule on
segment heads, and its reading of real segments' heads."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.synthetic_episodes import random_episode
from hercs.proto import hercs_pb2 as pb
from hercs.rl.task_registry import task_spec
from hercs.run.rundir import RunDir
from hercs.run.runlog import (
    EpisodeLogWriter,
    SegmentHead,
    latest_replay_state,
    prune_log,
    read_head,
    segment_paths,
    segments_to_delete,
)
from hercs.wire.codec import episode_to_msg

MB = 1_000_000


def seg(name: str, first: int | None, *, held_from: int | None = None,
        size: int = MB) -> SegmentHead:
    """A segment of `size` bytes whose episodes start at `first`; with `held_from`, it starts
    with a replay state at `first` whose buffer held episodes from `held_from` on."""
    return SegmentHead(path=Path(name), size=size, first_episode_id=first,
                       first_held_id=held_from)


# Four segments of 100 episodes, the live one starting with a state at 400 whose buffer (of
# 150 episodes) held 250..399: segments 0 (0..99) and 1 (100..199) hold only evicted episodes,
# segment 2 (200..299) holds 250..299, which resume needs.
LOG = [seg("s0", 0), seg("s1", 100, held_from=0), seg("s2", 200, held_from=50),
       seg("s3", 300, held_from=150), seg("live", 400, held_from=250)]


@pytest.mark.parametrize(("max_bytes", "deleted"), [
    (-1, []),              # unbounded: nothing
    (0, ["s0", "s1"]),     # keep only what resume needs: s2 holds buffered episodes
    (3 * MB, ["s0", "s1"]),
    (4 * MB, ["s0"]),      # under the bound after the oldest one
    (5 * MB, []),          # under the bound already
], ids=["unbounded", "zero", "bound-below-need", "one-over", "under"])
def test_the_oldest_segments_go_while_the_log_is_over_its_bound(max_bytes: int,
                                                                deleted: list[str]) -> None:
    assert [p.name for p in segments_to_delete(LOG, max_bytes=max_bytes)] == deleted


def test_a_segment_whose_last_episode_is_the_first_held_one_stays() -> None:
    # s1 holds 100..249 (the next segment starts at 250): 249 < 250 = first held, so it goes;
    # with the first held at 249 it must stay.
    log = [seg("s0", 0), seg("s1", 100), seg("live", 250, held_from=250)]
    assert [p.name for p in segments_to_delete(log, max_bytes=0)] == ["s0", "s1"]
    log[-1] = seg("live", 250, held_from=249)
    assert [p.name for p in segments_to_delete(log, max_bytes=0)] == ["s0"]


def test_nothing_after_the_newest_state_goes_and_nothing_without_one() -> None:
    """Segments after the newest state (a restart or a full disk started them without one)
    stay, and so does that state's own segment; a log with no state keeps everything (resume
    would replay it from episode 0)."""
    log = [seg("s0", 0), seg("s1", 100, held_from=100), seg("s2", 150), seg("live", 160)]
    assert [p.name for p in segments_to_delete(log, max_bytes=0)] == ["s0"]
    assert segments_to_delete([seg("s0", 0), seg("s1", 100), seg("live", 200)],
                              max_bytes=0) == []


def test_a_segment_with_no_episode_is_bounded_by_the_next_one_that_has_one() -> None:
    """s1 holds only an evaluation result (a replay started and stopped): its place in the id
    order is that of the next segment with an episode."""
    def deleted(held_from: int) -> list[str]:
        log = [seg("s0", 0), seg("s1", None), seg("s2", 100),
               seg("live", 300, held_from=held_from)]
        return [p.name for p in segments_to_delete(log, max_bytes=0)]

    assert deleted(300) == ["s0", "s1", "s2"]
    assert deleted(100) == ["s0", "s1"]  # s2 holds 100..299
    assert deleted(99) == []             # s0 holds 0..99


# -- real segments ---------------------------------------------------------------------------

RUN, TASK = "prune-test", "reach"


def episode(i: int) -> pb.Episode:
    ep = random_episode(task_spec(TASK), np.random.default_rng(i), actor_id="a", seq=i)
    return episode_to_msg(ep, run=RUN, task=TASK)


def state(next_id: int, held_from: int) -> pb.ReplayState:
    return pb.ReplayState(next_episode_id=next_id, first_held_id=held_from)


def write_segment(path: Path, ids: range, *, starts_with: pb.ReplayState | None = None) -> None:
    with EpisodeLogWriter(path, run=RUN, task=TASK, start_time_ns=0, scene=False) as writer:
        if starts_with is not None:
            writer.append_replay_state(starts_with)
        for i in ids:
            writer.append_episode(episode(i), episode_id=i)


def test_heads_are_read_from_real_segments_and_pruning_deletes_the_files(
        tmp_path: Path) -> None:
    write_segment(tmp_path / "episodes.000.mcap", range(0, 4))
    write_segment(tmp_path / "episodes.001.mcap", range(4, 8), starts_with=state(4, 0))
    write_segment(RunDir(tmp_path).episode_log, range(8, 10), starts_with=state(8, 6))
    heads = [read_head(p)[0] for p in segment_paths(tmp_path)]
    assert [(h.first_episode_id, h.first_held_id) for h in heads] == [(0, None), (4, 0),
                                                                      (8, 6)]
    latest = latest_replay_state(segment_paths(tmp_path))
    assert latest is not None and latest.next_episode_id == 8 and latest.first_held_id == 6
    deleted, size = prune_log(tmp_path, max_bytes=0)
    assert [p.name for p in deleted] == ["episodes.000.mcap"]  # 001 holds 6 and 7
    assert [p.name for p in segment_paths(tmp_path)] == ["episodes.001.mcap", "episodes.mcap"]
    assert size == sum(p.stat().st_size for p in segment_paths(tmp_path))


def test_a_state_must_come_before_the_episodes_it_counts(tmp_path: Path) -> None:
    with EpisodeLogWriter(RunDir(tmp_path).episode_log, run=RUN, task=TASK, scene=False) as w:
        w.append_episode(episode(0), episode_id=0)
        with pytest.raises(ValueError, match="next_episode_id=0: episode 0 is logged here"):
            w.append_replay_state(state(0, 0))
        w.append_replay_state(state(1, 0))
        with pytest.raises(ValueError, match="episode_id=0: ids must increase"):
            w.append_episode(episode(0), episode_id=0)
