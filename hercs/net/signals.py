"""Stop signals on the main thread without a lock in the signal handler (`StopSignals`).

Every hercs process that waits on its main thread for a signal uses it: the launcher, the
router and each service's entry (`hercs.net.service_shell.service_main`).
"""

from __future__ import annotations

import contextlib
import select
import signal
import socket
from collections.abc import Iterable
from types import FrameType


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
