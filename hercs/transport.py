"""The one Zenoh layer every hercs process uses (docs/DESIGN.md §3).

Services never touch zenoh config.

What it guarantees, and the Zenoh 1.x facts it rests on (verified on eclipse-zenoh 1.10.2):

- **Sessions** (`open_session`) have multicast scouting off and explicit endpoints only. A
  client (or peer) with `connect` endpoints blocks until a router answers: Zenoh retries inside
  one bounded window (`connect/timeout_ms`, retry from 100 ms doubling to 1 s) and we loop over
  windows with a log line, so Ctrl-C is seen between windows and `connect_timeout_s` can bound
  the wait. The window also bounds one handshake (TCP, TLS, Zenoh's open: about four round
  trips), which Zenoh abandons when the window ends: the windows double from 1 s to 4 s, so
  that a router across a slow link is reached too (bench.net_faults measured it: with 1 s
  windows a TLS client never joined across 200 ms of one-way delay). Once connected, a client
  reconnects by itself (and redeclares its entities) if the router restarts or the link is
  cut for longer than Zenoh's 10 s lease (tests/fault/test_network_faults.py). Timestamping
  is on (AdvancedPublisher refuses to start without it); the 500 ms scouting delay is off (it
  only serves multicast scouting).
- **Never block inside Zenoh.** Every queryable and subscriber uses a channel handler and is
  drained by our own daemon thread(s). The threads read the channel object (`entity.handler`),
  never `entity.recv()`: calling `undeclare()` while another thread sits in
  `Queryable.recv()` raises "Already borrowed" and can abort the interpreter. Undeclaring (or
  closing the session) closes the channel, and `recv()` then raises `ZError`: that is how the
  threads stop, at once, without polling. A full FifoChannel blocks Zenoh's receive path for
  the whole session, so handlers must be quick or defer (below).
- **Declared entities live only as long as their Python object** (dropping a channel-handled
  queryable or subscriber undeclares it); the handles below keep them referenced.
- **Queries are answered exactly once, possibly later and from any thread** (`PendingReply`).
  A `Query` may be replied to after its handler returned, from another thread; the querier's
  `get` ends only when the query is *finalised*, which needs an explicit `Query.drop()` (or its
  context manager): Python finalisers are not prompt, and a parked-but-dropped-late query makes
  the client wait for its full timeout. `PendingReply` replies then drops.
- **Exactly one queryable answers a request.** Queryables are declared `complete=True` and
  `request` uses target BEST_MATCHING: with several complete queryables on a key a remote
  client's query reaches only one of them (with non-complete ones, or target ALL, every one
  answers). Consolidation NONE hands each reply over as it arrives; the default (AUTO)
  holds replies until the query is finalised.
- **Declarations propagate asynchronously.** A get sent just after a queryable was declared
  elsewhere can find no match and end at once with no reply; `request` then waits for a match
  (a querier's matching listener) and asks again, within its timeout. Likewise a put sent
  before the router knows a subscriber is lost: `Publisher.wait_for_subscribers` waits for a
  match (note `matching_status` returns a `MatchingStatus` object, always truthy: read
  `.matching`). A liveliness *get* can briefly miss a token its watcher already reported, so
  we offer only the watcher (`watch_alive`), which with history is a snapshot plus changes.
- **Error replies** are `query.reply_err` with encoding `text/plain;hercs-error` and payload
  UTF-8 `"<reason>: <detail>"` (the reason never contains ": "). `request` turns them into
  `RemoteError(reason, detail)`. Zenoh's own timeout arrives as an error reply `b"Timeout"`
  (encoding `zenoh/string`) and becomes `TransportTimeout`.
- **Latest value for late joiners** (`publisher(..., latest=True)` + `subscribe(...,
  latest=True)`) is `zenoh.ext` AdvancedPublisher (cache 1, publisher detection) and
  AdvancedSubscriber (history of 1, late-publisher detection): a subscriber declared after the
  puts gets the last one at once, and one declared before the publisher gets its cache when it
  appears. Samples from one publisher arrive in order, duplicates removed. A put is
  asynchronous, so a subscriber joining right after it may get an older value still in
  flight before the cached one: payloads carry a version and consumers ignore older ones.
- **Liveliness**: a token disappears (DELETE) as soon as its session closes or its process
  dies (the router sees the TCP link drop); a watcher declared with history also sees the
  tokens that were already there.
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Literal

import zenoh
import zenoh.ext as zext

from hercs.errors import ConfigError
from hercs.queries import (
    PendingReply,
    QueryServer,
    join_threads,
    request,
    serve_deferred,
    serve_queryable,
    undeclare,
)
from hercs.rediscovery import Rediscovery
from hercs.transport_errors import (
    ConnectAborted,
    RemoteError,
    RouterUnreachable,
    TransportError,
    TransportTimeout,
)

__all__ = [
    "ConnectAborted", "PendingReply", "Publisher", "QueryServer", "RemoteError",
    "RouterUnreachable", "Subscription", "Transport", "TransportError", "TransportTimeout",
    "open_session",
]
"""Errors (hercs.transport_errors) and queries (hercs.queries) are importable from here too:
a service needs this one module."""

log = logging.getLogger(__name__)

Mode = Literal["router", "peer", "client"]

_CONNECT_WINDOW_S = 1.0
_CONNECT_WINDOW_MAX_S = 4.0
_CONNECT_RETRY = {"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 2}
_WAIT_LOG_EVERY_S = 10.0

_log_init_lock = threading.Lock()
_log_initialised = False


# --------------------------------------------------------------------------- sessions


def _init_zenoh_log() -> None:
    """Zenoh logs errors only, unless RUST_LOG says otherwise; once per process."""
    global _log_initialised
    with _log_init_lock:
        if not _log_initialised:
            zenoh.init_log_from_env_or("error")
            _log_initialised = True


def _zenoh_config(mode: Mode, connect: Sequence[str], listen: Sequence[str],
                  *, connect_window_ms: int, extra: Mapping[str, Any]) -> zenoh.Config:
    config = zenoh.Config()
    settings: dict[str, Any] = {
        "mode": mode,
        "scouting/multicast/enabled": False,
        "scouting/delay": 0,
        "timestamping/enabled": True,
        "connect/endpoints": list(connect),
        "listen/endpoints": list(listen),
        "connect/retry": _CONNECT_RETRY,
        # Zenoh's shared-memory transport gives every local sender of messages over 3 KiB a
        # 16 MiB pool that the receiver keeps mapped after the sender is gone: a replay whose
        # actors restart would grow without bound (measured by bench.throughput). Loopback
        # TCP is fast enough for our messages.
        "transport/shared_memory/enabled": False,
    }
    if mode == "router":
        # A router never waits for the routers it connects to: it retries them in the background.
        settings["connect/timeout_ms"] = 0
        settings["connect/exit_on_failure"] = False
    else:
        settings["connect/timeout_ms"] = connect_window_ms
        settings["connect/exit_on_failure"] = True
    settings.update(extra)  # security: TLS, credentials, access control (hercs.security)
    for key, value in settings.items():
        try:
            config.insert_json5(key, json.dumps(value))
        except zenoh.ZError as exc:
            shown = "***" if "password" in key else value
            raise ConfigError(f"transport: zenoh refused {key}={shown!r} ({exc})") from None
    return config


def open_session(
    *,
    mode: Mode,
    connect: Sequence[str] = (),
    listen: Sequence[str] = (),
    connect_timeout_s: float | None = None,
    stop: threading.Event | None = None,
    settings: Mapping[str, Any] | None = None,
) -> zenoh.Session:
    """Open a Zenoh session with multicast scouting off and only the given endpoints.

    A router must listen; a client must connect (else `ConfigError`, as for an endpoint Zenoh
    cannot parse). A client or peer with `connect` endpoints
    blocks until one of them answers, logging while it waits; `connect_timeout_s=None` waits
    forever, otherwise `TransportError` after that long. A router starts at once (it retries
    its `connect` endpoints in the background) and fails if it cannot listen.
    """
    if mode not in ("router", "peer", "client"):
        raise ConfigError(f"transport mode: got {mode!r}, must be 'router', 'peer' or 'client'")
    if mode == "router" and not listen:
        raise ConfigError("transport.listen: got [], a router needs at least one endpoint")
    if mode == "client" and not connect:
        raise ConfigError("transport.connect: got [], a client needs at least one endpoint")
    _init_zenoh_log()
    extra = dict(settings or {})
    secured = any(k.startswith(("transport/link/tls", "transport/auth")) for k in extra)
    hint = ("; this client's certificate or credentials may be refused (see docs/SECURITY.md)"
            if secured else "; a router that requires TLS or credentials refuses clients "
            "without them (see docs/SECURITY.md)")
    if mode == "router" or not connect:
        config = _zenoh_config(mode, connect, listen, connect_window_ms=0, extra=extra)
        try:
            return zenoh.open(config)
        except zenoh.ZError as exc:
            raise TransportError(f"cannot open a Zenoh {mode} listening on {list(listen)}: "
                                 f"{exc}") from None

    start = time.monotonic()
    next_log = start
    next_window = _CONNECT_WINDOW_S
    while True:
        window = next_window
        next_window = min(2 * next_window, _CONNECT_WINDOW_MAX_S)
        if connect_timeout_s is not None:
            window = min(window, max(connect_timeout_s - (time.monotonic() - start), 0.001))
        config = _zenoh_config(mode, connect, listen,
                               connect_window_ms=max(int(window * 1000), 1), extra=extra)
        attempt = time.monotonic()
        try:
            session = zenoh.open(config)
        except zenoh.ZError as exc:
            now = time.monotonic()
            waited = now - start
            if connect_timeout_s is not None and waited >= connect_timeout_s:
                raise RouterUnreachable(
                    f"no Zenoh router reachable at {list(connect)} after {waited:.1f} s "
                    f"(last error: {exc}); is `hercs up` or `hercs router` running, and is "
                    f"the endpoint (host, port, tcp/tls) the one it listens on{hint}?"
                ) from None
            if now >= next_log:
                log.info("waiting for a Zenoh router at %s (%.0f s so far); retrying until "
                         "it is up%s", list(connect), waited, hint)
                next_log = now + _WAIT_LOG_EVERY_S
            # An attempt that failed early (e.g. a name that does not resolve) must not spin;
            # a stop request (SIGTERM while waiting for the router) ends the wait at once.
            pause = max(0.0, window - (now - attempt))
            if stop is not None and (stop.is_set() or stop.wait(pause)):
                raise ConnectAborted(f"stopped while waiting for a Zenoh router at "
                                     f"{list(connect)}") from None
            if stop is None:
                time.sleep(pause)
            continue
        if time.monotonic() - start > _CONNECT_WINDOW_S:
            log.info("connected to Zenoh at %s after %.1f s", list(connect),
                     time.monotonic() - start)
        return session


# --------------------------------------------------------------------------- pub/sub


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
        while True:
            try:
                sample = channel.recv()
            except zenoh.ZError:  # channel closed: undeclared or session closed
                return
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


# --------------------------------------------------------------------------- the owner


REDISCOVER_S = 20.0
"""A client session whose requests on a key answered before have found no queryable for this
long, while it had a router, is reopened (`hercs.rediscovery`); 0 turns it off."""
REDISCOVER_MAX_S = 160.0
"""The longest wait between two reopens of one streak (the waits double up to it)."""


class Transport:
    """One process's Zenoh session and everything declared through it.

    The methods are the module functions bound to this session; every handle they return is
    also closed by `close()` (servers first, so parked queries get `unavailable`, then
    subscriptions, publishers and tokens, then the session). Use it as a context manager.

    A client transport reopens its session when it has gone blind (`hercs.rediscovery`: a
    key answered before finds no queryable for `rediscover_s` although the session has a
    router): a new session is opened (waiting for the router as `open` does), every handle is
    declared again on it, and the old one is closed. Handles stay valid throughout; requests
    in flight on the old session end with `TransportError` (callers retry them).
    """

    def __init__(self, session: zenoh.Session, *,
                 reopen: Callable[[], zenoh.Session] | None = None,
                 rediscover_s: float = 0.0) -> None:
        self.session = session
        self._lock = threading.Lock()
        self._owned: list[Any] = []
        self._closed = False
        self._reopen_session = reopen
        self._reopen_lock = threading.Lock()
        self._rediscovery_lock = threading.Lock()
        self._rediscovery = (Rediscovery(after_s=rediscover_s,
                                         max_after_s=max(REDISCOVER_MAX_S, rediscover_s))
                             if reopen is not None and rediscover_s > 0 else None)
        self.reopens = 0
        """Times this transport reopened its session."""
        self._generation = 0

    @classmethod
    def open(cls, *, mode: Mode, connect: Sequence[str] = (), listen: Sequence[str] = (),
             connect_timeout_s: float | None = None,
             stop: threading.Event | None = None,
             settings: Mapping[str, Any] | None = None,
             rediscover_s: float = REDISCOVER_S) -> Transport:
        """`settings`: extra Zenoh config entries (`hercs.security.zenoh_settings`).
        `rediscover_s`: see the class (clients with `connect` endpoints only; 0: never)."""
        def opener() -> zenoh.Session:
            return open_session(mode=mode, connect=connect, listen=listen,
                                connect_timeout_s=connect_timeout_s, stop=stop,
                                settings=settings)

        reopen = opener if mode != "router" and connect else None
        return cls(opener(), reopen=reopen, rediscover_s=rediscover_s)

    def _own(self, declare: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        with self._lock:
            if self._closed:
                raise TransportError(f"transport is closed; cannot {declare.__name__} {args[0]!r}")
            handle = declare(self.session, *args, **kwargs)
            self._owned.append(handle)
        return handle

    def serve(self, key: str, handler: Callable[[bytes], bytes], **kwargs: Any) -> QueryServer:
        return self._own(serve_queryable, key, handler, **kwargs)

    def serve_deferred(self, key: str, handler: Callable[[PendingReply], None],
                       **kwargs: Any) -> QueryServer:
        return self._own(serve_deferred, key, handler, **kwargs)

    def request(self, key: str, payload: bytes, *, timeout_s: float) -> bytes:
        generation, asked_at = self._generation, time.monotonic()
        try:
            reply = request(self.session, key, payload, timeout_s=timeout_s)
        except RemoteError:
            self._answered(key)
            raise
        except TransportTimeout as exc:
            if exc.no_queryable and self._blind(key, asked_at=asked_at):
                assert self._rediscovery is not None
                self.reopen(f"no queryable on {key!r} for {self._rediscovery.streak_s:.0f} s "
                            "although it answered before and the session has a router",
                            generation=generation)
            raise
        except zenoh.ZError as exc:  # the session was swapped and closed under this request
            raise TransportError(f"request to {key!r}: {exc}; the caller may retry") from None
        self._answered(key)
        return reply

    def _answered(self, key: str) -> None:
        if self._rediscovery is not None:
            with self._rediscovery_lock:
                self._rediscovery.answered(key)

    def _blind(self, key: str, *, asked_at: float) -> bool:
        """Whether a request on `key` that found no queryable calls for a reopen now."""
        if self._rediscovery is None or self._closed:
            return False
        try:
            has_router = any(True for _ in self.session.info.routers_zid())
        except zenoh.ZError:  # closed meanwhile
            return False
        if not has_router:  # cut off: Zenoh reconnects by itself, and a reopen would wait too
            return False
        with self._rediscovery_lock:
            return self._rediscovery.missing(key, asked_at=asked_at)

    def reopen(self, why: str, *, generation: int | None = None) -> None:
        """Open a new session, declare every handle on it, close the old one.

        Blocks until the router answers (as `open` does; `ConnectAborted` if the stop event is
        set meanwhile). `generation`: the `_generation` the caller saw; if the session was
        reopened since, nothing is done (two threads that went blind together reopen once).
        Liveliness tokens leave before the new session opens, so that watchers see the
        token go and come back, never the reverse; a subscription is undeclared on the old
        session before it is declared on the new one (samples in between are lost, as on
        any session loss, rather than delivered twice).
        """
        if self._reopen_session is None:
            raise TransportError("this transport cannot reopen its session (a router, or a "
                                 "session opened without connect endpoints)")
        with self._reopen_lock:
            if self._closed or (generation is not None and generation != self._generation):
                return
            log.warning("reopening this process's Zenoh session: %s", why)
            started = time.monotonic()
            with self._lock:
                owned = list(self._owned)
            for handle in owned:
                if isinstance(handle, AliveToken):
                    handle.suspend()
            new = self._reopen_session()
            with self._lock:
                if self._closed:
                    new.close()
                    return
                old, self.session = self.session, new
                owned = list(self._owned)
            failed = 0
            for handle in owned:
                try:
                    handle.rebind(new)
                except Exception:  # one handle must not keep the others on the old session
                    failed += 1
                    log.exception("could not declare %r again on the reopened session",
                                  getattr(handle, "key", getattr(handle, "name", handle)))
            try:
                old.close()
            except zenoh.ZError as exc:
                log.info("closing the old Zenoh session: %s", exc)
            self._generation += 1
            self.reopens += 1
            if self._rediscovery is not None:
                with self._rediscovery_lock:
                    self._rediscovery.reopened()
            log.warning("Zenoh session reopened in %.1f s; %d declarations renewed%s",
                        time.monotonic() - started, len(owned) - failed,
                        f", {failed} failed" if failed else "")

    def publisher(self, key: str, *, latest: bool = False, block: bool = False) -> Publisher:
        return self._own(declare_publisher, key, latest=latest, block=block)

    def subscribe(self, key: str, on_sample: Callable[[str, bytes], None],
                  **kwargs: Any) -> Subscription:
        return self._own(subscribe, key, on_sample, **kwargs)

    def declare_alive(self, key: str) -> AliveToken:
        return self._own(declare_alive, key)

    def watch_alive(self, key_expr: str, on_change: Callable[[str, bool], None]) -> Subscription:
        return self._own(watch_alive, key_expr, on_change)

    def alive_keys(self, key_expr: str, *, timeout_s: float = 2.0) -> list[str]:
        return alive_keys(self.session, key_expr, timeout_s=timeout_s)

    def close(self) -> None:
        """Undeclare everything, stop our threads and close the session; idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            owned, self._owned = self._owned, []
        order = (QueryServer, Subscription, Publisher, AliveToken)
        for kind in order:
            for handle in owned:
                if isinstance(handle, kind):
                    handle.close()
        try:
            self.session.close()
        except zenoh.ZError as exc:
            log.warning("closing the Zenoh session: %s", exc)

    def __enter__(self) -> Transport:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
