"""The calls the replay table holds: inserts waiting for the rate limiter, admitted inserts
waiting for the log's group commit, and samples waiting for the limiter, with each insert's
(actor_id, seq) parked at most once and never while stored (`check_unstored` checks each
group before the log is written). The table decides what moves between these queues; this
object only holds them. Not thread-safe: the table's lock guards it."""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from typing import Any

from hercs.replay_service.table_calls import (
    EpisodeIdConflict,
    Parked,
    ParkedInsert,
    ParkedSample,
    take_expired,
)
from hercs.replay_service.waiting_inserts import WaitingInserts
from hercs.wire.episode import EpisodeData

InsertKey = tuple[str, int]
"""(actor_id, seq): what a retry of an insert shares with its first call."""


def insert_key(episode: EpisodeData) -> InsertKey:
    return (episode.actor_id, int(episode.seq))


class ParkedCalls:
    def __init__(self, *, waiting_inserts_per_actor: int) -> None:
        self.inserts = WaitingInserts(per_actor=waiting_inserts_per_actor)
        """Waiting for the limiter, taken round-robin across actors."""
        self.ready: list[ParkedInsert] = []
        """Admitted, in admission order, waiting for the next group commit."""
        self.samples: deque[ParkedSample] = deque()
        """Waiting for the limiter, in arrival order."""
        self._by_key: dict[InsertKey, ParkedInsert] = {}
        """Every parked insert, waiting or admitted, until it is stored or answered."""

    def joined(self, key: InsertKey) -> ParkedInsert | None:
        """The parked insert a retry with `key` joins, or None."""
        return self._by_key.get(key)

    def park_insert(self, item: ParkedInsert) -> None:
        self.inserts.append(item)
        self._by_key[insert_key(item.episode)] = item

    def park_sample(self, item: ParkedSample) -> None:
        self.samples.append(item)

    def forget(self, item: ParkedInsert) -> None:
        """An insert is stored or answered: a later call with its key is a new one."""
        del self._by_key[insert_key(item.episode)]

    def take_ready(self) -> list[ParkedInsert]:
        """The admitted inserts, for one group commit (they stay parked until forgotten)."""
        group, self.ready = self.ready, []
        return group

    def take_expired(self, now: float) -> list[Parked[Any]]:
        """Remove and return every waiting call past its deadline (inserts forgotten); the
        order of the others is unchanged. Admitted inserts are not expired: they are logged."""
        inserts, samples = self.inserts.take_expired(now), take_expired(self.samples, now)
        for item in inserts:
            self.forget(item)
        return [*inserts, *samples]

    def waiting(self) -> tuple[int, int]:
        """(inserts, samples) waiting for the limiter."""
        return len(self.inserts), len(self.samples)


def check_unstored(stored: Mapping[InsertKey, int], group: list[ParkedInsert]) -> None:
    """`EpisodeIdConflict` if an episode of `group` is stored already (in `stored`, the
    table's episode ids by (actor_id, seq)) or twice in it: the store would then answer it
    with its earlier id instead of the next one, and the log would record it under an id the
    store never gives. An insert is parked only while it is neither stored nor parked, so
    this is a broken invariant, refused before anything is logged."""
    seen: set[InsertKey] = set()
    for item in group:
        key = insert_key(item.episode)
        known = stored.get(key)
        if known is not None or key in seen:
            where = f"stored as episode {known}" if known is not None else "twice in it"
            raise EpisodeIdConflict(
                f"a group of {len(group)} admitted inserts holds episode (actor "
                f"{key[0]!r}, seq {key[1]}) {where}: not logged and not stored, each call "
                "answered 'internal' (a retry is acknowledged as a duplicate if stored)")
        seen.add(key)
