"""How the replay table admits inserts and serves samples in its run's schedule: one policy
object behind the small `Admission` interface the table calls at each step, so the table has
no branch on the schedule. `AsynchronousAdmission` is the rate limiter's window with the
policy-lag bound (`training.max_policy_lag`); `LockstepAdmission` (hercs.replay_service.lockstep)
admits by cycle, and the limiter only counts. The builder (hercs.replay_service.builder) picks
the one of the run's schedule.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from typing import Protocol

from hercs.reasons import Reason
from hercs.replay_service.lag_bound import PolicyLagBound
from hercs.replay_service.policy_lag import PolicyLagLedger
from hercs.replay_service.rate_limiter import SampleToInsertRatio
from hercs.replay_service.table_calls import ParkedSample

Refusal = tuple[Reason, str]


class Admission(Protocol):
    """The schedule's rules, asked by the table under its lock; pure bookkeeping."""

    def refuse_insert(self, policy_version: int) -> Refusal | None:
        """Why an arriving episode acted with `policy_version` is refused at once, or None."""
        ...

    def refuse_admitted(self, policy_version: int, next_episode_id: int) -> Refusal | None:
        """Why an insert the limiter just admitted, to be stored under `next_episode_id`, is
        refused after all, or None."""
        ...

    def admit(self, policy_version: int) -> None:
        """An arriving episode was parked (its answer comes once it is stored or refused)."""
        ...

    def cancel(self, policy_version: int) -> None:
        """A parked episode will not be stored (its log append failed)."""
        ...

    def store(self, policy_version: int) -> None:
        """An admitted episode was stored."""
        ...

    def next_policy_version(self, policy_version: int, next_episode_id: int) -> int:
        """For an ack of an episode acted with `policy_version`: the oldest weights version the
        actor's next episode may use."""
        ...

    def take_servable(self, samples: deque[ParkedSample], *, failures: int,
                      fitted_at: int | None, now: float) -> list[ParkedSample]:
        """Remove from `samples` and return the calls to serve now, given the failed episodes
        stored and the failure count the cluster model was fitted at (None: no model)."""
        ...

    def served(self, weights_version: int, *, failures: int, fitted_at: int | None,
               model_version: int) -> str | None:
        """A call of `weights_version` was served; a warning to log, or None."""
        ...

    def recovered(self, policy_versions: Iterable[int]) -> None:
        """Count the episodes a restarted replay recovered from its log."""
        ...

    def stored_per_version(self) -> dict[int, int]:
        """Episodes stored per policy version, for a saved replay state (empty: not kept)."""
        ...

    def describe(self, *, inserts_waiting: int, samples_waiting: int) -> str:
        """A short word for ReplayStatus.rate_limiter."""
        ...


class AsynchronousAdmission:
    """The asynchronous schedule: the limiter's window decides both sides, samples are served
    in arrival order, and the lag bound (None: no bound) refuses an insert the limiter admits
    whose policy would lag its cycle by more than the bound."""

    def __init__(self, *, limiter: SampleToInsertRatio, lags: PolicyLagLedger,
                 lag_bound: PolicyLagBound | None) -> None:
        self.limiter = limiter
        self.lags = lags
        self.lag_bound = lag_bound

    def refuse_insert(self, policy_version: int) -> Refusal | None:
        return None

    def refuse_admitted(self, policy_version: int, next_episode_id: int) -> Refusal | None:
        return self.lags.bound_refusal(self.lag_bound, policy_version, next_episode_id)

    def admit(self, policy_version: int) -> None:
        pass

    def cancel(self, policy_version: int) -> None:
        pass

    def store(self, policy_version: int) -> None:
        pass

    def next_policy_version(self, policy_version: int, next_episode_id: int) -> int:
        """0 without a lag bound (any weights will do)."""
        return self.lags.bound_next_version(self.lag_bound, next_episode_id)

    def take_servable(self, samples: deque[ParkedSample], *, failures: int,
                      fitted_at: int | None, now: float) -> list[ParkedSample]:
        """The oldest call, if the limiter admits it: one at a time, since each served call
        moves the window."""
        if samples and self.limiter.can_sample(samples[0].call.num_minibatches):
            return [samples.popleft()]
        return []

    def served(self, weights_version: int, *, failures: int, fitted_at: int | None,
               model_version: int) -> str | None:
        return None

    def recovered(self, policy_versions: Iterable[int]) -> None:
        pass

    def stored_per_version(self) -> dict[int, int]:
        return {}

    def describe(self, *, inserts_waiting: int, samples_waiting: int) -> str:
        return self.limiter.describe(inserts_waiting=inserts_waiting,
                                     samples_waiting=samples_waiting)

