"""Opening a Zenoh session as every hercs process does (`open_session`): multicast scouting
off, explicit endpoints only, a client that waits for its router in bounded windows and can
be stopped between them (docs/ZENOH.md, "Sessions")."""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any, Literal

import zenoh

from hercs.errors import ConfigError
from hercs.net.transport_errors import (
    ConnectAborted,
    RouterUnreachable,
    TransportError,
)

log = logging.getLogger("hercs.net.transport")  # the Zenoh layer logs as one (as queries.py)

Mode = Literal["router", "peer", "client"]

_CONNECT_WINDOW_S = 1.0
_CONNECT_WINDOW_MAX_S = 4.0
_CONNECT_RETRY = {"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 2}
_WAIT_LOG_EVERY_S = 10.0

_log_init_lock = threading.Lock()
_log_initialised = False


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
        # actors restart would grow without bound (measured by bench.perf.throughput). Loopback
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
    settings.update(extra)  # security: TLS, credentials, access control (hercs.net.security)
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
