"""At-least-once delivery of an actor's episodes to the replay, on its own sender thread.

An episode stays with the `Inserter` until an `InsertAck` names its `(actor_id, seq)`; an error
reply is handled by its reason's disposition (`hercs.reasons`); a retry resends the same
bytes, which the replay's deduplication makes safe. Episodes go one at a time, in `seq` order.
`submit` blocks while `capacity` episodes wait, so a replay holding inserts stops the env
instead of a queue growing (the default 2 keeps the env stepping through one ack's round
trip); `close(timeout_s)` gives up what is left after it: an episode never acked may be
lost, an acked one never is.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from hercs.errors import InvalidMessage
from hercs.net.backoff import Backoff
from hercs.net.service_shell import start_supervised
from hercs.net.transport import RemoteError, TransportError, TransportTimeout
from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Disposition, Reason, disposition
from hercs.run.warn_once import WarnOncePerMinute
from hercs.wire.validation import parse_message

log = logging.getLogger(__name__)


BACKOFF_MIN_S = 0.1
BACKOFF_MAX_S = 2.0
_ACK_MAX_BYTES = 64 * 1024


@dataclass
class InsertCounters:
    """What happened to the submitted episodes (each ends in exactly one of the first five)."""

    acked: int = 0
    """Acked by the replay (stored now or by an earlier attempt)."""
    dropped: int = 0
    """Rejected for a validation reason; never retried."""
    abandoned: int = 0
    """Not acked when the inserter was closed."""
    superseded: int = 0
    """Refused by the lockstep schedule (weights too old, or the cycle already full)."""
    duplicates: int = 0
    """Acks with `duplicate=True` (a retry of an episode already stored), among `acked`."""
    retries: int = 0
    """Attempts after the first, over all episodes."""
    blocked_s: float = 0.0
    """Time `submit` spent waiting for a free slot (backpressure)."""


class Inserter:
    """Sends `(seq, payload)` episodes through `send` (one request → reply bytes) until acked.

    `send` is e.g. `lambda p: transport.request(keys.insert, p, timeout_s=...)`; it raises
    `TransportTimeout`, `RemoteError` or `TransportError` as `hercs.net.transport.request` does.
    """

    def __init__(
        self,
        *,
        send: Callable[[bytes], bytes],
        actor_id: str,
        capacity: int = 2,
        backoff_min_s: float = BACKOFF_MIN_S,
        backoff_max_s: float = BACKOFF_MAX_S,
        on_crash: Callable[[str, BaseException], None] | None = None,
    ) -> None:
        """`on_crash(thread name, exc)` hears of an unexpected exception that ended the sender
        thread (e.g. `ServiceRuntime.crashed`); without it the exception is only logged."""
        if capacity < 0:
            raise ValueError(f"Inserter capacity: got {capacity}, must be >= 0")
        self.actor_id = actor_id
        self.capacity = capacity
        self.counters = InsertCounters()
        self._send = send
        self._backoff = Backoff(backoff_min_s, backoff_max_s)  # checks the bounds now
        self._queue: collections.deque[tuple[int, bytes]] = collections.deque()
        self._cond = threading.Condition()
        self._closing = False
        self._busy = False
        """An episode is being delivered (popped from the queue, outcome not yet known)."""
        self.newest_next_policy_version = 0
        """The highest `next_policy_version` any ack carried (lockstep)."""
        self.latest_next_policy_version = 0
        """The `next_policy_version` of the latest ack (the lag bound: after a learner restart
        the versions start lower again, so the highest would ask for weights that never come)."""
        self._abort = threading.Event()
        self._warn = WarnOncePerMinute(log)
        self._thread = start_supervised(self._run, name=f"hercs-inserter-{actor_id}",
                                        on_crash=on_crash or (lambda name, exc: None))

    @property
    def queued(self) -> int:
        """Episodes waiting behind the one in flight."""
        with self._cond:
            return len(self._queue)

    def submit(self, seq: int, payload: bytes, *, stop: threading.Event,
               poll_s: float = 0.2) -> bool:
        """Queue one serialised `Episode`; blocks while the queue is full (backpressure).

        Returns False, without queueing, if `stop` is set or the inserter closes while waiting
        (`stop` is checked every `poll_s`; a freed slot wakes the call at once).
        """
        start = time.monotonic()
        with self._cond:
            while self._full():
                if stop.is_set() or self._closing:
                    return False
                self._cond.wait(poll_s)
            if self._closing:
                return False
            self._queue.append((seq, payload))
            self._cond.notify_all()
        self.counters.blocked_s += time.monotonic() - start
        return True

    def _full(self) -> bool:
        """(Under the lock.) With capacity 0 nothing waits behind a delivery in flight."""
        if self.capacity == 0:
            return bool(self._queue) or self._busy
        return len(self._queue) >= self.capacity

    def wait_idle(self, *, stop: threading.Event, poll_s: float = 0.2) -> bool:
        """Wait until every submitted episode's delivery has ended; False if `stop` is set or
        the sender thread ends first."""
        with self._cond:
            while self._queue or self._busy:
                if stop.is_set() or not self._thread.is_alive():
                    return False
                self._cond.wait(poll_s)
        return True

    def close(self, *, timeout_s: float) -> None:
        """Stop taking episodes and flush the queue for at most `timeout_s`, then abort.

        After an abort a request may still be in flight: close the transport, then `join()`.
        """
        with self._cond:
            self._closing = True
            self._cond.notify_all()
        self._thread.join(max(timeout_s, 0.0))
        if self._thread.is_alive():
            self._abort.set()
            with self._cond:
                self._cond.notify_all()

    def abort(self) -> None:
        """Give up at once: take no more episodes, retry nothing (a retry in its backoff
        ends now); what is queued is counted `abandoned`. For a run that is over, whose
        replay answers every insert `unavailable` while it closes."""
        with self._cond:
            self._closing = True
            self._abort.set()
            self._cond.notify_all()

    def join(self, timeout_s: float) -> bool:
        """Wait for the sender thread to end; True if it did."""
        self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._closing:
                    self._cond.wait()
                if self._abort.is_set() or not self._queue:
                    self.counters.abandoned += len(self._queue)
                    self._queue.clear()
                    return
                seq, payload = self._queue.popleft()
                self._busy = True
                self._cond.notify_all()  # a slot is free: wake a blocked submit
            self._deliver(seq, payload)
            with self._cond:
                self._busy = False
                self._cond.notify_all()  # wake `wait_idle`

    def _deliver(self, seq: int, payload: bytes) -> None:
        """Send until acked, dropped, superseded or aborted; counts the outcome."""
        c = self.counters
        backoff = self._backoff  # one sender thread: one delivery at a time
        backoff.reset()
        attempt = 0
        while True:
            if self._abort.is_set():
                c.abandoned += 1
                return
            try:
                reply = self._send(payload)
            except TransportTimeout as exc:
                kind, why = "timeout", str(exc)
            except RemoteError as exc:
                then = disposition(exc.reason)
                if then is Disposition.SUPERSEDED:
                    c.superseded += 1
                    log.debug("episode (%s, seq %d) not wanted by the lockstep schedule: %s",
                              self.actor_id, seq, exc.detail)
                    return
                if then is Disposition.DROP:
                    c.dropped += 1
                    self._warn.warn(f"rejected:{exc.reason}",
                                    f"replay rejected episode ({self.actor_id}, seq {seq}): "
                                    f"{exc.reason}: {exc.detail}; dropped, it cannot succeed")
                    return
                kind, why = f"remote:{exc.reason}", str(exc)
            except TransportError as exc:
                kind, why = Reason.TRANSPORT.value, str(exc)
            else:
                ack = self._check_ack(reply, seq, first_attempt=attempt == 0)
                if isinstance(ack, pb.InsertAck):
                    self.newest_next_policy_version = max(self.newest_next_policy_version,
                                                          int(ack.next_policy_version))
                    self.latest_next_policy_version = int(ack.next_policy_version)
                    return
                kind, why = "bad-ack", ack
            if self._abort.is_set():
                c.abandoned += 1
                return
            attempt += 1
            self._warn.warn(f"retry:{kind}",
                            f"insert of ({self.actor_id}, seq {seq}) not acked ({why}); "
                            f"retrying the same episode in {backoff.next_s:.1f} s (attempt "
                            f"{attempt + 1})")
            if backoff.wait(self._abort):
                c.abandoned += 1
                return
            c.retries += 1  # counted when sent: an abort in the backoff sends nothing

    def _check_ack(self, reply: bytes, seq: int, *,
                   first_attempt: bool) -> pb.InsertAck | str:
        """The ack if `reply` acks (actor_id, seq) (and count it), else why not."""
        try:
            ack = parse_message(reply, pb.InsertAck, max_bytes=_ACK_MAX_BYTES)
        except InvalidMessage as exc:
            return f"undecodable InsertAck: {exc}"
        if ack.actor_id != self.actor_id or ack.seq != seq:
            return (f"InsertAck names ({ack.actor_id!r}, seq {ack.seq}), "
                    f"expected ({self.actor_id!r}, seq {seq})")
        self.counters.acked += 1
        # one line per ack at DEBUG (HERCS_LOG=DEBUG): which (actor_id, seq) the replay
        # promised to keep, what bench.faults.net_faults checks the episode log against
        log.debug("episode (%s, seq %d) acked%s", self.actor_id, seq,
                  " (duplicate)" if ack.duplicate else "")
        if ack.duplicate:
            self.counters.duplicates += 1
            if first_attempt:
                # Nothing of ours was sent before: an earlier process used this actor id, and
                # the replay kept its episode under this seq instead of ours.
                self._warn.warn("duplicate-first",
                                f"replay already holds ({self.actor_id}, seq {seq}) from an "
                                "earlier process with this actor id; this episode was not "
                                "stored. Give each actor process a fresh --id")
        return ack
