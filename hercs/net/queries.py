"""Zenoh queries as hercs uses them: queryables answered at once or later (`PendingReply`, the
deferred replies behind the replay's backpressure) and requests that wait for a queryable to
appear. Error replies carry a `hercs.reasons.Reason` and a detail; hercs.net.transport owns the
sessions these run on."""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any, Literal, TypedDict, Unpack

import zenoh

from hercs.errors import InvalidMessage
from hercs.net.transport_errors import RemoteError, TransportError, TransportTimeout
from hercs.reasons import Reason

log = logging.getLogger("hercs.net.transport")

ERROR_ENCODING = "text/plain;hercs-error"
"""Encoding of every hercs error reply; its payload is UTF-8 `"<reason>: <detail>"`."""
_JOIN_TIMEOUT_S = 5.0
_RETRY_PAUSE_FIRST_S = 0.01
_RETRY_PAUSE_MAX_S = 0.5
_LAST_GET_S = 0.05
"""The pauses between gets to a queryable that is matched but did not answer (`request`), and
the least time left for which such a get is sent again."""


class PendingReply:
    """One received query, to be answered exactly once, from any thread, now or later.

    `reply`/`reply_error` return True if this call answered, False if it was already answered
    (so a rate limiter and a shutdown may race harmlessly). Answering finalises the Zenoh query,
    which ends the caller's get at once.
    """

    __slots__ = ("_done", "_key", "_lock", "_on_done", "_query", "payload")

    def __init__(self, query: zenoh.Query, reply_key: str,
                 on_done: Callable[[PendingReply], None]) -> None:
        self._query: zenoh.Query | None = query
        self._key = reply_key
        self._lock = threading.Lock()
        self._done = False
        self._on_done = on_done
        raw = query.payload
        self.payload: bytes = raw.to_bytes() if raw is not None else b""
        """The request payload (empty if the query carried none)."""

    @property
    def answered(self) -> bool:
        return self._done

    def reply(self, payload: bytes) -> bool:
        """Answer with `payload`."""
        return self._answer(lambda q: q.reply(self._key, payload))

    def reply_error(self, reason: Reason, detail: str) -> bool:
        """Answer with an error the caller receives as `RemoteError(reason, detail)`."""
        if ": " in reason:
            raise ValueError(f"reason: got {reason!r}, must not contain ': '")
        text = f"{reason}: {detail}".encode()
        return self._answer(lambda q: q.reply_err(text, encoding=ERROR_ENCODING))

    def _answer(self, send: Callable[[zenoh.Query], None]) -> bool:
        with self._lock:
            if self._done:
                return False
            self._done = True
            query, self._query = self._query, None
            assert query is not None, "a query is held until its one answer"
            try:
                send(query)
            except Exception as exc:  # the session closed meanwhile, or a payload of bad type
                log.warning("could not answer a query on %r: %s", self._key, exc)
                with contextlib.suppress(Exception):  # never leave the caller without an answer
                    query.reply_err(f"{Reason.INTERNAL}: reply not sent ({exc})".encode(),
                                    encoding=ERROR_ENCODING)
            finally:
                with contextlib.suppress(zenoh.ZError):
                    query.drop()
        self._on_done(self)
        return True


def _report(on_error: Callable[[Exception], None] | None, key: str, exc: Exception) -> None:
    if not isinstance(exc, InvalidMessage):
        log.error("handler for %r raised; replying %r", key, Reason.INTERNAL, exc_info=exc)
    if on_error is None:
        if isinstance(exc, InvalidMessage):
            log.warning("rejected a request on %r: %s", key, exc)
        return
    try:
        on_error(exc)
    except Exception:
        log.exception("on_error for %r raised; carrying on", key)


