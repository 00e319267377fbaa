"""What an actor process is on the wire (its incarnation) and what it acts with next (the
newest weights received, in a one-slot mailbox between the subscription and the rollout)."""

from __future__ import annotations

import threading
import time

from hercs.rl.policy import PolicyWeights


def incarnation() -> str:
    """This process's incarnation: its start time in milliseconds, base 36 (unique per
    restart of an id on one host, ordered, short)."""
    value, digits = time.time_ns() // 1_000_000, "0123456789abcdefghijklmnopqrstuvwxyz"
    out = ""
    while value:
        value, rest = divmod(value, 36)
        out = digits[rest] + out
    return out or "0"


class LatestWeights:
    """A one-slot mailbox: the subscription thread `offer`s, the rollout loop `take`s.

    The most recently received weights win (not the highest version: a learner restarted
    without its checkpoint counts from 0 again, and its weights must still be adopted).
    """

    def __init__(self) -> None:
        self._lock = threading.Condition()
        self._pending: PolicyWeights | None = None

    def offer(self, weights: PolicyWeights) -> None:
        with self._lock:
            self._pending = weights
            self._lock.notify_all()

    def wait(self, timeout_s: float) -> None:
        """Return once weights are pending, or after `timeout_s`."""
        with self._lock:
            if self._pending is None:
                self._lock.wait(timeout_s)

    def take(self) -> PolicyWeights | None:
        """The weights received since the last `take`, newest only; None if none."""
        with self._lock:
            weights, self._pending = self._pending, None
        return weights
