"""The one Zenoh layer every hercs process uses (docs/DESIGN.md §3): `Transport`, one process's
session and every handle declared through it, which reopens a client session gone blind
(`hercs.net.rediscovery`). Services never touch zenoh config. Sessions are opened by
`hercs.net.sessions`, publishers, subscriptions and liveliness by `hercs.net.pubsub`, queries by
`hercs.net.queries`; what the layer guarantees, and the Zenoh 1.x facts it rests on, are in
docs/ZENOH.md."""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import zenoh

from hercs.net.pubsub import (
    AliveToken,
    Publisher,
    Subscription,
    alive_keys,
    declare_alive,
    declare_publisher,
    subscribe,
    watch_alive,
)
from hercs.net.queries import (
    PendingReply,
    QueryServer,
    request,
    serve_deferred,
    serve_queryable,
)
from hercs.net.rediscovery import CutOff, Rediscovery
from hercs.net.sessions import Mode, open_session
from hercs.net.transport_errors import (
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
"""Errors (hercs.net.transport_errors) and queries (hercs.net.queries) are importable from here too:
a service needs this one module."""

log = logging.getLogger(__name__)


REDISCOVER_S = 20.0
"""A client session whose requests on a key answered before have found no queryable for this
long, while it had a router, is reopened (`hercs.net.rediscovery`); 0 turns it off."""
REDISCOVER_MAX_S = 160.0
"""The longest wait between two reopens of one streak (the waits double up to it)."""
CUT_OFF_S = 15.0
"""A client session whose requests have found no router for this long is reopened with a new
Zenoh id (`hercs.net.rediscovery.CutOff`); 0 turns it off."""


class Transport:
    """One process's Zenoh session and everything declared through it.

    The methods are the module functions bound to this session; every handle they return is
    also closed by `close()` (servers first, so parked queries get `unavailable`, then
    subscriptions, publishers and tokens, then the session). Use it as a context manager.

    A client transport reopens its session when it has gone blind or been cut off
    (`hercs.net.rediscovery`: a key answered before finds no queryable for `rediscover_s`
    although the session has a router; or requests have found no router for `cut_off_s`): a
    new session, with a new Zenoh id, is opened (waiting for the router as `open` does), every
    handle is declared again on it, and the old one is closed. The reopen runs in the request
    that called for it, which returns once the router answers or the stop event is set.
    Handles stay valid throughout; requests in flight on the old session end with
    `TransportError` (callers retry them).
    """

    def __init__(self, session: zenoh.Session, *,
                 reopen: Callable[[], zenoh.Session] | None = None,
                 rediscover_s: float = 0.0, cut_off_s: float = 0.0) -> None:
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
        self._cut_off = (CutOff(after_s=cut_off_s)
                         if reopen is not None and cut_off_s > 0 else None)
        self.reopens = 0
        """Times this transport reopened its session."""
        self._generation = 0

    @classmethod
    def open(cls, *, mode: Mode, connect: Sequence[str] = (), listen: Sequence[str] = (),
             connect_timeout_s: float | None = None,
             stop: threading.Event | None = None,
             settings: Mapping[str, Any] | None = None,
             rediscover_s: float = REDISCOVER_S,
             cut_off_s: float = CUT_OFF_S) -> Transport:
        """`settings`: extra Zenoh config entries (`hercs.net.security.zenoh_settings`).
        `rediscover_s`, `cut_off_s`: see the class (clients with `connect` endpoints only; 0:
        never)."""
        def opener() -> zenoh.Session:
            return open_session(mode=mode, connect=connect, listen=listen,
                                connect_timeout_s=connect_timeout_s, stop=stop,
                                settings=settings)

        reopen = opener if mode != "router" and connect else None
        return cls(opener(), reopen=reopen, rediscover_s=rediscover_s, cut_off_s=cut_off_s)

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
            why = self._why_reopen(key, asked_at=asked_at) if exc.no_queryable else None
            if why is not None:
                self.reopen(why, generation=generation)
            raise
        except zenoh.ZError as exc:  # the session was swapped and closed under this request
            raise TransportError(f"request to {key!r}: {exc}; the caller may retry") from None
        self._answered(key)
        return reply

    def _answered(self, key: str) -> None:
        with self._rediscovery_lock:
            if self._rediscovery is not None:
                self._rediscovery.answered(key)
            if self._cut_off is not None:
                self._cut_off.connected()

    def _why_reopen(self, key: str, *, asked_at: float) -> str | None:
        """Why a request on `key` sent at `asked_at` that found no queryable calls for a
        reopen now, or None."""
        if (self._rediscovery is None and self._cut_off is None) or self._closed:
            return None
        try:
            has_router = any(True for _ in self.session.info.routers_zid())
        except zenoh.ZError:  # closed meanwhile
            return None
        with self._rediscovery_lock:
            if not has_router:
                # Zenoh reconnects by itself, but after a long cut the router can hold that
                # reconnect for a minute (hercs.net.rediscovery.CutOff): a new id is not held
                if self._cut_off is None or not self._cut_off.no_router(asked_at=asked_at):
                    return None
                return (f"no router for {self._cut_off.streak_s:.0f} s (a cut longer than "
                        "Zenoh's lease); a new session is taken as soon as the link is back")
            if self._cut_off is not None:
                self._cut_off.connected()
            if self._rediscovery is None or not self._rediscovery.missing(key,
                                                                           asked_at=asked_at):
                return None
            return (f"no queryable on {key!r} for {self._rediscovery.streak_s:.0f} s although "
                    "it answered before and the session has a router")

    def reopen(self, why: str, *, generation: int | None = None) -> None:
        """Open a new session, declare every handle on it, close the old one.

        Blocks until the router answers (as `open` does; `ConnectAborted` if the stop event is
        set meanwhile, `RouterUnreachable` after `connect_timeout_s`: the old session and its
        tokens then stay). `generation`: the `_generation` the caller saw; if the session was
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
            tokens = [handle for handle in owned if isinstance(handle, AliveToken)]
            for token in tokens:
                token.suspend()
            try:
                new = self._reopen_session()
            except TransportError:
                # stopped, or the router not back within `connect_timeout_s`: the old session
                # stays and may still reconnect by itself, so its tokens must be there again
                for token in tokens:
                    with contextlib.suppress(zenoh.ZError):
                        token.rebind(self.session)
                raise
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
            with self._rediscovery_lock:
                if self._rediscovery is not None:
                    self._rediscovery.reopened()
                if self._cut_off is not None:
                    self._cut_off.connected()
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
