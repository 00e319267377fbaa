"""The run log on a disk that fills up, with a real full file system (a small tmpfs): no
append is reported done that is not on disk, appends are refused while the disk is full, the
log continues by itself in a new segment when space returns, and closing or reopening the
log while the disk is full neither crashes nor loses an acked episode. And one failed append
without a full disk: a record whose bytes reached the file but whose fsync failed is cut when
the log is retried (a real MCAP log; only fsync is made to fail, once)."""

from __future__ import annotations

import errno
import os
import subprocess
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from bench.synthetic_episodes import random_episode
from hercs.proto import hercs_pb2 as pb
from hercs.rl.task_registry import task_spec
from hercs.run.rundir import RunDir
from hercs.run.runlog import (
    EpisodeLog,
    EpisodeLogError,
    EpisodeLogWriter,
    RecoveringLogWriter,
    read_episode_messages,
    scan_segment,
    segment_paths,
)
from hercs.wire.codec import episode_to_msg
from tests.support import Clock

RUN, TASK = "disk-test", "push"
RETRY_S = 1.0


def episode(i: int) -> pb.Episode:
    ep = random_episode(task_spec(TASK), np.random.default_rng(i), actor_id="a", seq=i)
    return episode_to_msg(ep, run=RUN, task=TASK)


@pytest.fixture
def disk(tmp_path: Path) -> Iterator[Path]:
    """A 2 MiB file system of its own."""
    if os.geteuid() != 0:
        pytest.skip("needs root to mount a small tmpfs (a real full disk); run as root")
    mount = tmp_path / "disk"
    mount.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mount)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def fill(disk: Path, leave: int = 0) -> Path:
    """Take all free space but `leave` bytes with one ballast file; returns it."""
    ballast = disk / "ballast"
    with open(ballast, "ab") as f:
        try:
            while True:
                stat = os.statvfs(disk)
                free = stat.f_bavail * stat.f_frsize - leave
                if free <= 0:
                    break
                f.write(b"\0" * min(free, 1 << 16))
                f.flush()
        except OSError as exc:
            assert exc.errno == errno.ENOSPC
    return ballast


def append_until_refused(writer: RecoveringLogWriter, acked: list[int]) -> BaseException:
    """Append episodes with the next ids until one fails; ids of those that returned are
    'acked'. Returns the error of the failed append."""
    for _ in range(1000):
        i = len(acked)
        try:
            writer.append_episode(episode(i), episode_id=i)
        except (OSError, EpisodeLogError) as exc:
            return exc
        acked.append(i)
    raise AssertionError("the disk never filled")


def logged_ids(run_dir: Path) -> list[int]:
    return [i for i, _ in read_episode_messages(run_dir)]


def test_full_disk_refuses_then_recovers_by_itself(disk: Path) -> None:
    run_dir, clock = disk / RUN, Clock()
    writer, recovered = RecoveringLogWriter.open(run_dir, run=RUN, task=TASK, retry_s=RETRY_S,
                                                 clock=clock)
    assert list(recovered) == []
    acked: list[int] = []
    for i in range(3):
        writer.append_episode(episode(i), episode_id=i)
        acked.append(i)
    ballast = fill(disk, leave=150_000)
    error = append_until_refused(writer, acked)
    # the episode append hit the full disk, or the scene thread did first (then the refusal
    # carries its error as the cause)
    cause = error if isinstance(error, OSError) else error.__cause__
    assert isinstance(cause, OSError) and cause.errno == errno.ENOSPC, error
    assert len(acked) > 3 and writer.failed

    # While full: refused at once (no retry before retry_s), then retried and refused again.
    with pytest.raises(EpisodeLogError, match="cannot be written since"):
        writer.append_episode(episode(len(acked)), episode_id=len(acked))
    clock.now += RETRY_S
    fill(disk)
    # The retry cuts the failed segment's torn tail (the refused append, and scenes written
    # past the last durable episode): that may free room for a new segment's header and even
    # for a few appends, acked like any other (up to five 7 KB episodes, seen here); then the
    # disk is full again and the next append is refused. Never an acked episode lost.
    before = len(acked)
    error = append_until_refused(writer, acked)
    assert "No space left" in f"{error} {error.__cause__}", error
    assert "cannot be written since" not in str(error), "the retry was due: it was tried"
    assert writer.failed and writer.recoveries in (0, 1)
    recoveries_while_full, acked_while_full = writer.recoveries, len(acked) - before
    assert logged_ids(run_dir) == acked, "the torn segment still reads back every acked one"

    # Space returns: the next append after retry_s continues in a new segment.
    ballast.unlink()
    clock.now += RETRY_S
    for _ in range(3):
        i = len(acked)
        writer.append_episode(episode(i), episode_id=i)
        acked.append(i)
    assert not writer.failed and writer.recoveries == recoveries_while_full + 1
    writer.close()

    assert logged_ids(run_dir) == acked
    got = dict(read_episode_messages(run_dir))
    for i in (0, acked[-1]):
        assert got[i] == episode(i)
    segments = segment_paths(run_dir)
    # a segment started while full keeps its episodes; one that got none is deleted
    assert len(segments) == 2 + (acked_while_full > 0), (segments, acked_while_full)
    assert all(scan_segment(p).finished for p in segments), \
        "with space back, the torn segments were sealed and the live one closed normally"


def test_close_and_restart_while_the_disk_is_full(disk: Path) -> None:
    run_dir, clock = disk / RUN, Clock()
    writer, _ = RecoveringLogWriter.open(run_dir, run=RUN, task=TASK, clock=clock)
    acked = list(range(4))
    for i in acked:
        writer.append_episode(episode(i), episode_id=i)
    ballast = fill(disk)
    writer.close()  # no room for the summary: logged, not raised
    assert not scan_segment(RunDir(run_dir).episode_log).finished

    # A restart on the full disk recovers every acked episode and refuses appends.
    writer, recovered = RecoveringLogWriter.open(run_dir, run=RUN, task=TASK, clock=clock)
    assert [i for i, _ in recovered] == acked
    assert writer.failed
    with pytest.raises(EpisodeLogError):
        writer.append_episode(episode(4), episode_id=4)
    writer.close()

    ballast.unlink()
    clock.now += RETRY_S
    writer, recovered = RecoveringLogWriter.open(run_dir, run=RUN, task=TASK, clock=clock)
    assert [i for i, _ in recovered] == acked
    writer.append_episode(episode(4), episode_id=4)
    writer.close()
    assert logged_ids(run_dir) == [*acked, 4]
    assert all(scan_segment(p).finished for p in segment_paths(run_dir))


def test_plain_writer_close_on_a_full_disk_does_not_raise(disk: Path) -> None:
    path = RunDir(disk).episode_log
    writer = EpisodeLogWriter(path, run=RUN, task=TASK)
    writer.append_episode(episode(0), episode_id=0)
    ballast = fill(disk)
    writer.close()
    ballast.unlink()
    EpisodeLog.retire(disk, run=RUN, task=TASK)
    assert logged_ids(disk) == [0]


def test_a_record_whose_fsync_failed_is_cut_before_the_log_goes_on(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # never acked, so the caller sends the episode again under its id: it must be in the log
    # once, and every acked one must read back
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

    assert logged_ids(run_dir) == [0, 1, 2, 3, 4]
    assert dict(read_episode_messages(run_dir))[3] == episode(3)
    assert len(segment_paths(run_dir)) == 2, "the failed segment sealed, then a new one"
