"""When a client's session has gone blind: the rule behind `Transport`'s session reopen.

After a link cut longer than Zenoh's lease, a client session reconnects to its router by
itself, and the router should send it the declarations it missed. Zenoh has open reports of
sessions where that does not happen (eclipse-zenoh/zenoh#2767: after a reconnect, a query
returns zero replies at once; ros2/rmw_zenoh#1029: a client never discovers a reachable
queryable): the session is connected, yet finds no queryable for a key, and nothing inside
Zenoh ever repairs it. Reopening the session (a new session id, so the router sends every
declaration afresh) does.

`Rediscovery` decides when: a key that was answered before on this transport has found no
queryable for `after_s` while the session had a router, so the queryable is most likely
there and the session does not see it. A queryable that is really gone (a replay being
restarted) looks the same from here, so a streak's reopens back off, doubling up to
`max_after_s`; an answer on the key ends the streak. A key never answered (an actor started
before its run) never triggers a reopen: there is nothing it has lost.
"""

from __future__ import annotations

import time
from collections.abc import Callable


class Rediscovery:
    """Per-key streaks of "no queryable" and the reopen they call for (pure, one lock
    outside: `Transport` serialises the calls)."""

    def __init__(self, *, after_s: float, max_after_s: float,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not after_s > 0:
            raise ValueError(f"after_s: got {after_s}, must be > 0")
        if max_after_s < after_s:
            raise ValueError(f"max_after_s: got {max_after_s}, must be >= after_s ({after_s})")
        self.after_s = after_s
        self.max_after_s = max_after_s
        self._clock = clock
        self._answered: set[str] = set()
        self._missing_since: dict[str, float] = {}
        self._wait_s: dict[str, float] = {}

    def answered(self, key: str) -> None:
        """A request on `key` was answered (an error reply counts: something answered)."""
        self._answered.add(key)
        self._missing_since.pop(key, None)
        self._wait_s.pop(key, None)

    def missing(self, key: str) -> bool:
        """A request on `key` found no queryable; True when the session should be reopened
        now (the streak then waits twice as long for its next reopen)."""
        if key not in self._answered:
            return False
        now = self._clock()
        since = self._missing_since.setdefault(key, now)
        wait_s = self._wait_s.get(key, self.after_s)
        if now - since < wait_s:
            return False
        self._missing_since[key] = now
        self._wait_s[key] = min(2.0 * wait_s, self.max_after_s)
        return True

    def missing_for_s(self, key: str) -> float:
        """How long the current streak of `key` has gone on (0 if none)."""
        since = self._missing_since.get(key)
        return 0.0 if since is None else self._clock() - since
