"""`PolicyLagLedger`: the replay's record of how stale the stored episodes' policies are.

Two lags per stored episode (docs/DESIGN.md §9.1): against the learner's newest weights version
when the episode is stored (`policy_lag_request`), and against the cycle the episode holds in
the lockstep schedule (`policy_lag`, what the lag bound limits). Recent ones are averaged into
the counters; every schedule lag since the last sample call travels with the next served batch.
Pure bookkeeping, driven by `ReplayTable` under its lock.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from hercs.reasons import Reason
from hercs.replay_service.lag_bound import PolicyLagBound
from hercs.replay_service.lockstep import schedule_cycle

POLICY_LAG_WINDOW = 64
"""Recent episodes whose policy lags are averaged into each served batch's counters."""
POLICY_LAGS_KEPT = 65536
"""At most this many per-episode lags wait for the next sample call (`ServedBatch.policy_lags`);
the rate limiter keeps far fewer, unless it runs free with no learner sampling."""
INT64_MIN, INT64_MAX = -(1 << 63), (1 << 63) - 1


class PolicyLagLedger:
    def __init__(self, episodes_per_cycle: int) -> None:
        self.episodes_per_cycle = episodes_per_cycle
        self._learner_version = 0
        self._recent_lags: deque[int] = deque(maxlen=POLICY_LAG_WINDOW)
        self._recent_schedule_lags: deque[int] = deque(maxlen=POLICY_LAG_WINDOW)
        self._since_sample: deque[int] = deque(maxlen=POLICY_LAGS_KEPT)
        self.newest_request_version: int | None = None
        """The weights version of the latest sample call served (not the highest ever: a
        restarted learner counts from its checkpoint again); None before the first, when the
        lag bound refuses nothing (actors act with their own initial policy until then) and
        after a recovery until that call places the recovered episodes in the schedule."""
        self._schedule_offset = 0
        """Episode ids left out of the lockstep schedule that `policy_lag` measures against:
        after a recovery in the asynchronous schedule, the whole cycles the log holds beyond
        the resumed learner's weights version (episodes acted after its last checkpoint), so
        that a restart does not read as 50 cycles of lag. The limiter restarts balanced for
        the same reason."""
        self._recovered_unplaced: int | None = None
        """Recovered episodes whose place in the schedule waits for the learner's first
        sample call (its weights version); no schedule lag is recorded until then."""

    def recovered(self, count: int) -> None:
        """`count` episodes came back from the log; place them at the next sample call."""
        self._recovered_unplaced = count

    def cycle_of(self, episode_id: int) -> int:
        """The lockstep-schedule cycle that policy lag measures episode `episode_id` against."""
        return schedule_cycle(episode_id - self._schedule_offset, self.episodes_per_cycle)

    def stored(self, episode_id: int, policy_version: int) -> None:
        """An episode acted with `policy_version` was stored under `episode_id`."""
        self._recent_lags.append(self._learner_version - policy_version)
        if self._recovered_unplaced is None:
            # an int64 version far below -1 (valid on the wire) must not overflow the Batch
            lag = min(max(self.cycle_of(episode_id) - policy_version, INT64_MIN), INT64_MAX)
            self._recent_schedule_lags.append(lag)
            self._since_sample.append(lag)

    def serving(self, weights_version: int) -> None:
        """A sample call of the learner at `weights_version` is being served."""
        self._learner_version = max(self._learner_version, weights_version)
        if self._recovered_unplaced is not None:
            surplus = self._recovered_unplaced // self.episodes_per_cycle - weights_version
            self._schedule_offset = max(0, surplus) * self.episodes_per_cycle
            self._recovered_unplaced = None
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
