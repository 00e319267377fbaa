"""Helpers to run hercs service processes in integration tests (real processes, real Zenoh)."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from hercs.apps.launch.child_process import stop_process
from hercs.config import HercsConfig, apply_overrides, save_yaml
from hercs.net.transport import Transport
from hercs.proto import hercs_pb2 as pb
from hercs.proto.keys import RunKeys
from hercs.run.rundir import RunDir

WAIT_S = 15.0
STOP_WITHIN_S = 5.0

OpenClient = Callable[[], Transport]
"""The `open_client` fixture (conftest.py): a new client session connected to the test's router."""


def make_test_config(tmp_path: Path, endpoint: str,
                     overrides: list[str]) -> tuple[HercsConfig, Path]:
    """A config for one test run, saved to tmp_path/config.yaml; runs live under tmp_path."""
    config = apply_overrides(HercsConfig(), [
        "run.name=t", f"run.run_dir={tmp_path / 'runs'}", f"transport.connect=[{endpoint}]",
        f"transport.listen=[{endpoint}]", *overrides])
    path = RunDir(tmp_path).config
    save_yaml(config, path)
    return config, path


class ServiceProcess:
    """`hercs <service> --config FILE --id ID` as a child process, logging to a file."""

    def __init__(self, service: str, config_path: Path, ident: str, log_dir: Path) -> None:
        self.service = service
        self.ident = ident
        self.log_path = log_dir / f"{service}-{ident}.log"
        self._log = open(self.log_path, "wb")  # noqa: SIM115 (closed in stop())
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "hercs.apps.cli", service, "--config", str(config_path),
             "--id", ident], stdout=self._log, stderr=subprocess.STDOUT, env=env)

    def log_text(self) -> str:
        return self.log_path.read_text(errors="replace")

    def stop(self, timeout_s: float = 20.0) -> int:
        """SIGTERM, wait; returns the exit code (SIGKILL and a failing code if it hangs)."""
        if not stop_process(self.proc, signal.SIGTERM, grace_s=timeout_s):
            self._log.close()
            raise AssertionError(f"{self.service} ignored SIGTERM for {timeout_s} s:\n"
                                 f"{self.log_text()[-3000:]}")
        self._log.close()
        return self.proc.returncode

    def kill(self) -> None:
        self.proc.kill()
        self.proc.wait()
        self._log.close()

def start_service(role: str, config: HercsConfig, ident: str, tmp_path: Path) -> subprocess.Popen:
    path = tmp_path / f"{role}.yaml"
    save_yaml(config, path)
    with (tmp_path / f"{role}.log").open("w") as log:  # the child keeps its own copy
        return subprocess.Popen(
            [sys.executable, "-m", "hercs.apps.cli", role, "--config", str(path), "--id", ident],
            stdout=log, stderr=subprocess.STDOUT, env={**os.environ, "HERCS_LOG": "INFO"},
        )


def wait_for(q: queue.Queue, pred: Callable[[object], bool], what: str) -> object:
    """The first item of `q` satisfying `pred` (others are discarded), within WAIT_S."""
    deadline = time.monotonic() + WAIT_S
    while True:
        try:
            item = q.get(timeout=max(deadline - time.monotonic(), 0.001))
        except queue.Empty:
            raise AssertionError(f"timed out after {WAIT_S} s waiting for {what}") from None
        if pred(item):
            return item


@dataclass
class RunSide:
    """The test's side of one run, where it plays the services it does not start: a client
    session that watches the run's liveliness tokens, and the services it starts in the run
    (kept in the `procs` fixture, which kills what is left)."""

    transport: Transport
    keys: RunKeys
    tmp_path: Path
    procs: list[subprocess.Popen]
    alive: queue.Queue = field(init=False)
    """(key, up) for every liveliness token of the run that comes or goes."""

    def __post_init__(self) -> None:
        self.alive = queue.Queue()
        self.transport.watch_alive(self.keys.all_alive,
                                   lambda key, up: self.alive.put((key, up)))

    def metrics(self, role: str) -> queue.Queue[dict[str, float]]:
        """The values of every Metrics message `role` publishes in the run."""
        metrics: queue.Queue[dict[str, float]] = queue.Queue()
        self.transport.subscribe(
            self.keys.metrics(role),
            lambda key, raw: metrics.put(dict(pb.Metrics.FromString(raw).values)))
        return metrics

    def start(self, role: str, config: HercsConfig, ident: str) -> subprocess.Popen:
        """`start_service`, waited for until its liveliness token appears."""
        proc = start_service(role, config, ident, self.tmp_path)
        self.procs.append(proc)
        wait_for(self.alive, lambda c: c == (self.keys.alive(role, ident), True), f"the {role}")
        return proc

    def stop_cleanly(self, proc: subprocess.Popen, role: str, ident: str) -> None:
        """SIGTERM: the service exits with 0 within STOP_WITHIN_S, and its token vanishes."""
        key = self.keys.alive(role, ident)
        started = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=STOP_WITHIN_S + 5) == 0
        assert time.monotonic() - started < STOP_WITHIN_S
        wait_for(self.alive, lambda c: c == (key, False), f"{key} to vanish")


OpenRunSide = Callable[[str], RunSide]
"""The `run_side` fixture (conftest.py): the test's side of the run of that name."""


def next_replay_status(client: Transport, key: str, timeout_s: float) -> pb.ReplayStatus:
    """The next ReplayStatus the replay publishes on `key` (asserted within `timeout_s`)."""
    got = threading.Event()
    box: list[pb.ReplayStatus] = []

    def on_status(_key: str, payload: bytes) -> None:
        box.append(pb.ReplayStatus.FromString(payload))
        got.set()

    sub = client.subscribe(key, on_status)
    assert got.wait(timeout_s), "no ReplayStatus within the timeout"
    sub.close()
    return box[-1]

