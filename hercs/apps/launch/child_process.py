"""Service child processes, as `hercs up` and the benchmarks start them.

A child is `python -m hercs.apps.cli <role> ...` with its output in a log file, leading its own
process group (Ctrl-C at a terminal reaches only the parent, which stops the children in order;
a signal to the group also reaches what the child forked), with `PR_SET_PDEATHSIG` = SIGKILL set
between fork and exec so the kernel kills it if the parent dies. That signal fires
when the forking *thread* exits: start children from the main thread only.
`stop_process` ends any child: a signal, a grace period, then SIGKILL.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

_PR_SET_PDEATHSIG = 1


def service_argv(role: str, ident: str, config_path: Path) -> list[str]:
    """The argv of one service: `python -m hercs.apps.cli <role> --config <file> --id <ident>`."""
    return [sys.executable, "-m", "hercs.apps.cli", role, "--config", str(config_path),
            "--id", ident]


def pdeathsig_preexec(sig: int = signal.SIGKILL) -> Callable[[], None] | None:
    """A `preexec_fn` making the child get `sig` (SIGKILL unless told) when its parent dies
    (Linux only; strictly, when the parent's thread that forked it ends).

    Runs in the forked child before exec, so it only calls what was resolved here, in the
    parent. If the parent died before the prctl took effect the child is already
    re-parented: it exits at once.
    """
    if not sys.platform.startswith("linux"):
        return None
    prctl = ctypes.CDLL(None, use_errno=True).prctl
    prctl.argtypes = [ctypes.c_int, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong,
                      ctypes.c_ulong]
    number = int(sig)
    parent = os.getpid()

    def preexec() -> None:
        prctl(_PR_SET_PDEATHSIG, number, 0, 0, 0)
        if os.getppid() != parent:
            os._exit(1)

    return preexec


def start_child(argv: Sequence[str], *, log_path: Path,
                cwd: Path | None = None) -> subprocess.Popen[bytes]:
    """Start `argv` in a process group of its own, with the parent-death signal, stdin from
    /dev/null and stdout and stderr appended to `log_path` (unbuffered Python output)."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    with log_path.open("ab") as log_file:
        return subprocess.Popen(
            list(argv), stdin=subprocess.DEVNULL, stdout=log_file, stderr=subprocess.STDOUT,
            env=env, cwd=cwd, close_fds=True, process_group=0,
            preexec_fn=pdeathsig_preexec())


def signal_group(proc: subprocess.Popen[bytes], sig: int) -> None:
    """Signal the child's whole process group (it leads it); a group already gone is fine."""
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, sig)


def stop_process(proc: subprocess.Popen[Any], sig: int = signal.SIGTERM,
                 grace_s: float = 15.0) -> bool:
    """Send `sig` to `proc` if it still runs and give it `grace_s` seconds to end; SIGKILL it
    (and reap it) if it has not. True if it ended by itself, False if it had to be killed."""
    if proc.poll() is not None:
        return True
    proc.send_signal(sig)
    try:
        proc.wait(grace_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        return False
    return True


def describe_exit(code: int) -> str:
    """`exit code 3`, or `killed by SIGKILL` for a negative return code."""
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


def log_tail(path: Path, lines: int) -> list[str]:
    """The last `lines` lines of a child's log (read from its last 64 KiB), or one line
    saying why it cannot be read."""
    try:
        with path.open("rb") as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - 64 * 1024))
            text = f.read().decode("utf-8", errors="replace")
    except OSError as exc:
        return [f"(cannot read {path}: {exc})"]
    return text.splitlines()[-lines:]
