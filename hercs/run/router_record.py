"""Where a running run's router listens: `runs/<run>/router.json` (`RouterRecord`), written by
`hercs up` once its router listens and removed when it stops; `hercs actor` and `hercs live`
without `--connect` read it, or wait for it (`wait_router`).
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from hercs.config.deploy import endpoint_parts
from hercs.run.rundir import RunDir, RunDirError

WILDCARD_HOSTS = ("0.0.0.0", "[::]")


@dataclass(frozen=True)
class RouterRecord:
    """Where a running run's router listens (`runs/<run>/router.json`).

    `local` is what a process on the router's host uses (a wildcard listen address becomes
    loopback), `remote` what every other host uses (a wildcard becomes `host`, the router
    host's name). `hercs up` writes the record once its router listens and removes it when it
    stops; `pid` is the launcher's, so that only the writer removes it.
    """

    host: str
    local: tuple[str, ...]
    remote: tuple[str, ...]
    pid: int

    @classmethod
    def for_listen(cls, listen: Sequence[str], *, host: str | None = None,
                   pid: int | None = None) -> RouterRecord:
        """The record of a router listening on `listen` (concrete ports) on this host."""
        host = host or socket.gethostname()
        local, remote = [], []
        for endpoint in listen:
            proto, addr, port = endpoint_parts(endpoint)
            wildcard = addr in WILDCARD_HOSTS
            loop = "[::1]" if addr == "[::]" else "127.0.0.1"
            local.append(f"{proto}/{loop if wildcard else addr}:{port}")
            remote.append(f"{proto}/{host if wildcard else addr}:{port}")
        return cls(host=host, local=tuple(local), remote=tuple(remote),
                   pid=os.getpid() if pid is None else pid)

    def endpoints_for(self, host: str | None = None) -> list[str]:
        """What a client on `host` (default: this host) connects to."""
        return list(self.local if (host or socket.gethostname()) == self.host else self.remote)


def write_router(run_dir: Path, record: RouterRecord) -> Path:
    """Write `run_dir/router.json` atomically (readers never see half a file)."""
    path = RunDir(run_dir).router
    tmp = path.with_name(f".{path.name}.{os.getpid()}")
    tmp.write_text(json.dumps({"host": record.host, "local": list(record.local),
                               "remote": list(record.remote), "pid": record.pid}) + "\n")
    tmp.replace(path)
    return path


def read_router(run_dir: Path) -> RouterRecord | None:
    """The record in `run_dir/router.json`, or None while there is none (no run running)."""
    path = RunDir(run_dir).router
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        raise RunDirError(f"{path}: unreadable ({exc}); it is written by the "
                          "run's `hercs up`: is that one running?") from None
    try:
        return RouterRecord(host=str(data["host"]), local=tuple(data["local"]),
                            remote=tuple(data["remote"]), pid=int(data["pid"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise RunDirError(f"{path}: not a router record ({exc!r})") from None


def remove_router(run_dir: Path, pid: int | None = None) -> None:
    """Remove `run_dir/router.json` if it is the one `pid` (default: this process) wrote."""
    record = None
    with contextlib.suppress(RunDirError):
        record = read_router(run_dir)
    if record is not None and record.pid == (os.getpid() if pid is None else pid):
        RunDir(run_dir).router.unlink(missing_ok=True)


ROUTER_POLL_S = 0.5
"""How often `wait_router` looks for the file: run directories live on shared storage (NFS,
Lustre), where no file-change event reaches another host, so it polls."""


def wait_router(run_dir: Path, *, timeout_s: float, stop: Callable[[], bool] = lambda: False,
                say: Callable[[str], None] | None = None) -> RouterRecord | None:
    """Wait until `run_dir/router.json` exists and return its record; None after `timeout_s`
    (0: wait for ever) or once `stop()` is true. `say` gets a line every 10 s of waiting."""
    path = RunDir(run_dir).router
    started = time.monotonic()
    next_note = started + 10.0
    while True:
        record = read_router(run_dir)
        if record is not None:
            return record
        now = time.monotonic()
        if stop() or (timeout_s > 0 and now - started >= timeout_s):
            return None
        if say is not None and now >= next_note:
            say(f"waiting for {path} (written once the run's router listens), "
                f"{now - started:.0f} s so far")
            next_note = now + 10.0
        time.sleep(ROUTER_POLL_S)
