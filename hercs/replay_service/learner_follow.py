"""Which learner process the replay's rate limiter follows, and what its sample calls say.

A learner that says who it is (`SampleCall.learner_incarnation`) sends one sample request at
a time with the count of minibatches its run has kept (`samples_kept`), so the limiter's count
can follow the learner's durable updates through a learner or replay restart (docs/DESIGN.md
§8). Called by `ReplayTable` under its lock.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable

from hercs.reasons import Reason
from hercs.replay_service.rate_limiter import SampleToInsertRatio
from hercs.replay_service.table_calls import ParkedSample, SampleCall

log = logging.getLogger("hercs.replay")


def follow_learner(call: SampleCall, current: str | None, limiter: SampleToInsertRatio,
                   samples: deque[ParkedSample]) -> str | None:
    """Set the limiter's sample count to the minibatches `call`'s run has kept; returns the
    learner process followed from now on (`current` is the one followed so far).

    The learner sends one request at a time, so when a call arrives every earlier reply has
    reached it or is lost: the count is exact, up to a reply lost after its caller gave up. A
    learner that resumed from a checkpoint thus redoes the updates it lost on the episodes
    already stored, instead of the limiter admitting inserts for updates that were undone; a
    restarted replay takes the count it lost from the learner. Calls parked in `samples` for a
    learner process this one replaces are answered `expired`: nobody waits for them. So are
    the calls this learner process parked before: a new call means it stopped waiting for them
    (it asks again when a reply is overdue, `hercs.learner.prefetch.ASK_AGAIN_S`), and served
    they would only draw minibatches no update uses."""
    incarnation = call.learner_incarnation
    if not incarnation:  # a learner that does not say: counted as served
        return current
    before = limiter.samples
    limiter.resync_samples(call.samples_kept)
    if incarnation == current:
        if before != call.samples_kept:
            log.debug("learner %s kept %d minibatches, %d counted: recounted",
                      incarnation, call.samples_kept, before)
        expired = _expire(samples, lambda item: item.call.learner_incarnation == incarnation,
                          "the learner asked again: it stopped waiting for this call")
        if expired:
            log.debug("learner %s asked again; %d earlier call(s) answered expired",
                      incarnation, expired)
        return current
    if current is not None or before != call.samples_kept:
        log.info("learner %s: the rate limiter counts %d minibatches sampled (was %d), "
                 "the learner's kept updates", incarnation, call.samples_kept, before)
    _expire(samples, lambda item: item.call.learner_incarnation != incarnation,
            "a newer learner process took over this run")
    return incarnation


def _expire(samples: deque[ParkedSample], which: Callable[[ParkedSample], bool], why: str) -> int:
    """Answer `expired` (`why`) to the parked sample calls `which(item)` picks; their count."""
    stale = [item for item in samples if which(item)]
    for item in stale:
        samples.remove(item)
        for waiter in item.waiters:
            waiter.fail(Reason.EXPIRED, why)
    return len(stale)
