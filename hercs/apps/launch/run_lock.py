"""One owner per run directory: the `hercs up` that runs it holds `RUN/owner.lock`.

The lock is `flock(LOCK_EX)`, taken without waiting and held for the launcher's life; the
kernel drops it however the process dies, so a requeued `hercs up --resume` takes it at once.
The file names the owner for the refusal message, trusted only while the lock is held.
Children never inherit it (not inheritable, PEP 446). On a file system without a shared flock
(some Lustre mounts) `take` goes on without the lock and says so.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from hercs.errors import HercsError
from hercs.run.rundir import RunDir

NO_FLOCK = frozenset({errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL})
"""flock's errors on a file system that does not support it."""


class RunBusy(HercsError):
    """Another live process owns the run directory; the message names it."""


@dataclass(frozen=True)
class Owner:
    pid: int
    host: str
    started: float
    """Unix time the owner took the lock."""
    command: str

    def describe(self) -> str:
        since = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(self.started))
        return f"pid {self.pid} on {self.host}, started {since}: {self.command}"


def read_owner(run_dir: Path) -> Owner | None:
    """The owner recorded in `run_dir/owner.lock`, or None if it holds none (yet)."""
    try:
        data = json.loads(RunDir(run_dir).lock.read_text())
        return Owner(pid=int(data["pid"]), host=str(data["host"]),
                     started=float(data["started"]), command=str(data["command"]))
    except (OSError, ValueError, KeyError, TypeError):
        return None


class RunLock:
    """The lock on a run directory, held until `release()` (or the process's death)."""

    def __init__(self, run_dir: Path, fd: int | None) -> None:
        self.run_dir = run_dir
        self._fd = fd

    @property
    def held(self) -> bool:
        """False when the file system offered no lock (the run goes on without one)."""
        return self._fd is not None

    @classmethod
    def take(cls, run_dir: Path, *, wait_s: float = 0.0) -> RunLock:
        """Lock `run_dir` (which must exist) for this process, or raise `RunBusy` naming the
        process that holds it. With `wait_s` > 0, a held lock is tried again every second for
        that long first (a requeued Slurm job on a shared file system, where a dead node's
        lock lasts until its lease ends)."""
        deadline = time.monotonic() + wait_s
        while True:
            try:
                return cls._take(run_dir)
            except RunBusy:
                if time.monotonic() >= deadline:
                    raise
                time.sleep(1.0)  # another host's lock: nothing here to wait on

    @classmethod
    def _take(cls, run_dir: Path) -> RunLock:
        path = RunDir(run_dir).lock
        while True:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                owner = read_owner(run_dir)
                who = owner.describe() if owner else "a process that has not named itself yet"
                raise RunBusy(
                    f"{run_dir} is in use by a running `hercs up` ({who}); a run directory "
                    "has one owner at a time. Wait for that run to end, or stop it (Ctrl-C in "
                    f"its terminal, or `kill {owner.pid if owner else 'PID'}` on "
                    f"{owner.host if owner else 'its host'}; a stopped run continues with "
                    f"`hercs up --resume {run_dir}`)") from None
            except OSError as exc:
                os.close(fd)
                if exc.errno not in NO_FLOCK:
                    raise
                print(f"hercs up: {path}: this file system offers no lock ({exc.strerror}); "
                      "going on without one: make sure no other `hercs up` uses "
                      f"{run_dir}", file=sys.stderr, flush=True)
                return cls(run_dir, None)
            # The file may have been replaced between open and flock: lock the one in place.
            try:
                same = os.stat(path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        record = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.time(),
                  "command": " ".join(["hercs", *sys.argv[1:]])}
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(record) + "\n").encode(), 0)
        return cls(run_dir, fd)

    def release(self) -> None:
        """Give the run directory up (idempotent). The file is unlinked while still locked,
        so that a process that opened it meanwhile sees it replaced (`take` compares inodes)
        and locks the new one: no two owners, and `owner.lock` exists only while a run runs
        (or after its owner was killed, unlocked)."""
        if self._fd is not None:
            with contextlib.suppress(OSError):
                RunDir(self.run_dir).lock.unlink()
            os.close(self._fd)  # closing the only descriptor drops the flock
            self._fd = None
