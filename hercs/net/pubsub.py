"""Publishers, subscriptions and liveliness tokens on a Zenoh session, each drained by a
thread of ours and re-declarable on a reopened session (`rebind`); the latest value for late
joiners (docs/ZENOH.md)."""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Callable
from typing import Any

import zenoh
import zenoh.ext as zext

from hercs.net.queries import (
    join_threads,
    received,
    undeclare,
)
from hercs.net.transport_errors import (
    TransportError,
)

log = logging.getLogger("hercs.net.transport")  # the Zenoh layer logs as one (as queries.py)


class Publisher:
    """Puts on one key; with `latest=True` the last put is kept for late joiners."""

    def __init__(self, session: zenoh.Session, key: str, *, latest: bool = False,
                 block: bool = False) -> None:
        self.key = key
        self._lock = threading.Lock()
        self._latest = latest
        self._congestion = (zenoh.CongestionControl.BLOCK if block
                            else zenoh.CongestionControl.DROP)
        self._last: bytes | None = None
        """The last payload put (latest=True), put again on a reopened session's publisher."""
        self._matched: threading.Event | None = None if latest else threading.Event()
        self._listener: Any = None
        self._pub: Any = self._declare(session)
        self._closed = False

    def _declare(self, session: zenoh.Session) -> Any:
        if self._latest:
            return zext.declare_advanced_publisher(
                session, self.key, congestion_control=self._congestion,
                cache=zext.CacheConfig(1), publisher_detection=True,
            )
        pub = session.declare_publisher(self.key, congestion_control=self._congestion)
        matched = self._matched
        assert matched is not None
        matched.clear()

        def on_status(status: zenoh.MatchingStatus) -> None:  # only flips an Event
            (matched.set if status.matching else matched.clear)()

        self._listener = pub.declare_matching_listener(on_status)
        if pub.matching_status.matching:  # type: ignore[attr-defined]  # a MatchingStatus
            matched.set()
        return pub

    def rebind(self, session: zenoh.Session) -> None:
        """Publish on `session` instead (a reopened session); a `latest` publisher puts its
        last value again, so that late joiners still find it."""
        with self._lock:
            if self._closed:
                return
            if self._listener is not None:
                undeclare(self._listener)
            undeclare(self._pub)
            self._pub = self._declare(session)
            if self._last is not None:
                with contextlib.suppress(zenoh.ZError):
                    self._pub.put(self._last)

    def wait_for_subscribers(self, timeout_s: float) -> bool:
        """Block until some subscriber matches this key (True) or `timeout_s` passes (False).

        Puts made before any subscriber matches are lost; use this where the first sample
        matters. Not available with `latest=True`, whose late joiners get the cached value.
        """
        if self._matched is None:
            raise TransportError(f"publisher on {self.key!r}: wait_for_subscribers needs "
                                 "latest=False (late joiners of a latest publisher get its cache)")
        return self._matched.wait(timeout_s)

    def put(self, payload: bytes) -> None:
        with self._lock:
            if self._closed:
                raise TransportError(f"publisher on {self.key!r} is closed")
            try:
                self._pub.put(payload)
            except zenoh.ZError as exc:  # e.g. its session was closed
                raise TransportError(f"put on {self.key!r} failed: {exc}") from None
            if self._latest:
                self._last = payload

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            if self._listener is not None:
                undeclare(self._listener)
            undeclare(self._pub)


def declare_publisher(session: zenoh.Session, key: str, *, latest: bool = False,
                      block: bool = False) -> Publisher:
    """A publisher on `key`. `latest=True`: late joiners subscribed with `latest=True` get the
    last put at once (Weights, ClusterModel). `block=True`: a put waits when Zenoh's queues are
    full instead of dropping the sample (streams where every sample matters)."""
    return Publisher(session, key, latest=latest, block=block)


class Subscription:
    """Samples from a channel handler, dispatched on our own daemon thread; `close()`
    undeclares and joins it. Exceptions from the callback are logged and skipped.

    `declare(session)` makes the Zenoh entity (a subscriber with a channel handler); it is
    called again by `rebind` on a reopened session."""

    def __init__(self, session: zenoh.Session, declare: Callable[[zenoh.Session], Any],
                 dispatch: Callable[[zenoh.Sample], None], *, name: str) -> None:
        self.name = name
        self._declare = declare
        self._dispatch = dispatch
        self._lock = threading.Lock()
        self._closing = threading.Event()
        self._threads: list[threading.Thread] = []
        self._entity = self._start(session)

    def _start(self, session: zenoh.Session) -> Any:
        entity = self._declare(session)
        thread = threading.Thread(target=self._run, args=(entity.handler,),
                                  name=f"hercs-sub-{self.name}", daemon=True)
        thread.start()
        self._threads.append(thread)
        return entity

    def rebind(self, session: zenoh.Session) -> None:
        """Receive from `session` instead (a reopened session): the old entity goes first (its
        thread ends), then the new one is declared."""
        with self._lock:
            if self._closing.is_set():
                return
            undeclare(self._entity)  # its thread ends; nothing arrives twice
            self._entity = self._start(session)

    def _run(self, channel: Any) -> None:
        for sample in received(channel):
            if self._closing.is_set():
                return
            try:
                self._dispatch(sample)
            except Exception:
                log.exception("callback for %r raised; skipping that sample", self.name)

    def close(self) -> None:
        with self._lock:
            if self._closing.is_set():
                return
            self._closing.set()
            undeclare(self._entity)
        join_threads(self._threads)


