"""`PolicyLagLedger`: the replay's record of how stale the stored episodes' policies are.

Two lags per stored episode (docs/DESIGN.md §9.1): against the learner's newest weights at
storage (`policy_lag_request`) and against its lockstep cycle (`policy_lag`, what the lag bound
limits). Recent lags are averaged into the counters; every schedule lag since the last sample
call travels with the next served batch. The lag's derivation is `PolicyLagLedger`'s
docstring. Pure bookkeeping, driven by `ReplayTable` under its lock.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from hercs.reasons import Reason
from hercs.replay_service.lag_bound import PolicyLagBound
from hercs.replay_service.lockstep import schedule_cycle

POLICY_LAG_WINDOW = 64
"""Recent episodes whose policy lags are averaged into `ReplayCounters.policy_lag`."""
POLICY_LAGS_KEPT = 65536
"""At most this many per-episode lags wait for the next sample call (`ServedBatch.policy_lags`);
the rate limiter keeps far fewer, unless it runs free with no learner sampling."""
INT64_MAX = (1 << 63) - 1


class PolicyLagLedger:
    """Why the lag is never negative and needs no correction after a restart: episode ids run
    on through every restart (the log keeps them), and a learner at weights version v has
    kept 40·v minibatches (per cycle: `training.minibatches_per_cycle`), which the rate
    limiter follows through every restart (`learner_follow`). Its lower bound
    d = ρ·I − S ≥ ρ·N_min − E is 0 with the defaults (ρ = 10, N_min = 4, E = 40), so
    version v was published only once I ≥ v·episodes_per_cycle episodes were stored, and an
    episode acted with it is stored with an id ≥ that: its cycle is ≥ v. Three things break
    that premise, and each reads as 0, never below: a window wider than that (E > ρ·N_min)
    or `--free-run` (the learner runs ahead of lockstep: fresher than the schedule, not
    staler), and an episode log cut short (a torn tail: the ids restart below the learner's
    count, so the episodes it lost count as stored when the lag is taken). An episode acted
    with a version no learner can have published is refused instead (`future_refusal`)."""

    def __init__(self, episodes_per_cycle: int, *, prefetch_depth: int = 0) -> None:
        self.episodes_per_cycle = episodes_per_cycle
        self.versions_ahead = 1 + prefetch_depth
        """How far past the newest announced version the learner can have published: it
        publishes v + 1 after a request of version v is served, and each batch prefetched
        ahead (`learner.prefetch_depth`) lets it publish one more before it asks again."""
        self.highest_announced: int | None = None
        """The highest weights version a sample request has carried (on arrival, before the
        limiter parks it) or a recovered episode was acted with; None before either."""
        self._learner_version = 0
        self._recent_lags: deque[int] = deque(maxlen=POLICY_LAG_WINDOW)
        self._recent_schedule_lags: deque[int] = deque(maxlen=POLICY_LAG_WINDOW)
        self._since_sample: deque[int] = deque(maxlen=POLICY_LAGS_KEPT)
        self.newest_request_version: int | None = None
        """The weights version of the latest sample call served (not the highest ever: a
        restarted learner counts from its checkpoint again). Before the first call it is None
        in a new run, where the lag bound refuses nothing (actors act with their own initial
        policy until then), and after a restart the newest version a recovered episode was
        acted with (`recovered`), so that the bound holds from the first insert on."""

    def recovered(self, newest_version: int | None) -> None:
        """A restarted replay recovered episodes acted with weights up to `newest_version`
        (None: no episode): those weights existed, so the learner's are at least as new
        until its first sample call says which version it is at."""
        if newest_version is not None:
            self.announced(int(newest_version))
        if newest_version is not None and self.newest_request_version is None:
            self.newest_request_version = int(newest_version)
            self._learner_version = max(self._learner_version, int(newest_version))

    def announced(self, weights_version: int) -> None:
        """A sample request of the learner at `weights_version` arrived (served or not)."""
        if self.highest_announced is None or weights_version > self.highest_announced:
            self.highest_announced = weights_version

    def future_refusal(self, policy_version: int) -> tuple[Reason, str] | None:
        """Why an episode acted with `policy_version` cannot be from this run's learner: no
        learner can have published it yet (a lag below zero), or None."""
        newest = 0 if self.highest_announced is None else self.highest_announced
        if policy_version <= newest + self.versions_ahead:
            return None
        return (Reason.FUTURE_POLICY,
                f"episode acted with weights version {policy_version}, but the learner has "
                f"published at most version {newest + self.versions_ahead} (its newest "
                f"request: version {newest}); an episode from a policy that does not exist "
                "yet would record a negative lag")

    def cycle_of(self, episode_id: int) -> int:
        """The lockstep-schedule cycle that policy lag measures episode `episode_id` against."""
        return schedule_cycle(episode_id, self.episodes_per_cycle)

    def stored(self, episode_id: int, policy_version: int) -> None:
        """An episode acted with `policy_version` was stored under `episode_id`."""
        # acted with weights newer than the learner's last request: as fresh as can be, 0
        self._recent_lags.append(max(0, self._learner_version - policy_version))
        # an int64 version far below -1 (valid on the wire) must not overflow the Batch; one
        # ahead of the schedule (class docstring) reads 0
        lag = min(max(self.cycle_of(episode_id) - policy_version, 0), INT64_MAX)
        self._recent_schedule_lags.append(lag)
        self._since_sample.append(lag)

    def serving(self, weights_version: int) -> None:
        """A sample call of the learner at `weights_version` is being served."""
        self._learner_version = max(self._learner_version, weights_version)
        self.newest_request_version = weights_version

    def bound_refusal(self, bound: PolicyLagBound | None, policy_version: int,
                      next_episode_id: int) -> tuple[Reason, str] | None:
        """The lag bound's refusal of an insert acted with `policy_version` that would be
        stored under `next_episode_id`; None: admitted (or no bound, or no request yet)."""
        newest = self.newest_request_version
        if bound is None or newest is None:
            return None
        return bound.refusal(policy_version=policy_version,
                             cycle=self.cycle_of(next_episode_id), newest_version=newest)

    def bound_next_version(self, bound: PolicyLagBound | None, next_episode_id: int) -> int:
        """For an ack: the oldest weights version the actor's next episode may use under the
        lag bound (0 without a bound or before the learner's first request)."""
        newest = self.newest_request_version
        if bound is None or newest is None:
            return 0
        return bound.next_policy_version(next_cycle=self.cycle_of(next_episode_id),
                                         newest_version=newest)

    def take_since_sample(self) -> np.ndarray:
        """The schedule lags stored since the last served call, for this one's batch."""
        lags = np.asarray(self._since_sample, np.int64)
        self._since_sample.clear()
        return lags

    @property
    def mean_schedule_lag(self) -> float:
        return float(np.mean(self._recent_schedule_lags or [0]))

    @property
    def mean_request_lag(self) -> float:
        return float(np.mean(self._recent_lags or [0]))
