"""The lockstep admission: the replay's rules when `training.schedule` is `lockstep`.

It replaces the rate limiter's window (docs/DESIGN.md §9.1 states the rules): an insert is
admitted at once or refused (`stale_policy`, `cycle_full`), and cycle c is served once its
episodes are stored and, for the clustered methods, no refit is due (waited for at most
`cluster_wait_s`: the clusterer is another process and may be restarting; such a cycle is
counted in `late_cluster_models` and no later cycle waits for that refit again). After a
replay restart the per-version counts are rebuilt from the recovered episodes. Pure
bookkeeping under the table's lock (which calls it through hercs.replay_service.admission's
`Admission`); it never blocks.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Iterable

from hercs.reasons import Reason
from hercs.replay_service.table_calls import ParkedSample


def schedule_cycle(episode_id: int, episodes_per_cycle: int) -> int:
    """The cycle episode `episode_id` belongs to in the lockstep schedule, which is also the
    weights version it would have been acted with there: cycle c is `episodes_per_cycle`
    episodes acted with version c, then the learner's updates on a buffer holding them, as
    the reference's single process alternates, so episode i (its id, from 0) is in cycle
    i // episodes_per_cycle."""
    return int(episode_id) // int(episodes_per_cycle)

LOCKSTEP_CLUSTER_WAIT_S = 30.0
"""How long a sample waits for a cluster model that is due before it is served with the model
at hand (the clusterer may be restarting)."""


class LockstepAdmission:
    def __init__(self, *, episodes_per_cycle: int, fgb_size: int | None,
                 cluster_wait_s: float) -> None:
        """`fgb_size` None: the method has no clusters, no model is ever due."""
        self.episodes_per_cycle = int(episodes_per_cycle)
        self.fgb_size = fgb_size
        self.cluster_wait_s = float(cluster_wait_s)
        self.admitted: Counter[int] = Counter()
        """Episodes admitted (being logged or stored) per policy version."""
        self.stored: Counter[int] = Counter()
        """Episodes stored per policy version."""
        self.requested = 0
        """Newest weights version the learner has asked a batch for."""
        self.late_cluster_models = 0
        """Requests served with an older cluster model than was due (the clusterer was late
        by more than `cluster_wait_s`)."""
        self._first_asked: dict[int, float] = {}
        """When each cycle not yet served was first asked for (the grace is per cycle, not per
        retried request)."""
        self._waived_fit: int | None = None
        """The refit (by failure count) this admission stopped waiting for."""

    def refuse_insert(self, policy_version: int) -> tuple[Reason, str] | None:
        """Why an episode acted with `policy_version` is refused, or None to admit it."""
        if policy_version < self.requested:
            return (Reason.STALE_POLICY,
                    f"episode acted with weights version {policy_version}; the learner is "
                    f"collecting cycle {self.requested} (lockstep): act with version "
                    f"{self.requested} or newer")
        if self.admitted[policy_version] >= self.episodes_per_cycle:
            return (Reason.CYCLE_FULL,
                    f"cycle {policy_version} already has its {self.episodes_per_cycle} "
                    "episodes (lockstep): wait for the next weights")
        return None

    def refuse_admitted(self, policy_version: int, next_episode_id: int
                        ) -> tuple[Reason, str] | None:
        """None: an insert is refused only on arrival (`refuse_insert`)."""
        return None

    def admit(self, policy_version: int) -> None:
        self.admitted[policy_version] += 1

    def cancel(self, policy_version: int) -> None:
        """An admitted episode was not stored (its log append failed)."""
        self.admitted[policy_version] -= 1

    def store(self, policy_version: int) -> None:
        self.stored[policy_version] += 1

    def next_policy_version(self, policy_version: int, next_episode_id: int = 0) -> int:
        """After storing an episode of `policy_version`: the oldest version the actor's next
        episode may be acted with (the next cycle's once this one is full; the episode id
        does not matter here)."""
        if self.admitted[policy_version] >= self.episodes_per_cycle:
            return policy_version + 1
        return max(policy_version, self.requested)

    def next_fit(self, fitted_at: int | None) -> int | None:
        """The failure count at which the next refit is due: `fitted_at` (the current model's
        `failures_seen`, None before any model) plus `fgb_size`; None without clusters."""
        if self.fgb_size is None:
            return None
        return self.fgb_size if fitted_at is None else fitted_at + self.fgb_size

    def refit_due(self, *, failures: int, fitted_at: int | None) -> bool:
        due = self.next_fit(fitted_at)
        return due is not None and failures >= due and due != self._waived_fit

    def can_sample(self, weights_version: int, *, failures: int, fitted_at: int | None,
                   now: float) -> bool:
        """Whether cycle `weights_version`'s request may be served at time `now`. Records the
        request's version as the newest asked for, and when the cycle was first asked for."""
        self.requested = max(self.requested, weights_version)
        first = self._first_asked.setdefault(weights_version, now)
        if self.stored[weights_version] < self.episodes_per_cycle:
            return False
        if not self.refit_due(failures=failures, fitted_at=fitted_at):
            return True
        return now - first >= self.cluster_wait_s

    def take_servable(self, samples: deque[ParkedSample], *, failures: int,
                      fitted_at: int | None, now: float) -> list[ParkedSample]:
        """Every parked call whose cycle may be served, in any order: each names its own
        cycle, and one that can no longer be served (a dead learner's, for a cycle no actor
        got the weights of) must not hold a restarted learner's behind it."""
        ready: list[ParkedSample] = []
        waiting: list[ParkedSample] = []
        for item in samples:
            (ready if self.can_sample(item.call.weights_version, failures=failures,
                                      fitted_at=fitted_at, now=now) else waiting).append(item)
        samples.clear()
        samples.extend(waiting)
        return ready

    def served(self, weights_version: int, *, failures: int, fitted_at: int | None,
               model_version: int) -> str | None:
        """Cycle `weights_version` was served; with a refit overdue (then counted, and no
        later cycle waits for that refit again) the warning to log, else None."""
        self._first_asked.pop(weights_version, None)
        if not self.refit_due(failures=failures, fitted_at=fitted_at):
            return None
        self.late_cluster_models += 1
        due = self.next_fit(fitted_at)
        self._waived_fit = due
        return (f"lockstep: cycle {weights_version} served with cluster model "
                f"v{model_version}: the refit due at {due} failed goals did not arrive within "
                f"{self.cluster_wait_s:.0f} s (is the clusterer running?)")

    def recovered(self, policy_versions: Iterable[int]) -> None:
        """Count the episodes a restarted replay recovered from its log (once, all of them)."""
        for version in policy_versions:
            self.admitted[int(version)] += 1
            self.stored[int(version)] += 1
        if self.stored:
            self.requested = max(self.requested, max(self.stored))

    def stored_per_version(self) -> dict[int, int]:
        return dict(+self.stored)

    def describe(self, *, inserts_waiting: int, samples_waiting: int) -> str:
        return "lockstep"