class QueryServer:
    """A queryable served by our own worker threads; `close()` undeclares it.

    Each received query becomes a `PendingReply` given to `handler`. If the handler raises
    `InvalidMessage` the query is answered with its reason and detail; any other exception is
    logged and answered with reason `internal`; both are passed to `on_error` (which the
    service uses to count rejects by reason). A handler that returns without answering has
    parked the query: it must answer it later. Queries still unanswered at `close()` are
    answered with reason `unavailable`.
    """

    def __init__(
        self,
        session: zenoh.Session,
        key: str,
        handler: Callable[[PendingReply], None],
        *,
        on_error: Callable[[Exception], None] | None = None,
        workers: int = 1,
        capacity: int = 256,
    ) -> None:
        if workers < 1:
            raise ValueError(f"workers: got {workers}, must be >= 1")
        if capacity < 1:
            raise ValueError(f"capacity: got {capacity}, must be >= 1")
        self.key = key
        self._handler = handler
        self._on_error = on_error
        self._reply_key_fixed = "*" not in key
        self._lock = threading.Lock()
        self._pending: set[PendingReply] = set()
        self._closing = threading.Event()
        self._capacity = capacity
        self._workers = workers
        self._threads: list[threading.Thread] = []
        self._queryable = self._declare(session)

    def _declare(self, session: zenoh.Session) -> Any:
        """Declare the queryable on `session` and start its workers (they end when it is
        undeclared or its session closes)."""
        queryable = session.declare_queryable(
            self.key, zenoh.handlers.FifoChannel(self._capacity), complete=True
        )
        channel = queryable.handler
        threads = [
            threading.Thread(target=self._run, args=(channel,), daemon=True,
                             name=f"hercs-query-{self.key}-{i}")
            for i in range(self._workers)
        ]
        for thread in threads:
            thread.start()
        self._threads.extend(threads)
        return queryable

    def rebind(self, session: zenoh.Session) -> None:
        """Serve the same key on `session` instead (a reopened session): the new queryable is
        declared before the old one goes. Queries parked on the old session are answered as
        before, for as long as that session is open."""
        with self._lock:
            if self._closing.is_set():
                return
            old, self._queryable = self._queryable, self._declare(session)
        undeclare(old)

    @property
    def pending(self) -> int:
        """Queries received and not yet answered (parked ones included)."""
        with self._lock:
            return len(self._pending)

    def _forget(self, pending: PendingReply) -> None:
        with self._lock:
            self._pending.discard(pending)

    def _run(self, channel: Any) -> None:
        for query in received(channel):
            reply_key = self.key if self._reply_key_fixed else str(query.key_expr)
            pending = PendingReply(query, reply_key, self._forget)
            del query
            with self._lock:
                closing = self._closing.is_set()
                if not closing:
                    self._pending.add(pending)
            if closing:
                pending.reply_error(Reason.UNAVAILABLE, f"{self.key} is shutting down")
                continue
            try:
                self._handler(pending)
            except InvalidMessage as exc:  # counted before the caller hears of it
                _report(self._on_error, self.key, exc)
                pending.reply_error(exc.reason, exc.detail)
            except Exception as exc:
                _report(self._on_error, self.key, exc)
                pending.reply_error(Reason.INTERNAL, f"{type(exc).__name__}: {exc}")

    def close(self) -> None:
        """Stop taking queries, answer parked ones `unavailable`, join the workers."""
        with self._lock:
            if self._closing.is_set():
                return
            self._closing.set()
            parked = list(self._pending)
            queryable = self._queryable
        undeclare(queryable)
        for pending in parked:
            pending.reply_error(Reason.UNAVAILABLE, f"{self.key} closed before answering")
        join_threads(self._threads)


class ServeOptions(TypedDict, total=False):
    """QueryServer's keyword options, typed once for the two `serve_*` helpers."""

    on_error: Callable[[Exception], None] | None
    workers: int
    capacity: int


def serve_deferred(
    session: zenoh.Session, key: str, handler: Callable[[PendingReply], None],
    **options: Unpack[ServeOptions],
) -> QueryServer:
    """Give each query on `key` to `handler` as a `PendingReply`, which it answers now or parks
    and answers later from any thread (the rate limiter's backpressure). Raising
    `InvalidMessage` before answering sends an error reply. `options`: QueryServer's
    (on_error, workers, capacity)."""
    return QueryServer(session, key, handler, **options)


def serve_queryable(
    session: zenoh.Session, key: str, handler: Callable[[bytes], bytes],
    **options: Unpack[ServeOptions],
) -> QueryServer:
    """Answer each query on `key` with `handler(payload)`, run on our own worker thread(s);
    `options` as serve_deferred's.

    `handler` returns the reply payload or raises `InvalidMessage` (→ error reply with its
    reason). It should be quick: queries wait in a channel of `capacity`, and a full channel
    stalls the whole session. To hold a query and answer later use `serve_deferred`.
    """

    def answer_now(pending: PendingReply) -> None:
        pending.reply(handler(pending.payload))

    return serve_deferred(session, key, answer_now, **options)


