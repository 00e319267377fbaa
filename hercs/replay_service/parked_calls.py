"""The calls the replay table holds: inserts waiting for the rate limiter (round-robin across
actors, `WaitingInserts`), admitted inserts waiting for the log's group commit, and samples
waiting for the limiter, with each insert's (actor_id, seq) parked at most once and never
while stored (`check_unstored` checks each group before the log is written). The table
decides what moves between these queues; this object only holds them. Not thread-safe: the
table's lock guards it."""

from __future__ import annotations

from collections import OrderedDict, deque
from collections.abc import Mapping
from typing import Any

from hercs.reasons import Reason
from hercs.replay_service.table_calls import (
    EpisodeIdConflict,
    Parked,
    ParkedInsert,
    ParkedSample,
    take_expired,
)
from hercs.wire.episode import EpisodeData

InsertKey = tuple[str, int]
"""(actor_id, seq): what a retry of an insert shares with its first call."""


def insert_key(episode: EpisodeData) -> InsertKey:
    return (episode.actor_id, int(episode.seq))


class WaitingInserts:
    """The inserts waiting for the rate limiter, admitted round-robin across actor ids.

    A FIFO per actor id and a ring of the waiting actors: with m actors waiting each gets one
    admission in m (docs/DESIGN.md §3, "Fair sharing between actors"). At most `per_actor`
    inserts of one id wait; one more is refused `actor_queue_full` (a retry), so a flooder is
    slowed by its own backoff and the waiting inserts' memory stays bounded. A retry of a
    waiting (actor_id, seq) joins that call (hercs.replay_service.table) and is never refused
    here. `per_actor = 0` is one unbounded FIFO, kept to measure the difference
    (bench/perf/fair_share.py)."""

    def __init__(self, *, per_actor: int) -> None:
        if per_actor < 0:
            raise ValueError(f"WaitingInserts per_actor: got {per_actor}, must be >= 0 "
                             "(0: arrival order, no bound)")
        self.per_actor = per_actor
        self._ring: OrderedDict[str, deque[ParkedInsert]] = OrderedDict()
        """Actor id → its waiting inserts, oldest first; the head of the ring is next."""
        self._count = 0

    def __len__(self) -> int:
        return self._count

    def _key(self, actor_id: str) -> str:
        # Fair sharing off: every actor in one queue, i.e. arrival order.
        return actor_id if self.per_actor else ""

    def refusal(self, actor_id: str) -> tuple[Reason, str] | None:
        """Why a new insert of `actor_id` may not wait, or None if it may."""
        if not self.per_actor:
            return None
        queue = self._ring.get(actor_id)
        if queue is None or len(queue) < self.per_actor:
            return None
        return (Reason.ACTOR_QUEUE_FULL,
                f"actor {actor_id!r} already has {len(queue)} inserts waiting for the rate "
                f"limiter (replay.waiting_inserts_per_actor={self.per_actor}); retry after a "
                "backoff")

    def append(self, item: ParkedInsert) -> None:
        """Park `item` behind its actor's other waiting inserts (the caller checked
        `refusal`)."""
        key = self._key(item.episode.actor_id)
        queue = self._ring.get(key)
        if queue is None:
            queue = self._ring[key] = deque()  # a newcomer joins the ring at its tail
        queue.append(item)
        self._count += 1

    def popleft(self) -> ParkedInsert:
        """The next insert to admit: the oldest of the actor at the head of the ring."""
        if not self._ring:
            raise IndexError("popleft: no insert is waiting")
        key, queue = next(iter(self._ring.items()))
        item = queue.popleft()
        if queue:
            self._ring.move_to_end(key)
        else:
            del self._ring[key]
        self._count -= 1
        return item

    def take_expired(self, now: float) -> list[ParkedInsert]:
        """Remove and return the inserts past their deadline; the others keep their order
        and the ring its order."""
        gone: list[ParkedInsert] = []
        for key in list(self._ring):
            queue = self._ring[key]
            gone.extend(take_expired(queue, now))
            if not queue:
                del self._ring[key]
        self._count -= len(gone)
        return gone


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
