"""When a client's session has gone blind: the rule behind `Transport`'s session reopen.

After a cut longer than Zenoh's lease a client session reconnects by itself, and the router
should resend the declarations it missed. Zenoh has open reports where it does not
(eclipse-zenoh/zenoh#2767, ros2/rmw_zenoh#1029): the session is connected yet finds no
queryable for a key, and nothing inside Zenoh repairs it. Reopening the session (a new session
id, so the router sends every declaration afresh) does (docs/DESIGN.md §3, "Threads").

`Rediscovery` decides when: a key answered before on this transport has found no queryable for
`after_s` while the session had a router. A queryable really gone (a replay restarting) looks
the same from here, so a streak's reopens back off, doubling up to `max_after_s`; an answer on
the key ends the streak. A key never answered (an actor started before its run) never triggers
a reopen: there is nothing it has lost.
"""

from __future__ import annotations

import random
import time
from collections.abc import Callable


class Rediscovery:
    """Per-key streaks of "no queryable" and the reopen they call for (pure; `Transport`
    serialises the calls).

    A streak is a run of misses on one key with no answer between them and no gap longer
    than `after_s` (a request sent rarely, missing once an hour after its last miss, starts a
    new streak rather than completing an old one). Each wait is stretched by a random share
    up to `jitter`, so that clients that lost the same queryable together do not all reopen
    at the same moment.
    """

    def __init__(self, *, after_s: float, max_after_s: float, jitter: float = 0.25,
                 rng: random.Random | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not after_s > 0:
            raise ValueError(f"after_s: got {after_s}, must be > 0")
        if max_after_s < after_s:
            raise ValueError(f"max_after_s: got {max_after_s}, must be >= after_s ({after_s})")
        if not 0 <= jitter <= 1:
            raise ValueError(f"jitter: got {jitter}, must be in [0, 1]")
        self.after_s = after_s
        self.max_after_s = max_after_s
        self.jitter = jitter
        self._rng = rng or random.Random()
        self._clock = clock
        self._answered: set[str] = set()
        self._missing_since: dict[str, float] = {}
        self._last_miss: dict[str, float] = {}
        self._wait_s: dict[str, float] = {}
        self.streak_s = 0.0
        """How long the streak that last called for a reopen had gone on."""

    def answered(self, key: str) -> None:
        """A request on `key` was answered (an error reply counts: something answered)."""
        self._answered.add(key)
        self._missing_since.pop(key, None)
        self._last_miss.pop(key, None)
        self._wait_s.pop(key, None)

    def _wait(self, key: str) -> float:
        if key not in self._wait_s:
            self._wait_s[key] = self.after_s * (1.0 + self.jitter * self._rng.random())
        return self._wait_s[key]

    def missing(self, key: str, *, asked_at: float | None = None) -> bool:
        """A request on `key`, sent at `asked_at` (default: now, on this clock), found no
        queryable; True when the session should be reopened now (the streak then waits twice
        as long for its next reopen). The gap that ends a streak is from the last miss to
        this request's start, so requests that each wait longer than `after_s` still make
        one streak."""
        if key not in self._answered:
            return False
        now = self._clock()
        last = self._last_miss.get(key)
        self._last_miss[key] = now
        asked = now if asked_at is None else asked_at
        if last is None or asked - last > self.after_s:
            self._missing_since[key] = asked  # a new streak, from this request's start
        since = self._missing_since[key]
        wait_s = self._wait(key)
        if now - since < wait_s:
            return False
        self.streak_s = now - since
        self._wait_s[key] = min(2.0 * wait_s, self.max_after_s)
        self.reopened()
        return True

    def reopened(self) -> None:
        """The session was reopened: every streak starts again from now (a key that went
        missing meanwhile gets the new session's full bound too)."""
        now = self._clock()
        for key in self._missing_since:
            self._missing_since[key] = now
