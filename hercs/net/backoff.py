"""The one retry delay: exponential backoff, doubling from a first delay up to a ceiling, slept
on an event so that a stop interrupts it. Used wherever a client asks again (the actor's
inserts, a service joining its run, the clusterer's state request) and for the launcher's
restart delays."""

from __future__ import annotations

import threading


def nth_delay(first_s: float, n: int, max_s: float) -> float:
    """The delay before retry `n` (0-based): `first_s` · 2ⁿ, at most `max_s`."""
    return min(first_s * 2.0 ** min(n, 64), max_s)


class Backoff:
    """Successive retry delays of one operation; `reset()` after it succeeds."""

    def __init__(self, first_s: float, max_s: float) -> None:
        if not 0 < first_s <= max_s:
            raise ValueError(f"Backoff: got first {first_s}, max {max_s}; need "
                             "0 < first <= max")
        self.first_s, self.max_s = first_s, max_s
        self.attempts = 0

    @property
    def next_s(self) -> float:
        """The delay the next `wait` sleeps."""
        return nth_delay(self.first_s, self.attempts, self.max_s)

    def wait(self, stop: threading.Event) -> bool:
        """Sleep the next delay unless `stop` is set first; True if it was (give up)."""
        delay = self.next_s
        self.attempts += 1
        return stop.wait(delay)

    def reset(self) -> None:
        self.attempts = 0
