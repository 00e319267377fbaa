"""When a client's session has gone blind or been cut off: the rules behind `Transport`'s
reopen (a new session, so a new Zenoh id, with every declaration made afresh).

`Rediscovery`: after a cut a session can be connected yet never relearn the router's
declarations (reported Zenoh bugs: eclipse-zenoh/zenoh#2767, ros2/rmw_zenoh#1029), so reopen
when a key answered before finds no queryable for `after_s` while the session had a router. A
queryable really gone (a replay restarting) looks the same, so a streak's reopens back off; a
key never answered (an actor started before its run) never counts.

`CutOff`: after a two-way cut longer than Zenoh's lease the router attaches the session's own
reconnect (same Zenoh id) to its old transport of that id, whose queries can go unanswered
until the dead connection under it is reset, up to a minute after the heal (TCP's back-off;
docs/results/net_faults.md). So a session without a router for `after_s` is reopened, and the
new id is taken as soon as the link is back.
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


class CutOff:
    """How long a client's session has had no router, and when that calls for a reopen (pure;
    `Transport` serialises the calls).

    It hears of the requests that found no queryable. The streak starts when the first one
    that ended with no router was sent: no router answered it since (a query the router had
    taken would have been answered or timed out instead), though one may have been there while
    it waited for a queryable, so the streak can start early by one request's timeout. A cut
    shorter than Zenoh's lease never counts: the session keeps its router. An answer, or a
    request that ends with a router, ends the streak. No jitter, unlike `Rediscovery`: clients
    cut off together wait for their link, not for the router, and connect when it heals as
    Zenoh's own reconnect would have.
    """

    def __init__(self, *, after_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        if not after_s > 0:
            raise ValueError(f"after_s: got {after_s}, must be > 0")
        self.after_s = after_s
        self._clock = clock
        self._since: float | None = None
        self.streak_s = 0.0
        """How long the session had had no router when a reopen was last called for."""

    def connected(self) -> None:
        """The session has a router (a request was answered, found one, or a reopen opened
        one): no streak."""
        self._since = None

    def no_router(self, *, asked_at: float | None = None) -> bool:
        """A request sent at `asked_at` (default: now, on this clock) found no queryable and
        the session has no router now; True when it has had none for `after_s`: reopen now.
        The streak then starts again, so a reopen that gave up (`transport.wait_s`) is
        called for again after another `after_s`."""
        now = self._clock()
        asked = now if asked_at is None else asked_at
        self._since = asked if self._since is None else min(self._since, asked)
        if now - self._since < self.after_s:
            return False
        self.streak_s = now - self._since
        self._since = now
        return True
