"""hercs.net.transport against real Zenoh sessions on loopback (a router plus clients per test):
queries (request and reply, deferred replies, errors, timeouts) and sessions (connecting,
settings). Pub/sub, liveliness, closing and reopening: test_transport_pubsub.py.

No sleeps stand in for synchronisation: every wait is on an Event or a queue with a timeout.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from typing import Any

import pytest

from hercs.errors import ConfigError, InvalidMessage
from hercs.net.transport import (
    PendingReply,
    RemoteError,
    Transport,
    TransportError,
    TransportTimeout,
)
from hercs.reasons import Reason
from tests.integration.services import OpenClient
from tests.integration.transport_support import RUN, WAIT_S, echo, request_in_background

pytestmark = pytest.mark.integration


@pytest.mark.parametrize("size", [5, 4 * 1024 * 1024], ids=["small", "4MiB"])
def test_request_reply_round_trip_through_router(open_client: OpenClient, size: int) -> None:
    server, client = open_client(), open_client()
    server.serve(f"{RUN}/replay/sample", echo)
    payload = bytes(range(256)) * (size // 256) + b"x" * (size % 256)

    assert client.request(f"{RUN}/replay/sample", payload, timeout_s=WAIT_S) == b"echo:" + payload


def test_invalid_message_is_an_error_reply_with_its_reason(open_client: OpenClient) -> None:
    server, client = open_client(), open_client()
    errors: list[Exception] = []

    def handler(payload: bytes) -> bytes:
        if payload == b"bad":
            raise InvalidMessage(Reason.BAD_SHAPE, "obs: got shape (3,), expected (25,)")
        return b"ok"

    server.serve(f"{RUN}/replay/insert", handler, on_error=errors.append)

    with pytest.raises(RemoteError) as info:
        client.request(f"{RUN}/replay/insert", b"bad", timeout_s=WAIT_S)
    assert (info.value.reason, info.value.detail) == ("bad_shape",
                                                      "obs: got shape (3,), expected (25,)")
    assert [type(e) for e in errors] == [InvalidMessage]
    # the service carries on
    assert client.request(f"{RUN}/replay/insert", b"good", timeout_s=WAIT_S) == b"ok"


def _divide_by_zero(payload: bytes) -> bytes:
    return bytes(len(payload) // 0)


def _return_an_int(payload: bytes) -> bytes:
    return len(payload)  # type: ignore[return-value]


@pytest.mark.parametrize(
    ("handler", "detail"),
    [(_divide_by_zero, "ZeroDivisionError"), (_return_an_int, "expected bytes")],
    ids=["raises", "returns-non-bytes"],
)
def test_handler_bug_is_an_internal_error_reply_answered_once(
    open_client: OpenClient, handler: Callable[[bytes], bytes], detail: str
) -> None:
    server, client = open_client(), open_client()
    calls: list[bytes] = []
    server.serve(f"{RUN}/replay/sample", lambda payload: calls.append(payload) or handler(payload))

    with pytest.raises(RemoteError) as info:
        client.request(f"{RUN}/replay/sample", b"x", timeout_s=WAIT_S)
    assert info.value.reason == Reason.INTERNAL
    assert detail in info.value.detail
    assert calls == [b"x"]  # not re-sent


def test_deferred_reply_is_answered_later_from_another_thread(open_client: OpenClient) -> None:
    server, client = open_client(), open_client()
    parked: queue.Queue[PendingReply] = queue.Queue()
    handler_returned = threading.Event()

    def park(pending: PendingReply) -> None:
        parked.put(pending)
        handler_returned.set()

    srv = server.serve_deferred(f"{RUN}/replay/sample", park)
    result = request_in_background(client, f"{RUN}/replay/sample", b"batch?")
    pending = parked.get(timeout=WAIT_S)
    assert handler_returned.wait(WAIT_S)
    assert srv.pending == 1 and result.empty()  # held: the request is still waiting

    answered_from: list[str] = []

    def answer() -> None:
        answered_from.append(threading.current_thread().name)
        assert pending.reply(b"batch:" + pending.payload)

    limiter = threading.Thread(target=answer, name="rate-limiter")
    limiter.start()
    limiter.join(WAIT_S)

    assert result.get(timeout=WAIT_S) == b"batch:batch?"
    assert answered_from == ["rate-limiter"]
    assert pending.answered and srv.pending == 0
    assert not pending.reply(b"twice") and not pending.reply_error(Reason.EXPIRED, "ignored")


def test_closing_a_server_answers_parked_queries_unavailable(open_client: OpenClient) -> None:
    server, client = open_client(), open_client()
    parked: queue.Queue[PendingReply] = queue.Queue()
    srv = server.serve_deferred(f"{RUN}/replay/insert", parked.put)
    result = request_in_background(client, f"{RUN}/replay/insert", b"ep")
    pending = parked.get(timeout=WAIT_S)
    started = time.monotonic()
    srv.close()

    error = result.get(timeout=WAIT_S)
    assert isinstance(error, RemoteError) and error.reason == Reason.UNAVAILABLE
    assert time.monotonic() - started < 1.0
    assert not pending.reply(b"too late")  # the limiter's later answer is a harmless no-op


def test_request_waits_for_a_queryable_declared_after_it_was_sent(
    open_client: OpenClient, log_event: Callable[[str], threading.Event]
) -> None:
    server, client = open_client(), open_client()
    waiting = log_event("waiting up to")
    result = request_in_background(client, f"{RUN}/replay/sample", b"early")
    assert waiting.wait(WAIT_S), "the request never found itself without a queryable"
    server.serve(f"{RUN}/replay/sample", echo)
    assert result.get(timeout=WAIT_S) == b"echo:early"


def test_request_with_no_queryable_times_out(open_client: OpenClient) -> None:
    client = open_client()
    started = time.monotonic()
    with pytest.raises(TransportTimeout, match=r"no queryable appeared within 0\.3 s"):
        client.request(f"{RUN}/nobody", b"x", timeout_s=0.3)
    assert 0.3 <= time.monotonic() - started < 2.0


def test_request_outlasts_a_matched_queryable_that_does_not_answer(
    open_client: OpenClient,
) -> None:
    # A replay killed a moment ago is still declared at the router: gets routed to it end at
    # once with no reply while the client still sees a match. A request sent then must keep
    # asking until the restarted replay answers (it once gave up after three quick gets).
    server, client = open_client(), open_client()
    silent_gets = 6
    asked: list[float] = []

    def on_query(query: Any) -> None:
        asked.append(time.monotonic())
        if len(asked) > silent_gets:  # dropping a query unanswered ends its get with no reply
            query.reply(query.key_expr, b"answered")

    queryable = server.session.declare_queryable(f"{RUN}/replay/insert", on_query)
    try:
        assert client.request(f"{RUN}/replay/insert", b"ep", timeout_s=WAIT_S) == b"answered"
    finally:
        queryable.undeclare()
    assert len(asked) == silent_gets + 1


def test_request_to_a_queryable_that_never_answers_waits_its_timeout_without_spinning(
    open_client: OpenClient,
) -> None:
    server, client = open_client(), open_client()
    # one answered request first: its round trip is this machine's cost of a get, from which
    # the bound below is sized (a slower machine gets a longer one)
    warm = server.session.declare_queryable(f"{RUN}/replay/ping",
                                            lambda query: query.reply(query.key_expr, b"ok"))
    try:
        started = time.monotonic()
        assert client.request(f"{RUN}/replay/ping", b"", timeout_s=WAIT_S) == b"ok"
        round_trip = time.monotonic() - started
    finally:
        warm.undeclare()
    asked: list[float] = []
    queryable = server.session.declare_queryable(f"{RUN}/replay/insert",
                                                 lambda query: asked.append(time.monotonic()))
    timeout_s = 1.0
    started = time.monotonic()
    try:
        with pytest.raises(TransportTimeout, match=r"no queryable answered within 1 s"):
            client.request(f"{RUN}/replay/insert", b"ep", timeout_s=timeout_s)
    finally:
        queryable.undeclare()
    # past its timeout by at most the longest pause between gets (0.5 s) and a few gets' cost:
    # it ends at its own deadline, not at a whole further get's timeout
    took = time.monotonic() - started
    assert timeout_s <= took < timeout_s + 0.5 + max(1.0, 10 * round_trip), \
        f"{took:.2f} s for a {timeout_s} s timeout (a get's round trip: {round_trip:.3f} s)"
    # the pauses between gets double from 10 ms to 0.5 s: 9 gets fill one second however fast
    # the machine; a slower one makes fewer
    assert 1 <= len(asked) <= 10, f"{len(asked)} gets in {timeout_s} s"


def test_request_held_past_its_timeout_raises_transport_timeout(open_client: OpenClient) -> None:
    server, client = open_client(), open_client()
    parked: queue.Queue[PendingReply] = queue.Queue()
    server.serve_deferred(f"{RUN}/replay/sample", parked.put)
    # first a request answered at once: the queryable is then known to the client, so the
    # held one below cannot end as "no queryable appeared" on a machine slow to propagate it
    answerer = threading.Thread(target=lambda: parked.get(timeout=WAIT_S).reply(b"known"))
    answerer.start()
    assert client.request(f"{RUN}/replay/sample", b"warm-up", timeout_s=WAIT_S) == b"known"
    answerer.join()

    with pytest.raises(TransportTimeout, match=r"no reply within 0\.3 s"):
        client.request(f"{RUN}/replay/sample", b"x", timeout_s=0.3)
    assert parked.get(timeout=WAIT_S).reply(b"after the caller gave up")  # no error either


def test_client_started_before_router_connects_once_router_is_up(
    endpoint: str, log_event: Callable[[str], threading.Event]
) -> None:
    waiting = log_event("waiting for a Zenoh router")
    opened: queue.Queue[Transport | Exception] = queue.Queue()

    def open_client() -> None:
        try:
            opened.put(Transport.open(mode="client", connect=[endpoint], connect_timeout_s=10))
        except Exception as exc:
            opened.put(exc)

    threading.Thread(target=open_client).start()
    router = None
    client = None
    try:
        assert waiting.wait(WAIT_S), "the client never reported that it is waiting"
        assert opened.empty()
        router = Transport.open(mode="router", listen=[endpoint])
        router.serve(f"{RUN}/replay/sample", echo)  # the launcher's router serves it here
        client = opened.get(timeout=WAIT_S)
        assert isinstance(client, Transport)
        assert client.request(f"{RUN}/replay/sample", b"hi", timeout_s=WAIT_S) == b"echo:hi"
    finally:
        for transport in (client, router):
            if isinstance(transport, Transport):
                transport.close()


def test_client_gives_up_after_connect_timeout(endpoint: str) -> None:
    started = time.monotonic()
    with pytest.raises(TransportError, match="no Zenoh router reachable"):
        Transport.open(mode="client", connect=[endpoint], connect_timeout_s=0.3)
    assert time.monotonic() - started < 2.0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"mode": "client", "connect": ["tcp-127.0.0.1"]}, "Endpoints must be of the form"),
        ({"mode": "client"}, "transport.connect: got"),
        ({"mode": "router"}, "transport.listen: got"),
        ({"mode": "broker", "connect": ["tcp/127.0.0.1:7447"]}, "transport mode: got 'broker'"),
    ],
    ids=["bad-endpoint", "client-without-connect", "router-without-listen", "bad-mode"],
)
def test_bad_session_settings_are_config_errors(kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        Transport.open(**kwargs)


def test_router_on_a_busy_port_fails_clearly(router: Transport, endpoint: str) -> None:
    with pytest.raises(TransportError, match="cannot open a Zenoh router"):
        Transport.open(mode="router", listen=[endpoint])
