"""An append whose bytes reached the file but whose fsync failed was never acknowledged: when
the log is retried it cuts that record, so the episode the caller sends again under the same
id is in the log once, and every acknowledged one reads back (a real MCAP log on disk; only
fsync is made to fail, once)."""

from __future__ import annotations

import errno
from pathlib import Path

import numpy as np
import pytest

from hercs.proto import hercs_pb2 as pb
from hercs.rl.task_registry import task_spec
from hercs.run.runlog import EpisodeLogError, RecoveringLogWriter, read_episodes, segment_paths
from hercs.run.runlog.writer import EpisodeLogWriter
from hercs.wire.codec import episode_to_msg
from hercs.wire.episode import random_episode
from tests.support import Clock

RUN, TASK = "fsync-test", "push"
RETRY_S = 1.0


def episode(i: int) -> pb.Episode:
    ep = random_episode(task_spec(TASK), np.random.default_rng(i), actor_id="a", seq=i)
    return episode_to_msg(ep, run=RUN, task=TASK)


def test_a_record_whose_fsync_failed_is_cut_before_the_log_goes_on(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    run_dir, clock = tmp_path / RUN, Clock()
    writer, _ = RecoveringLogWriter.open(run_dir, run=RUN, task=TASK, retry_s=RETRY_S,
                                         clock=clock, scene=False)
    for i in range(3):
        writer.append_episode(episode(i), episode_id=i)

    real_sync = EpisodeLogWriter._sync
    fail_next = [True]

    def sync_failing_once(self: EpisodeLogWriter) -> None:
        if fail_next and fail_next.pop():
            self._mcap.flush()  # the record's bytes are in the file, complete...
            raise OSError(errno.EIO, "fsync failed")  # ...but never made durable nor acked
        real_sync(self)

    monkeypatch.setattr(EpisodeLogWriter, "_sync", sync_failing_once)
    with pytest.raises((OSError, EpisodeLogError)):
        writer.append_episode(episode(3), episode_id=3)
    assert writer.failed

    clock.now += RETRY_S  # the retry is due: the caller sends episode 3 again
    writer.append_episode(episode(3), episode_id=3)
    writer.append_episode(episode(4), episode_id=4)
    writer.close()

    assert [i for i, _ in read_episodes(run_dir)] == [0, 1, 2, 3, 4]
    assert dict(read_episodes(run_dir))[3] == episode(3)
    assert len(segment_paths(run_dir)) == 2, "the failed segment sealed, then a new one"
