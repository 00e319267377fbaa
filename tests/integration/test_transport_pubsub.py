"""hercs.net.transport against real Zenoh sessions on loopback (a router plus clients per test):
publishers and subscribers, liveliness, concurrency, closing, shared memory and sessions
that reopen. Queries and sessions: test_transport.py.

No sleeps stand in for synchronisation: every wait is on an Event or a queue with a timeout.
"""

from __future__ import annotations

import queue
import subprocess
import sys
import threading
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor

import pytest

from hercs.net.transport import PendingReply, Transport, TransportError, TransportTimeout
from tests.integration.services import OpenClient
from tests.integration.transport_support import RUN, WAIT_S, echo, request_in_background

pytestmark = pytest.mark.integration


def test_late_joiner_gets_the_latest_value(open_client: OpenClient) -> None:
    learner, probe = open_client(), open_client()
    through: queue.Queue[bytes] = queue.Queue()
    probe.subscribe(f"{RUN}/weights", lambda key, payload: through.put(payload), latest=True)
    weights = learner.publisher(f"{RUN}/weights", latest=True)
    weights.put(b"v1")
    weights.put(b"v2")
    # Puts are asynchronous: wait until v2 (so v1 too: one link is FIFO) has left the learner,
    # or a joiner could still get v1 live. Consumers ignore older versions for that reason.
    while through.get(timeout=WAIT_S) != b"v2":
        pass

    actor = open_client()  # a new session, joining after both puts went out
    got: queue.Queue[tuple[str, bytes]] = queue.Queue()
    actor.subscribe(f"{RUN}/weights", lambda key, payload: got.put((key, payload)), latest=True)

    assert got.get(timeout=WAIT_S) == (f"{RUN}/weights", b"v2")
    weights.put(b"v3")
    assert got.get(timeout=WAIT_S) == (f"{RUN}/weights", b"v3")  # so v1 never came in between


def test_subscriber_gets_puts_in_order_with_their_keys(open_client: OpenClient) -> None:
    sender, monitor = open_client(), open_client()
    got: queue.Queue[tuple[str, bytes]] = queue.Queue()
    monitor.subscribe(f"{RUN}/metrics/**", lambda key, payload: got.put((key, payload)))
    metrics = sender.publisher(f"{RUN}/metrics/learner", block=True)
    assert metrics.wait_for_subscribers(WAIT_S)

    for i in range(50):
        metrics.put(str(i).encode())
    received = [got.get(timeout=WAIT_S) for _ in range(50)]
    assert received == [(f"{RUN}/metrics/learner", str(i).encode()) for i in range(50)]


