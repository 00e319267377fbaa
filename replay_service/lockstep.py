"""The lockstep gate: the replay's admission rules when `training.schedule` is `lockstep`.

It replaces the rate limiter's window (docs/DESIGN.md §9.1). The learner asks for cycle c's
batch with `SampleRequest.weights_version = c`, the version it would broadcast after cycle
c − 1. Then:

- an insert acted with version p is refused as `stale_policy` when p is below the newest
  version the learner has asked with (the actor was slower than a broadcast), and as
  `cycle_full` when version p already has `episodes_per_cycle` episodes admitted; otherwise it
  is admitted at once (nothing waits: the actors wait for weights instead);
- cycle c's request is served once `episodes_per_cycle` episodes acted with version c are
  stored and, for the cluster-balanced methods, once the cluster model due by then has been
  adopted: the reference refits k-means in the same process, before the next update, when
  every `cluster.fgb_size`-th failed goal arrives, so model version ⌊failures / fgb_size⌋ is
  due. The clusterer is a separate process that may be restarting: past `cluster_wait_s` of
  waiting the request is served with the model at hand and counted in `late_cluster_models`.

After a learner restart from its checkpoint, the versions it asks for again already have
their episodes: those cycles run again on the episodes stored for them. After a replay restart
the per-version counts are rebuilt from the recovered episodes (`recover`).

Pure bookkeeping under the table's lock; it never blocks.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable

from hercs.lockstep import LockstepReason


class LockstepGate:
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

    def refuse_insert(self, policy_version: int) -> tuple[LockstepReason, str] | None:
        """Why an episode acted with `policy_version` is refused, or None to admit it."""
        if policy_version < self.requested:
            return (LockstepReason.STALE_POLICY,
                    f"episode acted with weights version {policy_version}; the learner is "
                    f"collecting cycle {self.requested} (lockstep): act with version "
                    f"{self.requested} or newer")
        if self.admitted[policy_version] >= self.episodes_per_cycle:
            return (LockstepReason.CYCLE_FULL,
                    f"cycle {policy_version} already has its {self.episodes_per_cycle} "
                    "episodes (lockstep): wait for the next weights")
        return None

    def admit(self, policy_version: int) -> None:
        self.admitted[policy_version] += 1

    def cancel(self, policy_version: int) -> None:
        """An admitted episode was not stored (its log append failed)."""
        self.admitted[policy_version] -= 1

    def store(self, policy_version: int) -> None:
        self.stored[policy_version] += 1

    def next_policy_version(self, policy_version: int) -> int:
        """After storing an episode of `policy_version`: the oldest version the actor's next
        episode may be acted with (the next cycle's once this one is full)."""
        if self.admitted[policy_version] >= self.episodes_per_cycle:
            return policy_version + 1
        return max(policy_version, self.requested)

    def due_cluster_version(self, failures: int) -> int:
        return 0 if self.fgb_size is None else failures // self.fgb_size

    def can_sample(self, weights_version: int, *, failures: int, cluster_version: int,
                   waited_s: float) -> bool:
        """Whether cycle `weights_version`'s request may be served now; `waited_s` is how long
        it has been parked. Records the request's version as the newest asked for."""
        self.requested = max(self.requested, weights_version)
        if self.stored[weights_version] < self.episodes_per_cycle:
            return False
        if cluster_version >= self.due_cluster_version(failures):
            return True
        return waited_s >= self.cluster_wait_s

    def served(self, *, failures: int, cluster_version: int) -> None:
        if cluster_version < self.due_cluster_version(failures):
            self.late_cluster_models += 1

    def recover(self, policy_versions: Iterable[int]) -> None:
        """Count the episodes a restarted replay recovered from its log."""
        for version in policy_versions:
            self.admitted[int(version)] += 1
            self.stored[int(version)] += 1
        if self.stored:
            self.requested = max(self.requested, max(self.stored))
