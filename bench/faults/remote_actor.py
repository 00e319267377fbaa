"""Actors on other hosts for the network-fault benches (bench/faults/net_faults.py, the chaos
soak, rejoin): `hercs actor` started in a network namespace (bench/faults/netns.py) and
stopped, each with its own DEBUG log (one line per ack, read back by net_measure), and the
small things those benches share: a free port on every address and SIGTERM as an exit.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from bench.common import REPO
from bench.faults.netns import Host
from hercs.apps.launch.child_process import pdeathsig_preexec, stop_process

ACTOR_EXIT_S = 60.0
"""How long an actor may take to stop by itself once `hercs up` has exited (it stops when
the learner says the run is finished); then it gets SIGTERM."""


@dataclass
class Actor:
    host: Host
    ident: str
    log: Path
    proc: subprocess.Popen[bytes]

    def stop(self, timeout_s: float) -> tuple[int, bool]:
        """Its exit status once it ends by itself, else after SIGTERM (then SIGKILL);
        and whether it had to be stopped."""
        try:
            return self.proc.wait(timeout=timeout_s), False
        except subprocess.TimeoutExpired:
            stop_process(self.proc, signal.SIGTERM, grace_s=30)
            return self.proc.returncode, True


def actor_ident(index: int) -> str:
    """The `--id` of the actor on host `index` (its wire id adds `@<incarnation>`)."""
    return f"net-{index}"


def start_actor(host: Host, *, index: int, endpoint: str, run: str, certs: Path,
                out: Path, log_name: str | None = None) -> Actor:
    """`hercs actor` in `host`'s namespace, its output (DEBUG: one line per ack) in
    `out/log_name` (default `<run>.<ident>.log`)."""
    ident = actor_ident(index)
    log = out / (log_name or f"{run}.{ident}.log")
    argv = host.exec_argv([sys.executable, "-m", "hercs.apps.cli", "actor", "--connect", endpoint,
                           "--run", run, "--tls-dir", str(certs), "--id", ident])
    with log.open("wb") as sink:
        proc = subprocess.Popen(argv, stdout=sink, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, cwd=REPO, start_new_session=True,
                                env=dict(os.environ, HERCS_LOG="DEBUG"),
                                preexec_fn=pdeathsig_preexec())  # dies with the bench
    return Actor(host, ident, log, proc)


@contextlib.contextmanager
def sigterm_as_exit() -> Iterator[None]:
    """SIGTERM ends the bench through its `finally` blocks (namespaces, iptables chains)."""
    previous = signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    try:
        yield None
    finally:
        signal.signal(signal.SIGTERM, previous)
