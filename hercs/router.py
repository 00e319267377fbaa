"""The Zenoh router every hercs run goes through: standalone (`hercs router`, the compose
`router` service) or embedded in `hercs up`'s launcher. It only routes: it holds no hercs
state, so services and actors may come and go (clients reconnect by themselves if it restarts).
"""

from __future__ import annotations

import contextlib
import logging
import select
import signal
import socket
import sys
from collections.abc import Iterable, Sequence
from types import FrameType

from hercs.config import HercsConfig
from hercs.transport import Transport, TransportError
from proto.keys import ROOT

log = logging.getLogger(__name__)


class RouterListenError(TransportError):
    """The router could not listen on an endpoint; nothing was started."""


def open_router(listen: Sequence[str]) -> Transport:
    """A router-mode `Transport` listening on `listen`.

    Raises `RouterListenError` with what to do next when an endpoint cannot be bound (most
    often: the port is taken by another `hercs up` or `hercs router`).
    """
    endpoints = list(listen)
    try:
        return Transport.open(mode="router", listen=endpoints)
    except TransportError as exc:
        text = str(exc)
        if "Address already in use" in text:
            raise RouterListenError(
                f"cannot listen on {endpoints}: the port is already in use (another `hercs up` "
                "or `hercs router`?). Stop that process, or pick a free port with "
                "--listen tcp/127.0.0.1:PORT (remote actors then use --connect with that port)."
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


class StopSignals:
    """Turns stop signals into wake-ups of `wait()` on the main thread, without locks.

    A signal handler that sets a `threading.Event` can deadlock when the signal lands while
    the main thread holds that Event's lock (inside `Event.wait`). Instead the handlers only
    append to `received`, and `signal.set_wakeup_fd` writes a byte to a socket pair that
    `wait()` selects on; other threads call `wake()`. Signals in `wake_on` (e.g. SIGCHLD) get
    a no-op handler so that they, too, interrupt `wait()`. Enter and exit on the main thread;
    the previous handlers are restored on exit.
    """

    def __init__(self, stop_on: Iterable[int] = (signal.SIGINT, signal.SIGTERM),
                 *, wake_on: Iterable[int] = ()) -> None:
        self.received: list[int] = []
        """Stop signals received so far, in order (a second one means "hurry")."""
        self._stop_on = tuple(stop_on)
        self._wake_on = tuple(wake_on)
        self._previous: dict[int, object] = {}
        self._previous_fd = -1
        self._reader, self._writer = socket.socketpair()
        self._reader.setblocking(False)
        self._writer.setblocking(False)

    def __enter__(self) -> StopSignals:
        self._previous_fd = signal.set_wakeup_fd(self._writer.fileno(),
                                                 warn_on_full_buffer=False)
        for sig in self._stop_on:
            self._previous[sig] = signal.signal(sig, self._on_stop)
        for sig in self._wake_on:
            self._previous[sig] = signal.signal(sig, self._on_wake)
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)  # type: ignore[arg-type]
        signal.set_wakeup_fd(self._previous_fd)
        self._reader.close()
        self._writer.close()

    def _on_stop(self, signum: int, frame: FrameType | None) -> None:
        self.received.append(signum)

    def _on_wake(self, signum: int, frame: FrameType | None) -> None:
        pass

    @property
    def stop_requested(self) -> bool:
        return bool(self.received)

    def wake(self) -> None:
        """Make the main thread's `wait()` return; callable from any thread."""
        with contextlib.suppress(OSError):  # a full buffer already holds a wake-up
            self._writer.send(b"\0")

    def wait(self, timeout_s: float | None) -> None:
        """Block until a signal, a `wake()` or `timeout_s`; then drain the wake-ups."""
        select.select([self._reader], [], [], timeout_s)
        with contextlib.suppress(BlockingIOError, InterruptedError):
            while self._reader.recv(4096):
                pass


def run_router(config: HercsConfig) -> int:
    """Route until SIGINT/SIGTERM; logs every hercs process that joins or leaves any run.

    Returns 0 after a signal, 1 if it cannot listen. Must run on the main thread (signals).
    """
    logging.basicConfig(level=logging.INFO,
                        format="%(asctime)s router %(levelname)s %(message)s")
    with StopSignals() as signals:
        try:
            router = open_router(config.transport.listen)
        except RouterListenError as exc:
            print(f"hercs router: {exc}", file=sys.stderr, flush=True)
            return 1
        with router:
            router.watch_alive(
                f"{ROOT}/*/alive/**",
                lambda key, alive: log.info("%s %s", alive_label(key),
                                            "joined" if alive else "left"),
            )
            print(f"hercs router: listening on {list(config.transport.listen)}; "
                  "Ctrl-C to stop", flush=True)
            while not signals.stop_requested:
                signals.wait(None)
        print("hercs router: stopped", flush=True)
        return 0
