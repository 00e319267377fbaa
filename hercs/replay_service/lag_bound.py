"""The bound on policy lag in the asynchronous schedule (`training.max_policy_lag`).

An episode's lag is its lockstep cycle minus its weights version; asynchronously it grows with
whatever lets episodes be stored before their weights exist (the limiter's surplus, prefetched
batches, the actor's queue). With a bound L an insert is checked when the limiter admits it,
when its cycle is known, and refused `stale_policy` if its lag would pass L and its weights
are older than the learner's newest; one acted with the newest weights is always admitted, so
the bound never holds every actor back, nor after a learner restart. A refused episode was
never stored or acked; acks carry the oldest version the next episode may use, so actors wait
for weights instead of acting episodes that would be refused. Pure bookkeeping under the
table's lock.
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
