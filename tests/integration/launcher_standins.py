"""Stand-ins for `hercs up`'s children and a driver that runs `hercs up` with them, for the
launcher's tests (the `up` fixture of conftest.py starts them): a small script per service
that joins the run over Zenoh, announces itself and then serves, publishes learner metrics,
crashes or ignores SIGTERM; a reader of the launcher's output lines; the events file the
stand-ins write; a settable clock for Progress."""

from __future__ import annotations

import contextlib
import os
import queue
import re
import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
WAIT_S = 20.0

# A stand-in for one service: joins the run like a real service (client session, liveliness
# token), records "start"/"stop" in the events file, then behaves as told for its id.
STANDIN = r'''
import json, os, signal, sys, time
role, ident, config_path, events, behaviours = sys.argv[1:6]
behaviour = json.loads(behaviours).get(ident, "serve")

def record(what):
    fd = os.open(events, os.O_WRONLY | os.O_APPEND | os.O_CREAT)
    os.write(fd, f"{what} {ident} {os.getpid()}\n".encode())
    os.close(fd)

def on_term(signum, frame):
    if behaviour == "stubborn":
        record("ignore")
        return
    record("stop")
    os._exit(0)

signal.signal(signal.SIGTERM, on_term)

from hercs.config import load_yaml
from hercs.net.transport import Transport
from hercs.proto import SCHEMA_VERSION, hercs_pb2 as pb
from hercs.proto.keys import RunKeys

config = load_yaml(config_path)
keys = RunKeys(config.run.name)
transport = Transport.open(mode="client", connect=config.transport.connect,
                           connect_timeout_s=10)
transport.declare_alive(keys.alive(role, ident))
record("start")
if behaviour == "crash":
    print("boom: the stand-in failed on purpose", file=sys.stderr, flush=True)
    os._exit(3)
if behaviour == "crash-once" and not os.path.exists(f"{events}.crashed.{ident}"):
    open(f"{events}.crashed.{ident}", "w").close()
    print("boom: the stand-in failed once on purpose", file=sys.stderr, flush=True)
    os._exit(3)
if behaviour == "exit0":
    os._exit(0)
if behaviour == "diverged":  # what hercs.net.service_shell exits with for Diverged
    print("hercs learner: training diverged in the stand-in on purpose", file=sys.stderr,
          flush=True)
    os._exit(4)
if behaviour == "config-error":  # what hercs.net.service_shell exits with for a ConfigError
    print("hercs replay: invalid configuration: the stand-in refused it", file=sys.stderr,
          flush=True)
    os._exit(2)
if behaviour.startswith("epochs:"):
    metrics = transport.publisher(keys.metrics(role))
    evals = transport.publisher(keys.eval_result)
    assert metrics.wait_for_subscribers(10) and evals.wait_for_subscribers(10)
    for epoch in range(1, int(behaviour.split(":")[1]) + 1):
        values = {"epoch": epoch, "env_steps_per_s": 1000 + epoch, "updates_per_s": 200 + epoch,
                  "replay_size": 100 * epoch, "policy_lag": 1.5}
        if epoch % 2:  # odd epochs carry their success; even ones come as an EvalResult
            values["success_rate"] = epoch / 10
        metrics.put(pb.Metrics(schema_version=SCHEMA_VERSION, service=f"{role}/{ident}",
                               step=epoch, values=values).SerializeToString())
        if not epoch % 2:
            evals.put(pb.EvalResult(schema_version=SCHEMA_VERSION, epoch=epoch,
                                    success_rate=epoch / 10).SerializeToString())
    transport.close()
    sys.exit(0)
# Not signal.pause(): a SIGTERM that lands after the interpreter's last check for signals
# but before pause() is entered leaves pause() asleep for good (the launcher then SIGKILLs
# the stand-in after its stop timeout and no "stop" is recorded; measured: 1 signal in
# 300,000 sent back to back). A sleep bounds that miss to its length.
while True:
    time.sleep(0.2)
'''

# Runs `hercs up` (argv after the first four) with the stand-ins as children.
DRIVER = r'''
import sys
from hercs.apps.cli.main import build_parser, resolve_config
from hercs.apps.launch.launcher import run_up
standin, events, behaviours, stop_timeout = sys.argv[1:5]
args = build_parser()[0].parse_args(["up", *sys.argv[5:]])

def command(spec, config_path):
    return [sys.executable, standin, spec.role, spec.ident, str(config_path), events, behaviours]

sys.exit(run_up(resolve_config(args), command=command, stop_timeout_s=float(stop_timeout)))
'''

def process_alive(pid: int) -> bool:
    """True while `pid` runs (a zombie, dead but not yet reaped, counts as gone)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False
    return stat.rpartition(")")[2].split()[0] not in ("Z", "X")


def wait_for(condition: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(0.02)


class Launcher:
    """A `hercs up` process whose stdout and stderr are read line by line as they come."""

    def __init__(self, argv: list[str], *, cwd: Path) -> None:
        env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen(argv, cwd=cwd, env=env, text=True,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        self.out: list[str] = []
        self.err: list[str] = []
        self._lines: queue.Queue[str] = queue.Queue()
        self._readers = [threading.Thread(target=self._read, args=(stream, sink), daemon=True)
                         for stream, sink in ((self.proc.stdout, self.out),
                                              (self.proc.stderr, self.err))]
        for reader in self._readers:
            reader.start()

    def _read(self, stream, sink: list[str]) -> None:
        for line in stream:
            sink.append(line.rstrip("\n"))
            self._lines.put(line)

    def wait_for_line(self, pattern: str, timeout_s: float = WAIT_S) -> str:
        deadline = time.monotonic() + timeout_s
        regex = re.compile(pattern)
        while True:
            # every line each time: stdout and stderr grow separately, so an index into
            # their concatenation would skip a stdout line that follows stderr ones
            lines = self.out + self.err
            for line in lines:
                if regex.search(line):
                    return line
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError(f"no line matching {pattern!r} within {timeout_s} s; "
                                     f"output so far:\n" + "\n".join(lines))
            with contextlib.suppress(queue.Empty):
                self._lines.get(timeout=remaining)

    def finish(self, timeout_s: float = WAIT_S) -> int:
        code = self.proc.wait(timeout_s)
        for reader in self._readers:
            reader.join(timeout_s)
        return code

    @property
    def child_pids(self) -> dict[str, int]:
        """ident → pid, from the launcher's "started <role> <ident> (pid N)" lines."""
        found = (re.search(r"started \w+ (\S+) \(pid (\d+)\)", line) for line in self.out)
        return {m.group(1): int(m.group(2)) for m in found if m}

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()

def read_events(path: Path) -> list[tuple[str, str]]:
    if not path.exists():
        return []
    return [tuple(line.split()[:2]) for line in path.read_text().splitlines()]  # type: ignore[misc]