def request(session: zenoh.Session, key: str, payload: bytes, *, timeout_s: float) -> bytes:
    """Send `payload` to the one queryable on `key` and return its reply; blocks up to
    `timeout_s`, waiting for a queryable to appear if none is there yet.

    Raises `RemoteError` on an error reply and `TransportTimeout` when nothing answers in
    time; closing the session ends a waiting request with `TransportError`. Thread-safe: many
    threads may request on one session.
    """
    if timeout_s <= 0:
        raise ValueError(f"timeout_s: got {timeout_s}, must be > 0")
    deadline = time.monotonic() + timeout_s
    # A get that ends at once with no reply found no queryable able to answer. Either none is
    # declared yet (one still starting, or declared a moment ago and not yet propagated): wait
    # for a match, then ask again. Or one is matched but did not answer: a server killed a
    # moment ago whose declaration the router still holds, or one that drops queries. Then ask
    # again after a pause that doubles up to _RETRY_PAUSE_MAX_S, so a restarting server is
    # found once it serves, a silent one cannot make us spin, and the request still waits its
    # whole timeout (three quick empty gets once gave up in milliseconds, "within 30 s").
    pause = 0.0
    silent = False  # a queryable matched and let a get end unanswered
    while True:
        try:
            reply = _get_one(session, key, payload, deadline=deadline, timeout_s=timeout_s)
        except TransportTimeout as exc:
            if not silent or exc.no_queryable:
                raise
            # the last get to a queryable that never answered ran into the deadline before
            # its empty answer came (a loaded machine: later than _LAST_GET_S): still silent
            raise TransportTimeout(key, timeout_s, "no queryable answered",
                                   no_queryable=True) from None
        if reply is not None:
            return reply
        if session.is_closed():
            raise TransportError(f"request to {key!r}: the session closed while it waited")
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise TransportTimeout(key, timeout_s, "no queryable answered", no_queryable=True)
        log.debug("no queryable on %r answered; waiting up to %.1f s for one", key, remaining)
        found = _wait_for_queryable(session, key, remaining)
        if found is None:
            raise TransportTimeout(key, timeout_s, "no queryable appeared", no_queryable=True)
        if found == "appeared":  # a new queryable: ask it at once
            pause, silent = 0.0, False
        else:
            silent = True
            remaining = deadline - time.monotonic()
            if remaining < _LAST_GET_S:
                # a get this short may end in Zenoh's own timeout before the silent
                # queryable's empty answer, and be reported as "no reply"
                time.sleep(max(remaining, 0.0))
                raise TransportTimeout(key, timeout_s, "no queryable answered",
                                       no_queryable=True)
            time.sleep(min(pause, remaining - _LAST_GET_S))
        pause = min(max(2 * pause, _RETRY_PAUSE_FIRST_S), _RETRY_PAUSE_MAX_S)


def _get_one(session: zenoh.Session, key: str, payload: bytes, *, deadline: float,
             timeout_s: float) -> bytes | None:
    """One get on `key`: the first ok reply's payload, None if the get ended with no reply;
    raises `RemoteError` on an error reply and `TransportTimeout` if the queryable that got
    it held it past `deadline`."""
    replies = session.get(
        key,
        payload=payload,
        timeout=max(deadline - time.monotonic(), 0.001),
        target=zenoh.QueryTarget.BEST_MATCHING,
        consolidation=zenoh.ConsolidationMode.NONE,
    )
    for reply in replies:
        ok = reply.ok
        if ok is not None:
            return ok.payload.to_bytes()
        err = reply.err
        if err is None:  # a reply is either ok or err
            continue
        text = err.payload.to_bytes().decode("utf-8", errors="replace")
        if str(err.encoding) == ERROR_ENCODING:
            reason, _, detail = text.partition(": ")
            raise RemoteError(key, reason, detail)
        if text == "Timeout":
            raise TransportTimeout(key, timeout_s, "no reply")
        raise RemoteError(key, Reason.TRANSPORT, text)
    return None


def _wait_for_queryable(session: zenoh.Session, key: str,
                        timeout_s: float) -> Literal["known", "appeared"] | None:
    """Whether a complete queryable matching `key` is known to this session: "known" at
    once, "appeared" within `timeout_s`, else None."""
    matched = threading.Event()
    querier = session.declare_querier(key, target=zenoh.QueryTarget.BEST_MATCHING)
    try:
        listener = querier.declare_matching_listener(
            lambda status: matched.set() if status.matching else None  # only flips an Event
        )
        try:
            # zenoh's stub types matching_status as bool; it is a MatchingStatus at run time
            if querier.matching_status.matching:  # type: ignore[attr-defined]
                return "known"
            return "appeared" if matched.wait(timeout_s) else None
        finally:
            undeclare(listener)
    finally:
        undeclare(querier)


def received(channel: Any) -> Iterator[Any]:
    """What arrives on a Zenoh handler channel, until the channel closes (its entity undeclared
    or its session closed). The item is yielded, never kept here: a query must be dropped by
    its consumer for Zenoh to send its final reply."""
    while True:
        try:
            yield channel.recv()
        except zenoh.ZError:
            return


def undeclare(entity: Any) -> None:
    """Undeclare; a no-op if the session is closed already."""
    with contextlib.suppress(zenoh.ZError):
        entity.undeclare()


def join_threads(threads: Sequence[threading.Thread]) -> None:
    me = threading.current_thread()
    for thread in threads:
        if thread is me:
            continue
        thread.join(_JOIN_TIMEOUT_S)
        if thread.is_alive():
            log.warning("thread %s did not stop within %.0f s (a handler is stuck); leaving "
                        "it behind as a daemon", thread.name, _JOIN_TIMEOUT_S)