def test_liveliness_token_appears_and_disappears(open_client: OpenClient, endpoint: str) -> None:
    launcher = open_client()
    changes: queue.Queue[tuple[str, bool]] = queue.Queue()
    launcher.watch_alive(f"{RUN}/alive/**", lambda key, alive: changes.put((key, alive)))

    replay = open_client()
    replay.declare_alive(f"{RUN}/alive/replay/0")
    assert changes.get(timeout=WAIT_S) == (f"{RUN}/alive/replay/0", True)
    replay.close()
    assert changes.get(timeout=WAIT_S) == (f"{RUN}/alive/replay/0", False)

    # a real process that dies without closing anything
    child = subprocess.Popen(
        [sys.executable, "-c",
         "import sys\n"
         "from hercs.net.transport import Transport\n"
         f"t = Transport.open(mode='client', connect=[{endpoint!r}], connect_timeout_s=5)\n"
         f"t.declare_alive('{RUN}/alive/actor/7')\n"
         "print('ready', flush=True)\n"
         "sys.stdin.read()\n"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == "ready"
        assert changes.get(timeout=WAIT_S) == (f"{RUN}/alive/actor/7", True)
        child.kill()
        assert changes.get(timeout=WAIT_S) == (f"{RUN}/alive/actor/7", False)
    finally:
        child.kill()
        child.wait(WAIT_S)


def test_concurrent_requests_are_each_answered_exactly_once(open_client: OpenClient) -> None:
    server, client = open_client(), open_client()
    seen: Counter[bytes] = Counter()
    lock = threading.Lock()

    def handler(payload: bytes) -> bytes:
        with lock:
            seen[payload] += 1
        return b"ack:" + payload

    server.serve(f"{RUN}/replay/insert", handler, workers=2)
    requests = [f"actor{i % 4}/seq{i}".encode() for i in range(100)]

    with ThreadPoolExecutor(max_workers=4) as pool:
        replies = list(pool.map(
            lambda p: client.request(f"{RUN}/replay/insert", p, timeout_s=WAIT_S), requests))

    assert replies == [b"ack:" + p for p in requests]
    assert seen == Counter(requests) and set(seen.values()) == {1}


def test_transport_close_undeclares_everything_and_stops_threads_promptly(
    open_client: OpenClient,
) -> None:
    holder = open_client()  # holds a query of `service` while it closes
    parked: queue.Queue[PendingReply] = queue.Queue()
    holder.serve_deferred(f"{RUN}/held", parked.put)
    changes: queue.Queue[tuple[str, bool]] = queue.Queue()
    holder.watch_alive(f"{RUN}/alive/**", lambda key, alive: changes.put((key, alive)))
    before = {t.name for t in threading.enumerate()}
    service = open_client()
    service.serve(f"{RUN}/replay/sample", echo, workers=3)
    service.serve_deferred(f"{RUN}/replay/insert", lambda pending: None)
    service.subscribe(f"{RUN}/cluster/model", lambda key, payload: None, latest=True)
    service.subscribe(f"{RUN}/replay/inserted", lambda key, payload: None)
    service.watch_alive(f"{RUN}/alive/**", lambda key, alive: None)
    service.publisher(f"{RUN}/weights", latest=True).put(b"w")
    service.publisher(f"{RUN}/replay/status").put(b"s")
    service.declare_alive(f"{RUN}/alive/replay/0")
    assert changes.get(timeout=WAIT_S) == (f"{RUN}/alive/replay/0", True)
    assert {t.name for t in threading.enumerate()} - before  # our threads are running
    in_flight = request_in_background(service, f"{RUN}/held", b"x")
    parked.get(timeout=WAIT_S)

    started = time.monotonic()
    service.close()
    service.close()  # idempotent

    assert time.monotonic() - started < 2.0
    error = in_flight.get(timeout=WAIT_S)  # the waiting request ends too
    assert isinstance(error, TransportError) and "session closed" in str(error)
    assert not {t.name for t in threading.enumerate() if t.name.startswith("hercs-")} - before
    assert service.session.is_closed()
    with pytest.raises(TransportError, match="transport is closed"):
        service.publisher(f"{RUN}/weights")
    assert changes.get(timeout=WAIT_S) == (f"{RUN}/alive/replay/0", False)
    with pytest.raises(TransportTimeout):  # its queryables are gone
        holder.request(f"{RUN}/replay/sample", b"x", timeout_s=0.3)


def _rss_shmem_kib() -> int:
    for line in open("/proc/self/status"):  # noqa: SIM115 (procfs, read once)
        if line.startswith("RssShmem:"):
            return int(line.split()[1])
    raise AssertionError("no RssShmem in /proc/self/status")


def test_senders_that_come_and_go_leave_no_shared_memory_behind(
        open_client: OpenClient) -> None:
    """Zenoh's shared-memory transport (off in our sessions) maps a 16 MiB pool per local
    sender of messages over 3 KiB and keeps it after the sender closes; a long-lived replay
    with restarting actors would grow without bound."""
    server = open_client()
    server.serve(f"{RUN}/shm", echo)
    before = _rss_shmem_kib()
    for _ in range(4):
        client = open_client()
        payload = bytes(256 * 1024)
        assert client.request(f"{RUN}/shm", payload, timeout_s=WAIT_S) == b"echo:" + payload
        client.close()
    grown_mib = (_rss_shmem_kib() - before) / 1024
    assert grown_mib < 8, f"shared memory grew by {grown_mib:.0f} MiB for 4 short-lived senders"


def test_a_blind_client_reopens_its_session_and_every_handle_works_on_the_new_one(
        open_client: OpenClient, endpoint: str) -> None:
    """A key that answered before finds no queryable for `rediscover_s` while the session has
    its router: the client reopens its session (hercs.net.rediscovery); its subscription,
    `latest` publisher, queryable and liveliness token then work on the new session."""
    replay, monitor = open_client(), open_client()
    client = Transport.open(mode="client", connect=[endpoint], connect_timeout_s=5.0,
                            rediscover_s=1.0)
    try:
        got: queue.Queue[bytes] = queue.Queue()
        client.subscribe(f"{RUN}/progress", lambda key, payload: got.put(payload))
        weights = client.publisher(f"{RUN}/weights", latest=True)
        weights.put(b"w1")
        client.serve(f"{RUN}/learner/state", echo)
        client.declare_alive(f"{RUN}/alive/actor/1")
        changes: queue.Queue[tuple[str, bool]] = queue.Queue()
        monitor.watch_alive(f"{RUN}/alive/actor/*", lambda key, alive: changes.put((key, alive)))
        assert changes.get(timeout=WAIT_S) == (f"{RUN}/alive/actor/1", True)

        server = replay.serve(f"{RUN}/replay/insert", echo)
        assert client.request(f"{RUN}/replay/insert", b"1", timeout_s=WAIT_S) == b"echo:1"
        server.close()  # the key now finds no queryable; the session still has its router
        deadline = time.monotonic() + 20 * WAIT_S
        while client.reopens == 0:
            assert time.monotonic() < deadline, "never reopened"
            with pytest.raises(TransportError):
                client.request(f"{RUN}/replay/insert", b"2", timeout_s=0.3)
        assert client.reopens == 1
        # the token left with the old session and came back with the new one
        assert changes.get(timeout=WAIT_S) == (f"{RUN}/alive/actor/1", False)
        assert changes.get(timeout=WAIT_S) == (f"{RUN}/alive/actor/1", True)

        replay.serve(f"{RUN}/replay/insert", echo)
        assert client.request(f"{RUN}/replay/insert", b"3", timeout_s=WAIT_S) == b"echo:3"
        assert monitor.request(f"{RUN}/learner/state", b"q", timeout_s=WAIT_S) == b"echo:q"
        progress = monitor.publisher(f"{RUN}/progress", block=True)
        assert progress.wait_for_subscribers(WAIT_S)
        progress.put(b"p")
        assert got.get(timeout=WAIT_S) == b"p"
        late: queue.Queue[bytes] = queue.Queue()  # a late joiner finds the last weights again
        monitor.subscribe(f"{RUN}/weights", lambda key, payload: late.put(payload), latest=True)
        assert late.get(timeout=WAIT_S) == b"w1"
    finally:
        client.close()


def test_a_key_that_never_answered_does_not_reopen(open_client: OpenClient,
                                                   endpoint: str) -> None:
    """An actor started before its run waits for the replay without reopening anything."""
    client = Transport.open(mode="client", connect=[endpoint], connect_timeout_s=5.0,
                            rediscover_s=0.2)
    try:
        started = time.monotonic()
        while time.monotonic() - started < 1.0:  # five bounds' worth of misses
            with pytest.raises(TransportTimeout):
                client.request(f"{RUN}/config", b"", timeout_s=0.2)
        assert client.reopens == 0
    finally:
        client.close()