def _channel(capacity: int, drop_oldest: bool) -> Any:
    if capacity < 1:
        raise ValueError(f"capacity: got {capacity}, must be >= 1")
    return (zenoh.handlers.RingChannel(capacity) if drop_oldest
            else zenoh.handlers.FifoChannel(capacity))


def subscribe(
    session: zenoh.Session,
    key: str,
    on_sample: Callable[[str, bytes], None],
    *,
    latest: bool = False,
    capacity: int = 256,
    drop_oldest: bool = False,
) -> Subscription:
    """Call `on_sample(key, payload)` for every put on `key` (wildcards allowed), on our thread.

    `latest=True`: also receive, at once, the last value cached by each `latest` publisher
    (late joiner); an older value still in flight may come first, so ignore stale versions.
    `drop_oldest=True`: when `capacity` samples wait, the oldest is dropped instead of
    stalling the session (for "only the newest matters" streams).
    """
    _channel(capacity, drop_oldest)  # checks capacity now, not at the first declare

    def declare(session: zenoh.Session) -> Any:
        channel = _channel(capacity, drop_oldest)
        if latest:
            return zext.declare_advanced_subscriber(
                session, key, channel,
                history=zext.HistoryConfig(detect_late_publishers=True, max_samples=1),
            )
        return session.declare_subscriber(key, channel)

    def dispatch(sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            on_sample(str(sample.key_expr), sample.payload.to_bytes())

    return Subscription(session, declare, dispatch, name=key)


# --------------------------------------------------------------------------- liveliness


class AliveToken:
    """A liveliness token; it vanishes when `close()`d, the session closes or the process dies."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.key = key
        self._lock = threading.Lock()
        self._closed = False
        self._token = session.liveliness().declare_token(key)

    def suspend(self) -> None:
        """Withdraw the token before its session is replaced (`rebind` declares it again):
        the withdrawal travels on the old link well before the new session exists."""
        with self._lock:
            undeclare(self._token)

    def rebind(self, session: zenoh.Session) -> None:
        """Declare the token on `session` instead (a reopened session)."""
        with self._lock:
            if self._closed:
                return
            undeclare(self._token)  # a no-op after `suspend`
            self._token = session.liveliness().declare_token(self.key)

    def close(self) -> None:
        with self._lock:
            self._closed = True
            undeclare(self._token)


def declare_alive(session: zenoh.Session, key: str) -> AliveToken:
    """Announce this process as alive under `key` (e.g. `hercs/<run>/alive/<role>/<id>`)."""
    return AliveToken(session, key)


def watch_alive(session: zenoh.Session, key_expr: str,
                on_change: Callable[[str, bool], None]) -> Subscription:
    """Call `on_change(key, alive)` when a token matching `key_expr` (e.g. `…/alive/**`)
    appears (True) or disappears (False); tokens present already are reported at once."""
    def declare(session: zenoh.Session) -> Any:
        return session.liveliness().declare_subscriber(
            key_expr, zenoh.handlers.FifoChannel(256), history=True
        )

    def dispatch(sample: zenoh.Sample) -> None:
        on_change(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)

    return Subscription(session, declare, dispatch, name=key_expr)


def alive_keys(session: zenoh.Session, key_expr: str, *, timeout_s: float = 2.0) -> list[str]:
    """The keys of the liveliness tokens matching `key_expr` that the router knows now (a
    snapshot for messages to people, e.g. which runs exist; watchers use `watch_alive`)."""
    keys: set[str] = set()
    try:
        for reply in session.liveliness().get(key_expr, timeout=timeout_s):
            if reply.ok is not None:
                keys.add(str(reply.ok.key_expr))
    except zenoh.ZError as exc:  # the session closed meanwhile: report what was seen
        log.debug("liveliness get on %r ended: %s", key_expr, exc)
    return sorted(keys)
