"""Which weights an actor's next episode must be acted with: the pure core of the actor's waits.

Asynchronous without a lag bound: never wait; asynchronous with `training.max_policy_lag` >= 1:
after an ack that asked for newer weights, wait for the next Weights, whatever its version;
lockstep: wait for weights of at least `min_version`. No clock, no threads.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum


class Need(Enum):
    NOTHING = "nothing"
    """Act now with the weights at hand."""
    VERSION = "version"
    """Wait for weights of at least `Wait.version` (lockstep)."""
    NEXT_ARRIVAL = "next arrival"
    """Wait for the next Weights to arrive, whatever its version (the lag bound)."""


@dataclass(frozen=True)
class Wait:
    need: Need
    version: int = 0


ACT_NOW = Wait(Need.NOTHING)


class WeightsSchedule:
    """The actor's side of the training schedule (module docstring)."""

    def __init__(self, *, schedule: str, max_policy_lag: int) -> None:
        self.lockstep = schedule == "lockstep"
        self.lag_bounded = not self.lockstep and max_policy_lag >= 1
        self.min_version = 0
        """Lockstep: the oldest weights version the next episode may be acted with."""

    def before_episode(self, *, policy_version: int, latest_ack_version: int) -> Wait:
        """What to wait for before the next episode, with weights `policy_version` at hand and
        `latest_ack_version` the `next_policy_version` of the latest ack.

        The lag bound waits for an arrival, not for a version number: a learner restarted
        from its checkpoint broadcasts lower versions than the acks before its restart asked
        for, and an actor waiting for those numbers would wait for ever while the learner
        waits for its episodes. The latest ack, not the highest, for the same reason. An
        ack's 0 asks for nothing: it is also what a replay without a bound, or before the
        learner's first sample call, answers."""
        if self.lockstep:
            return (Wait(Need.VERSION, self.min_version) if policy_version < self.min_version
                    else ACT_NOW)
        if self.lag_bounded and latest_ack_version > 0 and policy_version < latest_ack_version:
            return Wait(Need.NEXT_ARRIVAL)
        return ACT_NOW

    def after_outcome(self, *, acted_with: int, newest_ack_version: int,
                      superseded: bool) -> None:
        """Lockstep, once the inserts of the episodes acted with `acted_with` have ended:
        `newest_ack_version` is the highest version any ack asked for; `superseded`, whether
        the replay refused one of them as stale or surplus."""
        if not self.lockstep:
            return
        wanted = newest_ack_version
        if superseded:
            # only newer weights can make an episode wanted; a dropped (malformed) episode is
            # replaced by another acted with the same weights, or its cycle never completes
            wanted = max(wanted, acted_with + 1)
        self.min_version = max(self.min_version, wanted)
