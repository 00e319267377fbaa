"""The learner's prefetcher: sample requests sent ahead of the update loop, on its own thread,
within a credit of `learner.prefetch_depth` batches (docs/DESIGN.md §9.1)."""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

from hercs.errors import InvalidMessage
from hercs.net.service_shell import ServiceRuntime
from hercs.net.transport import RemoteError, TransportError, TransportTimeout
from hercs.proto import SCHEMA_VERSION
from hercs.proto import hercs_pb2 as pb
from hercs.rl.task_registry import TaskSpec
from hercs.run.warn_once import WarnOncePerMinute
from hercs.wire.served import ServedBatch, decode_served_batch

log = logging.getLogger("hercs.learner")

_POLL_S = 0.5

ASK_AGAIN_S = 30.0
"""The longest one sample request waits for its reply before the same request is sent again.

The replay parks a request until it can serve it (the rate limiter, lockstep's cycle), up to
`replay.sample_timeout_s` (10 min). A request can lose its reply for good: a get that Zenoh
routes to a replay killed a moment before may never be finalised, and until its own timeout
nothing says so, while the restarted replay, the actors and their episodes all wait for this
learner. Asking again after this long bounds that loss; it is safe: the replay answers this
learner's earlier parked call `expired` (one request at a time) and recounts its limiter from
`samples_kept`, and lockstep's grace for a late cluster model runs from the cycle's first ask."""


@dataclass(frozen=True)
class BatchShape:
    """What each sample request asks for, and so what each reply must be to be trained on."""

    run: str
    spec: TaskSpec
    clusters: int
    """k: the length of a batch's per-cluster draw counts."""
    minibatches: int
    batch_size: int


