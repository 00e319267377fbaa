"""bench/faults/delay_relay.py on loopback: bytes arrive in order and complete however the per-chunk
delays are drawn, none before its delay, an end of stream is passed on, and `close()` ends
the connections it relays."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest

from bench.faults.delay_relay import DelayRelay

WAIT_S = 20.0


@pytest.fixture
def echo() -> Iterator[tuple[str, int]]:
    """A server that sends back what it reads and closes its side at the client's EOF."""
    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(WAIT_S)

    def serve() -> None:
        with server:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            with conn:
                while data := conn.recv(65536):
                    conn.sendall(data)
                conn.shutdown(socket.SHUT_WR)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    yield server.getsockname()
    thread.join(WAIT_S)


def read_all(sock: socket.socket) -> bytes:
    chunks = []
    while data := sock.recv(65536):
        chunks.append(data)
    return b"".join(chunks)


def test_chunks_keep_their_order_and_none_arrives_before_its_delay(
        echo: tuple[str, int]) -> None:
    delay_s, jitter_s = 0.05, 0.04  # draws from 10 to 90 ms: unordered draws must not reorder
    relay = DelayRelay(listen=("127.0.0.1", 0), target=echo, delay_s=delay_s,
                       jitter_s=jitter_s, rng=np.random.default_rng(7))
    with relay, socket.create_connection(relay.listen_address, timeout=WAIT_S) as sock:
        sent = []
        started = time.monotonic()
        for i in range(40):  # separate small writes, most read as separate chunks
            chunk = f"{i:04d};".encode()
            sock.sendall(chunk)
            sent.append(chunk)
            time.sleep(0.002)
        sock.shutdown(socket.SHUT_WR)
        first = sock.recv(5)
        first_after_s = time.monotonic() - started
        received = first + read_all(sock)
    assert received == b"".join(sent)  # every byte, in order, then the end of stream
    # one delay each way, each at least delay − jitter
    assert first_after_s >= 2 * (delay_s - jitter_s)
    assert relay.connections == 1


def test_a_fixed_delay_holds_each_direction(echo: tuple[str, int]) -> None:
    relay = DelayRelay(listen=("127.0.0.1", 0), target=echo, delay_s=0.15,
                       rng=np.random.default_rng(0))
    with relay, socket.create_connection(relay.listen_address, timeout=WAIT_S) as sock:
        started = time.monotonic()
        sock.sendall(b"ping")
        assert sock.recv(4) == b"ping"
        assert time.monotonic() - started >= 0.3


def test_close_ends_the_relayed_connections(echo: tuple[str, int]) -> None:
    relay = DelayRelay(listen=("127.0.0.1", 0), target=echo, delay_s=0.0,
                       rng=np.random.default_rng(0))
    relay.start()
    with socket.create_connection(relay.listen_address, timeout=WAIT_S) as sock:
        sock.sendall(b"x")
        assert sock.recv(1) == b"x"
        relay.close()
        assert read_all(sock) == b""  # closed from the relay's side
    with pytest.raises(OSError):
        socket.create_connection(relay.listen_address, timeout=2).close()


def test_jitter_larger_than_the_delay_is_refused() -> None:
    with pytest.raises(ValueError, match="jitter"):
        DelayRelay(listen=("127.0.0.1", 0), target=("127.0.0.1", 1), delay_s=0.01,
                   jitter_s=0.02, rng=np.random.default_rng(0))
