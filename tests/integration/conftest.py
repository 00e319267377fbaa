"""Fixtures for real Zenoh sessions on loopback, each test on its own free port, and `up`:
`hercs up` with stand-in children (tests/integration/launcher_standins.py)."""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from hercs.net.transport import Transport
from hercs.proto.keys import RunKeys
from tests.integration.launcher_standins import DRIVER, STANDIN, Launcher, process_alive
from tests.integration.services import OpenClient, OpenRunSide, RunSide
from tests.support import free_endpoint


@pytest.fixture
def endpoint() -> str:
    return free_endpoint()


@pytest.fixture
def log_event(caplog: pytest.LogCaptureFixture) -> Iterator[Callable[[str], threading.Event]]:
    """`log_event(text)` → an Event set when hercs.net.transport logs a message containing text."""
    logger = logging.getLogger("hercs.net.transport")
    caplog.set_level(logging.DEBUG, logger="hercs.net.transport")
    spies: list[logging.Handler] = []

    def watch(text: str) -> threading.Event:
        seen = threading.Event()

        class _Spy(logging.Handler):
            def emit(self, record: logging.LogRecord) -> None:
                if text in record.getMessage():
                    seen.set()

        spies.append(_Spy())
        logger.addHandler(spies[-1])
        return seen

    yield watch
    for spy in spies:
        logger.removeHandler(spy)


@pytest.fixture
def router(endpoint: str) -> Iterator[Transport]:
    """A router listening on `endpoint`, as `hercs up` embeds one."""
    transport = Transport.open(mode="router", listen=[endpoint])
    yield transport
    transport.close()


@pytest.fixture
def open_client(router: Transport, endpoint: str) -> Iterator[Callable[[], Transport]]:
    """Opens client transports connected to `router`; all are closed at teardown."""
    opened: list[Transport] = []

    def _open() -> Transport:
        transport = Transport.open(mode="client", connect=[endpoint], connect_timeout_s=5.0)
        opened.append(transport)
        return transport

    yield _open
    for transport in reversed(opened):
        transport.close()


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[list[subprocess.Popen]]:
    started: list[subprocess.Popen] = []
    yield started
    for proc in started:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
    for log in tmp_path.glob("*.log"):  # shown by pytest on failure
        print(f"---- {log.name}\n{log.read_text()}")


@pytest.fixture
def run_side(open_client: OpenClient, tmp_path: Path, procs: list[subprocess.Popen]
             ) -> OpenRunSide:
    """Opens the test's side of the run of that name (services.RunSide)."""
    return lambda run: RunSide(open_client(), RunKeys(run), tmp_path, procs)


@pytest.fixture
def up(tmp_path: Path):
    """Starts `hercs up` with stand-in children: up(behaviours, *flags, stop_timeout_s=5)."""
    standin, driver = tmp_path / "standin.py", tmp_path / "driver.py"
    standin.write_text(STANDIN)
    driver.write_text(DRIVER)
    events = tmp_path / "events.txt"
    started: list[Launcher] = []

    def start(behaviours: dict[str, str], *flags: str, stop_timeout_s: float = 5.0,
              listen: bool = True) -> Launcher:
        """listen=False leaves --listen out: the router takes any free port."""
        argv = [sys.executable, str(driver), str(standin), str(events), json.dumps(behaviours),
                str(stop_timeout_s), "--run-dir", str(tmp_path / "runs"),
                *(["--listen", free_endpoint()] if listen else []), *flags]
        launcher = Launcher(argv, cwd=tmp_path)
        started.append(launcher)
        return launcher

    start.events = events  # type: ignore[attr-defined]
    yield start
    for launcher in started:
        pids = launcher.child_pids.values()
        launcher.kill()
        for pid in pids:  # never leave anything behind, even when a test failed
            if process_alive(pid):
                os.kill(pid, signal.SIGKILL)
