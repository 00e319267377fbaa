"""Fixtures for real Zenoh sessions on loopback, each test on its own free port."""

from __future__ import annotations

import socket
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from hercs.net.transport import Transport


def free_tcp_port() -> int:
    """A TCP port nothing listens on right now (the OS picks it; loopback only)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def free_endpoint() -> str:
    return f"tcp/127.0.0.1:{free_tcp_port()}"


@pytest.fixture
def endpoint() -> str:
    return free_endpoint()


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
