"""A run directory has one owner at a time (hercs.apps.launch.run_lock): a second `hercs up` on a
folder another live process holds is refused at once, naming it; an owner that was killed
leaves nothing stuck. The holder is a real second process."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from hercs.apps.cli.main import main
from hercs.apps.launch.run_lock import RunBusy, RunLock, read_owner
from hercs.run.rundir import RunDir
from tests.run_dirs import make_run

REPO = Path(__file__).resolve().parents[3]
HOLDER = """
import sys, time
from pathlib import Path
from hercs.apps.launch.run_lock import RunLock
lock = RunLock.take(Path(sys.argv[1]))
print("held", flush=True)
time.sleep(600)
"""


@contextmanager
def holder(run_dir: Path) -> Iterator[subprocess.Popen[str]]:
    """A second process that takes the lock and holds it until killed."""
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(run_dir), "up", "--resume",
                             str(run_dir)], cwd=REPO, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline() == "held\n"
        yield proc
    finally:
        proc.kill()
        proc.wait()


def test_a_second_owner_is_refused_naming_the_first(tmp_path: Path, capsys) -> None:
    run = tmp_path / "runs" / "busy"
    make_run(run, epochs=3, trained=3, checkpoint=3)
    with holder(run) as first:
        owner = read_owner(run)
        assert owner is not None and (owner.pid, owner.host) == (first.pid,
                                                                 socket.gethostname())
        with pytest.raises(RunBusy) as busy:
            RunLock.take(run)
        assert f"{run} is in use by a running `hercs up` (pid {first.pid} on " \
               f"{socket.gethostname()}, started " in str(busy.value)
        # through the command line: a resume, and a fresh start on the same name
        for argv in (["up", "--resume", str(run)],
                     ["up", "--run", "busy", "--run-dir", str(tmp_path / "runs")]):
            assert main(argv) == 2, argv
            err = capsys.readouterr().err
            assert err.startswith(f"hercs up: {run} is in use by a running `hercs up` (pid "
                                  f"{first.pid} on "), err
            assert f"`kill {first.pid}` on {socket.gethostname()}" in err
        assert read_owner(run) == owner  # the refused ones changed nothing


def test_a_killed_owner_leaves_no_stuck_lock(tmp_path: Path, capsys) -> None:
    run = tmp_path / "runs" / "orphan"
    make_run(run, epochs=3, trained=3, checkpoint=3)
    with holder(run) as first:
        first.send_signal(signal.SIGKILL)
        first.wait()
    assert RunDir(run).lock.exists()  # the dead owner's file is still there, unlocked
    assert main(["up", "--resume", str(run)]) == 0  # taken at once: "already finished"
    assert "already finished (3 epochs)" in capsys.readouterr().out
    assert not RunDir(run).lock.exists()  # released and removed
    lock = RunLock.take(run)
    try:
        assert lock.held and read_owner(run) is not None
    finally:
        lock.release()


def test_an_owner_never_shares_with_one_that_opened_the_file_before_it_was_removed(
        tmp_path: Path) -> None:
    """The owner removes owner.lock as it lets go; a process that had opened the old file
    must not lock it (it is no longer the one at the path) but the new one."""
    import fcntl
    import os

    first = RunLock.take(tmp_path)
    stale = os.open(RunDir(tmp_path).lock, os.O_RDWR)
    try:
        first.release()
        second = RunLock.take(tmp_path)  # a new file at the path
        fcntl.flock(stale, fcntl.LOCK_EX | fcntl.LOCK_NB)  # the old inode: free, but orphaned
        with pytest.raises(RunBusy):
            RunLock.take(tmp_path)
        second.release()
    finally:
        os.close(stale)


def test_a_requeued_attempt_waits_for_the_previous_attempts_lock(tmp_path: Path) -> None:
    """A dead node's lock on a shared file system lasts until its lease ends: `take` with a
    wait tries again until the holder is gone (here a process killed 1 s in), and without one
    it refuses at once."""
    run = tmp_path / "runs" / "requeued"
    run.mkdir(parents=True)
    with holder(run) as first:
        with pytest.raises(RunBusy):
            RunLock.take(run)
        killer = threading.Timer(1.0, first.kill)
        killer.start()
        try:
            lock = RunLock.take(run, wait_s=60.0)
        finally:
            killer.cancel()
        try:
            assert lock.held and read_owner(run).pid == os.getpid()
        finally:
            lock.release()
