"""The inserts waiting for the rate limiter, admitted round-robin across actor ids.

While the limiter holds inserts, the order in which it takes the waiting ones decides who
gets the insert capacity. In arrival order (one FIFO) an actor with k inserts waiting ahead
of another actor's one takes k admissions first: an actor that sends many inserts at once
(a misbehaving client, several senders under one id) takes nearly all of the capacity, and
the others' inserts wait until their callers time out.

Round-robin: a FIFO per actor id and a ring of the actor ids that have inserts waiting.
Each admission takes the oldest insert of the actor at the head of the ring and moves that
actor to the tail (or out of the ring, if nothing of it waits any more); an actor whose
first insert arrives joins at the tail. So with m actors waiting, an actor's oldest insert
is admitted after at most m − 1 admissions of other actors' inserts, however many inserts
each of them has waiting: every actor with inserts waiting gets one admission in m. An
actor that alone has inserts waiting is admitted in arrival order, as with one FIFO.

Bound: at most `per_actor` inserts of one actor id wait. `refusal` answers one more with
`actor_queue_full`, a retry (hercs.reasons): the actor's inserter backs off (0.1 s
doubling to 2 s) and sends the same bytes again, so nothing is lost, the flooding actor is
slowed by its own backoff, and what the waiting inserts hold in memory is bounded by
actors × `per_actor` × the largest message. An inserter delivers one episode at a time
(hercs.actors.inserter), so a well-behaved actor never has more than one waiting. A retry of a
waiting (actor_id, seq) joins that call (hercs.replay_service.table) and is never refused here.

`per_actor = 0` turns fair sharing off: one FIFO in arrival order and no bound (what the
replay did before, kept for the side-by-side measurement, bench/perf/fair_share.py).
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