class Prefetcher:
    """Requests batches ahead of the update loop on its own thread.

    At most `learner.prefetch_depth` batches are sampled and not yet taken by the loop: each
    request takes a credit, each `get` gives one back before it waits, so with depth 0 a
    batch is asked for only when the loop wants it. Every batch sampled ahead lets the rate
    limiter admit a cycle of episodes more before their weights exist: one cycle of policy lag
    per batch of depth (docs/DESIGN.md §9.1).

    In the lockstep schedule it asks for nothing ahead: cycle c's request (weights_version c)
    is sent once the loop has reached version c (`cycle_done` wakes it), and the replay holds
    it until cycle c's episodes are stored."""

    def __init__(self, *, runtime: ServiceRuntime, shape: BatchShape, lockstep: bool,
                 depth: int, sample_timeout_s: float, version: Callable[[], int],
                 samples_kept: int) -> None:
        """`depth`: `learner.prefetch_depth`; `sample_timeout_s`: `replay.sample_timeout_s`;
        `samples_kept`: the updates this run's learner has done and kept (its checkpoint's
        count after a restart; 0 for a new run)."""
        self.runtime = runtime
        self.shape = shape
        self.sample_timeout_s = sample_timeout_s
        self.version = version
        self.lockstep = lockstep
        self._advanced = threading.Condition()
        self.batches: queue.Queue[ServedBatch] = queue.Queue()  # bounded by the credits
        self._credits = threading.Semaphore(depth)
        self.warn = WarnOncePerMinute(log)
        self._request_id = 0
        self.asked_again = 0
        """Requests sent again because their reply was overdue (`ASK_AGAIN_S`)."""
        self.samples_kept = samples_kept
        """Minibatches received and kept: each request tells the replay (SampleRequest)."""
        self.incarnation = f"{runtime.ident}@{time.time_ns()}"
        self.waiting_s = 0.0
        self._credit_returned = False
        """`take`: the credit of the batch it waits for was given back."""
        self.bad_batches: Counter[str] = Counter()
        """Batch replies skipped because they failed validation, by reason."""
        self._thread = runtime.start_thread(self._run, name="prefetch")

    def cycle_done(self) -> None:
        """The loop finished a cycle and broadcast its weights (lockstep's cue)."""
        with self._advanced:
            self._advanced.notify_all()

    def _wait_for_version(self, wanted: int) -> bool:
        """Lockstep: wait until the loop is at `wanted`; False if stopped first."""
        stop = self.runtime.stop
        with self._advanced:
            while self.version() < wanted:
                if stop.is_set():
                    return False
                self._advanced.wait(_POLL_S)
        return not stop.is_set()

    def _run(self) -> None:
        stop = self.runtime.stop
        wanted = self.version()  # lockstep: the cycle the next request is for
        while not stop.is_set():
            if not self._credits.acquire(timeout=_POLL_S):
                continue
            if self.lockstep and not self._wait_for_version(wanted):
                return
            if not self._fetch(wanted):
                self._credits.release()  # nothing was sampled with it
                continue
            wanted += 1

    def _fetch(self, wanted: int) -> bool:
        """One request for cycle `wanted`; True once its batch is queued, False if it failed
        (counted and warned; the caller asks again) or the service is stopping. A request
        whose reply is overdue (`ASK_AGAIN_S`) is sent again, quietly until it has waited
        `replay.sample_timeout_s` in all."""
        stop = self.runtime.stop
        started = time.monotonic()
        while True:
            try:
                return self._ask(wanted)
            except TransportTimeout as exc:
                if stop.is_set():
                    return False
                waited = time.monotonic() - started
                if exc.no_queryable or waited >= self.sample_timeout_s:
                    self.warn.warn(type(exc).__name__,
                                   f"sample request failed ({exc}); retrying")
                    stop.wait(0.5)
                    return False
                self.asked_again += 1
                log.debug("no batch for cycle %d after %.0f s; asking again", wanted, waited)

    def _ask(self, wanted: int) -> bool:
        """`_fetch`'s one request; raises `TransportTimeout` when its reply is overdue."""
        stop = self.runtime.stop
        self._request_id += 1
        shape = self.shape
        request = pb.SampleRequest(
            schema_version=SCHEMA_VERSION, run=shape.run,
            learner_id=self.runtime.ident, request_id=self._request_id,
            num_minibatches=shape.minibatches, batch_size=shape.batch_size,
            weights_version=wanted if self.lockstep else self.version(),
            samples_kept=self.samples_kept, learner_incarnation=self.incarnation)
        try:
            raw = self.runtime.transport.request(
                self.runtime.keys.sample, request.SerializeToString(),
                timeout_s=min(self.sample_timeout_s, ASK_AGAIN_S))
            batch = decode_served_batch(raw, spec=shape.spec, k=shape.clusters,
                                        batch_size=shape.batch_size,
                                        num_minibatches=shape.minibatches)
        except InvalidMessage as exc:  # a reply no update may see: counted, skipped
            self.bad_batches[exc.reason] += 1
            self.warn.warn(f"bad:{exc.reason}", f"skipped a bad Batch ({exc}); asking again")
            return False
        except TransportTimeout:
            raise
        except (RemoteError, TransportError) as exc:
            if not stop.is_set():
                self.warn.warn(type(exc).__name__, f"sample request failed ({exc}); retrying")
                stop.wait(0.5)
            return False
        self.samples_kept += len(batch.minibatches)
        self.batches.put(batch)
        return True

    def take(self, timeout_s: float) -> ServedBatch | None:
        """The next batch if one is here within `timeout_s`, else None (a stacked learner's
        poll of each of its cells: hercs.learner.stacked_shell). The credit for the batch
        after the ones sampled is given back once per batch taken, however often it polls;
        time spent waiting adds to `waiting_s`."""
        if not self._credit_returned:
            self._credits.release()
            self._credit_returned = True
        started = time.monotonic()
        try:
            batch = self.batches.get(timeout=timeout_s) if timeout_s > 0 \
                else self.batches.get_nowait()
        except queue.Empty:
            return None
        finally:
            self.waiting_s += time.monotonic() - started
        self._credit_returned = False
        return batch

    def get(self) -> ServedBatch | None:
        """The next batch, or None once the service is stopping. Time spent waiting for one
        adds to `waiting_s`: the update loop idles then, so it is what prefetch failed to hide."""
        self._credits.release()  # room for the batch after the ones already sampled
        try:
            return self.batches.get_nowait()
        except queue.Empty:
            pass
        started = time.monotonic()
        try:
            while not self.runtime.stop.is_set():
                try:
                    return self.batches.get(timeout=0.5)
                except queue.Empty:
                    continue
            return None
        finally:
            self.waiting_s += time.monotonic() - started
