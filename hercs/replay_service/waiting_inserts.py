"""The inserts waiting for the rate limiter, admitted round-robin across actor ids.

A FIFO per actor id and a ring of the waiting actors: with m actors waiting each gets one
admission in m (docs/DESIGN.md §3, "Fair sharing between actors"). At most `per_actor` inserts
of one id wait; one more is refused `actor_queue_full` (a retry), so a flooder is slowed by its
own backoff and the waiting inserts' memory stays bounded. A retry of a waiting (actor_id, seq)
joins that call (hercs.replay_service.table) and is never refused here. `per_actor = 0` is one
unbounded FIFO, kept to measure the difference (bench/perf/fair_share.py).
"""

from __future__ import annotations

from collections import OrderedDict, deque

from hercs.reasons import Reason
from hercs.replay_service.table_calls import ParkedInsert, take_expired


class WaitingInserts:
    """Parked inserts by actor id, taken round-robin (module docstring)."""

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
