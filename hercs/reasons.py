"""The one vocabulary of error-reply reasons, each tagged with what a client does on it.

`DROP`: can never succeed, drop and count it; `SUPERSEDED`: no longer wanted, drop quietly and
act with newer weights; `RETRY`: send the same bytes again after a backoff. A reason outside
this enum is retried with a warning, or raises with `HERCS_STRICT_REASONS=1` (the tests), so a
new reason without a tag fails the tests rather than silently meaning "retry".
"""

from __future__ import annotations

import os
from enum import StrEnum


class Disposition(StrEnum):
    DROP = "drop"
    SUPERSEDED = "superseded"
    RETRY = "retry"


class Reason(StrEnum):
    disposition: Disposition

    def __new__(cls, value: str, disposition: Disposition) -> Reason:
        member = str.__new__(cls, value)
        member._value_ = value
        member.disposition = disposition
        return member

    # the message is malformed (hercs.wire.validation, hercs.wire.codec)
    UNDECODABLE = "undecodable", Disposition.DROP
    OVERSIZED = "oversized", Disposition.DROP
    SCHEMA_VERSION = "schema_version", Disposition.DROP
    UNKNOWN_RUN = "unknown_run", Disposition.DROP
    WRONG_TASK = "wrong_task", Disposition.DROP
    MISSING_FIELD = "missing_field", Disposition.DROP
    BAD_ARRAY = "bad_array", Disposition.DROP
    BAD_DTYPE = "bad_dtype", Disposition.DROP
    BAD_SHAPE = "bad_shape", Disposition.DROP
    BAD_LENGTH = "bad_length", Disposition.DROP
    NON_FINITE = "non_finite", Disposition.DROP
    BAD_VALUE = "bad_value", Disposition.DROP
    IMPLAUSIBLE = "implausible", Disposition.DROP
    """Finite and well formed, but a value lies more than 1,000 std from the running
    statistics (hercs.rl.plausibility): an episode that would poison the normalisers."""
    UNKNOWN_EPISODE = "unknown_episode", Disposition.DROP
    """An `EpisodeRequest` for an id the replay does not hold (never inserted, or overwritten
    by the ring): a miss, not bad input, so it is not counted in `ReplayStatus.rejects`."""
    # well formed, not wanted (hercs.replay_service.lockstep, hercs.replay_service.lag_bound)
    STALE_POLICY = "stale_policy", Disposition.SUPERSEDED
    """Acted with weights older than the lockstep cycle or the lag bound allows."""
    FUTURE_POLICY = "future_policy", Disposition.SUPERSEDED
    """Acted with a weights version newer than any the learner can have published (its
    newest request's version + 1 + `learner.prefetch_depth`): forged or corrupt, or, after
    a replay restart, one whose learner has not asked yet; an honest actor loses one episode
    and acts again with the weights it gets next (hercs.replay_service.policy_lag)."""
    CYCLE_FULL = "cycle_full", Disposition.SUPERSEDED
    """Lockstep: its cycle already has its `episodes_per_cycle` episodes."""
    # not now (hercs.replay_service.table, hercs.net.transport)
    EXPIRED = "expired", Disposition.RETRY
    """The rate limiter held the call past its caller's timeout."""
    LOG_FAILED = "log_failed", Disposition.RETRY
    """The episode log append failed (disk full, I/O error): neither stored nor acked."""
    UNAVAILABLE = "unavailable", Disposition.RETRY
    """The service is shutting down, or closed before answering."""
    INTERNAL = "internal", Disposition.RETRY
    """The handler raised; the error is logged where it happened."""
    TRANSPORT = "transport", Disposition.RETRY
    """Zenoh itself answered with an error (not a hercs reply); the detail is its text."""
    ACTOR_QUEUE_FULL = "actor_queue_full", Disposition.RETRY
    """Fair sharing: this actor id already has `replay.waiting_inserts_per_actor` inserts
    waiting for the rate limiter (hercs.replay_service.parked_calls); its backoff slows it."""


_BY_VALUE: dict[str, Reason] = {r.value: r for r in Reason}


class UnknownReason(ValueError):
    """An error reply named a reason outside `Reason` (strict mode only)."""


def disposition(reason: str) -> Disposition:
    """What a client does on an error reply naming `reason`."""
    known = _BY_VALUE.get(reason)
    if known is not None:
        return known.disposition
    if os.environ.get("HERCS_STRICT_REASONS") == "1":
        raise UnknownReason(f"error-reply reason {reason!r} is not in hercs.reasons.Reason; "
                            "add it there with its disposition")
    return Disposition.RETRY
