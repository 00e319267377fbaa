"""The bound on policy lag in the asynchronous schedule (`training.max_policy_lag`).

An episode's policy lag is its cycle in the lockstep schedule
(`hercs.replay_service.lockstep.schedule_cycle`
of the id it is stored under) minus the weights version it was acted with: 0 in lockstep,
where cycle c's episodes are acted with version c. Asynchronously it grows with everything
that lets episodes be stored before their weights exist: the rate limiter's surplus, the
learner's prefetched batches, the actor's queue (docs/DESIGN.md §9.1).

With a bound L the replay checks each insert when the rate limiter admits it (so the cycle it
would get is known): it is refused as `stale_policy` when its lag would pass L *and* it was
acted with weights older than the learner's newest (the version of the latest sample request).
An episode acted with the newest weights is always admitted: the bound can never hold every
actor back while the learner waits for their episodes, whatever the limiter and prefetch allow,
and it still is when a restarted learner counts from an older version. A refused episode was
never stored nor acknowledged (nothing acked is dropped); the actor drops it and acts the next
with newer weights. Acks carry the oldest version the actor's next episode may use, so actors
wait for weights instead of acting episodes that would be refused.

Pure bookkeeping under the table's lock.
"""

from __future__ import annotations

from hercs.reasons import Reason


class PolicyLagBound:
    def __init__(self, *, max_lag: int) -> None:
        if max_lag < 1:
            raise ValueError(f"PolicyLagBound max_lag: got {max_lag}, must be >= 1 "
                             "(lag 0 is the lockstep schedule)")
        self.max_lag = int(max_lag)

    def refusal(self, *, policy_version: int, cycle: int,
                newest_version: int) -> tuple[Reason, str] | None:
        """Why an episode acted with `policy_version`, to be stored in `cycle`, is refused
        while the learner's newest weights are `newest_version`; None to admit it."""
        lag = cycle - policy_version
        if lag <= self.max_lag or policy_version >= newest_version:
            return None
        return (Reason.STALE_POLICY,
                f"episode acted with weights version {policy_version} would be stored in "
                f"cycle {cycle}: {lag} cycles of policy lag, more than "
                f"training.max_policy_lag={self.max_lag}; act with version "
                f"{self.next_policy_version(next_cycle=cycle, newest_version=newest_version)}"
                " or newer")

    def next_policy_version(self, *, next_cycle: int, newest_version: int) -> int:
        """The oldest weights version an episode stored in `next_cycle` may be acted with:
        within the bound, but never newer than the newest weights there are."""
        return max(0, min(next_cycle - self.max_lag, newest_version))
