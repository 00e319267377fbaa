"""The Zenoh router every hercs run goes through: standalone (`hercs router`, the compose
`router` service) or embedded in `hercs up`'s launcher. It only routes: it holds no hercs
state, so services and actors may come and go (clients reconnect by themselves if it restarts).
"""

from __future__ import annotations

import logging
import socket
import sys
from collections.abc import Sequence

from hercs.config import HercsConfig, SecurityConfig, endpoint_parts
from hercs.errors import ConfigError
from hercs.net.security import listen_problem, zenoh_settings
from hercs.net.signals import StopSignals
from hercs.net.transport import Transport, TransportError
from hercs.proto.keys import ROOT

log = logging.getLogger(__name__)


class RouterListenError(TransportError):
    """The router could not listen on an endpoint; nothing was started."""


class PortInUse(RouterListenError):
    """An endpoint's port is taken by another process."""


FREE_PORT_TRIES = 5
"""How often `open_router_anywhere` picks new ports when a picked one was taken meanwhile."""


def free_port(host: str = "127.0.0.1", *, datagram: bool = False) -> int:
    """A port free on `host` now ("0.0.0.0": on every address; "::1" or "[::1]": IPv6): the
    kernel's choice for a socket bound to port 0, which is then closed, so another process
    may take it before the caller binds it. `datagram`: a UDP port (Zenoh's udp and quic).
    Raises OSError where `host` is not one of this host's addresses."""
    address = host.strip("[]")
    family = socket.AF_INET6 if ":" in address else socket.AF_INET
    with socket.socket(family, socket.SOCK_DGRAM if datagram else socket.SOCK_STREAM) as probe:
        probe.bind((address, 0))
        return int(probe.getsockname()[1])


def pick_free_ports(listen: Sequence[str]) -> list[str]:
    """`listen` with every port 0 replaced by a port that is free on that address now
    (`free_port`)."""
    out = []
    for endpoint in listen:
        proto, host, port = endpoint_parts(endpoint)
        if port != 0:
            out.append(endpoint)
            continue
        try:
            out.append(f"{proto}/{host}:{free_port(host, datagram=proto in ('udp', 'quic'))}")
        except OSError as exc:
            raise RouterListenError(f"cannot listen on {endpoint}: {exc.strerror} (is "
                                    f"{host} one of this host's addresses?)") from None
    return out


def open_router_anywhere(listen: Sequence[str], security: SecurityConfig | None = None
                         ) -> tuple[Transport, list[str]]:
    """`open_router` on `listen` where port 0 means "any free port": returns the router and
    the endpoints it listens on. A picked port that another process took between the pick
    and the bind is picked again (`FREE_PORT_TRIES` times); an explicit port that is taken
    fails at once (`PortInUse`)."""
    for attempt in range(FREE_PORT_TRIES):
        concrete = pick_free_ports(listen)
        try:
            return open_router(concrete, security), concrete
        except PortInUse:
            if concrete == list(listen) or attempt == FREE_PORT_TRIES - 1:
                raise
    raise AssertionError("unreachable")


def open_router(listen: Sequence[str],
                security: SecurityConfig | None = None) -> Transport:
    """A router-mode `Transport` listening on `listen`, authenticating clients and applying
    access control as `security` says (`hercs.net.security`).

    Raises `ConfigError` for a listen address other hosts can reach without TLS (unless
    `security.allow_insecure`) or unusable certificates, and `RouterListenError` with what to
    do next when an endpoint cannot be bound (most often: the port is taken by another
    `hercs up` or `hercs router`).
    """
    endpoints = list(listen)
    security = security or SecurityConfig()
    problem = listen_problem(security, endpoints)
    if problem is not None:
        raise ConfigError(problem)
    settings = zenoh_settings(security, mode="router", role=None, endpoints=endpoints)
    try:
        return Transport.open(mode="router", listen=endpoints, settings=settings)
    except TransportError as exc:
        text = str(exc)
        if "Address already in use" in text:
            raise PortInUse(
                f"cannot listen on {endpoints}: the port is already in use (another `hercs up` "
                "or `hercs router`?). Stop that process, or leave --listen out (any free port), or "
                "give port 0 (tcp/0.0.0.0:0: any free port, recorded in the run directory's "
                "router.json) or another PORT."
            ) from None
        if "Cannot assign requested address" in text:
            raise RouterListenError(
                f"cannot listen on {endpoints}: that address is not one of this host's; use "
                "tcp/0.0.0.0:PORT for every interface or one of `ip addr`'s addresses."
            ) from None
        raise RouterListenError(f"cannot listen on {endpoints}: {exc}") from None


def alive_label(key: str) -> str:
    """`hercs/<run>/alive/<role>/<id>` → `<role> <id> (run <run>)`; other keys unchanged."""
    parts = key.split("/")
    if len(parts) >= 5 and parts[0] == ROOT and parts[2] == "alive":
        return f"{parts[3]} {'/'.join(parts[4:])} (run {parts[1]})"
    return key


def run_router(config: HercsConfig) -> int:
    """Route until SIGINT/SIGTERM; logs every hercs process that joins or leaves any run.

    Returns 0 after a signal, 1 if it cannot listen, 2 for an unusable security set-up (e.g.
    a non-loopback address without TLS). Must run on the main thread (signals).
    """
    logging.basicConfig(level=logging.INFO,
                        format="%(asctime)s router %(levelname)s %(message)s")
    with StopSignals() as signals:
        try:
            router, listening = open_router_anywhere(config.transport.listen, config.security)
        except ConfigError as exc:
            print(f"hercs router: {exc}", file=sys.stderr, flush=True)
            return 2
        except RouterListenError as exc:
            print(f"hercs router: {exc}", file=sys.stderr, flush=True)
            return 1
        with router:
            router.watch_alive(
                f"{ROOT}/*/alive/**",
                lambda key, alive: log.info("%s %s", alive_label(key),
                                            "joined" if alive else "left"),
            )
            print(f"hercs router: listening on {listening}; "
                  "Ctrl-C to stop", flush=True)
            while not signals.stop_requested:
                signals.wait(None)
        print("hercs router: stopped", flush=True)
        return 0
