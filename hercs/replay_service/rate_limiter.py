"""Sample-to-insert rate limiter (Reverb's SampleToInsertRatio, restated for hercs).

With I episodes inserted, S minibatches sampled and ρ = updates_per_episode, the surplus
d = ρ·I − S stays within E of ρ·N_min: an insert is admitted while the window has room (else the
actor waits), a request for n minibatches once I ≥ N_min and the window allows it (else the
learner waits). So updates per episode stay at ρ up to a bounded error (docs/DESIGN.md §4.7).
A window narrower than one request plus one insert could hold both sides at once, so the
constructor refuses 2E < n_max + ρ (`hercs.config.replay.least_rate_tolerance`, the rule the
config checks too). With `free_run` everything is admitted and the counts are still kept. Pure
bookkeeping, it never blocks: the service parks what is not admitted and retries it after every
insert or sample.
"""

from __future__ import annotations

from dataclasses import dataclass

from hercs.config import least_rate_tolerance
from hercs.errors import ConfigError


@dataclass
class RateLimiterState:
    inserts: int
    samples: int
    surplus: float
    min_surplus: float
    max_surplus: float


class SampleToInsertRatio:
    def __init__(
        self,
        *,
        samples_per_insert: float,
        min_size_to_sample: int,
        error_buffer: float,
        max_request: int,
        free_run: bool = False,
    ) -> None:
        if samples_per_insert <= 0:
            raise ConfigError(f"samples_per_insert: got {samples_per_insert}, must be > 0")
        if min_size_to_sample < 1:
            raise ConfigError(f"min_size_to_sample: got {min_size_to_sample}, must be >= 1")
        least = least_rate_tolerance(max_request=max_request,
                                     samples_per_insert=samples_per_insert)
        if not free_run and error_buffer < least:
            raise ConfigError(
                f"replay.rate_tolerance_updates: got {error_buffer}, must be at least "
                f"(max_request + samples_per_insert)/2 = {least} or inserts and samples "
                "could both wait forever"
            )
        self.samples_per_insert = float(samples_per_insert)
        self.min_size_to_sample = int(min_size_to_sample)
        self.error_buffer = float(error_buffer)
        self.max_request = int(max_request)
        self.free_run = free_run
        self.inserts = 0
        self.samples = 0
        self.pending_inserts = 0
        """Admitted inserts not yet stored (their group is being logged): they count against
        the insert bound at once, and towards samples only once stored."""
        center = self.samples_per_insert * self.min_size_to_sample
        self.min_surplus = center - self.error_buffer
        self.max_surplus = center + self.error_buffer

    @property
    def surplus(self) -> float:
        return self.samples_per_insert * self.inserts - self.samples

    def can_insert(self) -> bool:
        pending = self.samples_per_insert * self.pending_inserts
        return self.free_run or self.surplus + pending + self.samples_per_insert <= \
            self.max_surplus

    def can_sample(self, num_minibatches: int) -> bool:
        if self.inserts < self.min_size_to_sample:
            return False
        return self.free_run or self.surplus - num_minibatches >= self.min_surplus

    def max_admissible_sample(self) -> float:
        """The largest request admitted whatever the history: inserts stop once d would pass
        d_max, so d always gets above d_max − ρ, and a request of n is admitted at d when
        d − n ≥ d_min; hence n ≤ 2E − ρ (unbounded in free run)."""
        if self.free_run:
            return float("inf")
        return 2 * self.error_buffer - self.samples_per_insert

    def could_ever_sample(self, num_minibatches: int) -> bool:
        """False for a request that would wait forever (and, first in line, hold every later
        request behind it)."""
        return num_minibatches <= self.max_admissible_sample()

    def admit_insert(self) -> None:
        """An insert was admitted; it is stored later (`store_admitted`) or
        given up (`cancel_inserts`)."""
        self.pending_inserts += 1

    def store_admitted(self) -> None:
        """An admitted insert is now stored."""
        if self.pending_inserts < 1:
            raise ValueError("store_admitted: no admitted insert is pending")
        self.pending_inserts -= 1
        self.inserts += 1

    def cancel_inserts(self, count: int) -> None:
        """Give up `count` admitted inserts that were never stored (their log append failed)."""
        if not 0 <= count <= self.pending_inserts:
            raise ValueError(f"cancel_inserts({count}): only {self.pending_inserts} pending")
        self.pending_inserts -= count

    def record_sample(self, num_minibatches: int) -> None:
        self.samples += num_minibatches

    def describe(self, *, inserts_waiting: int, samples_waiting: int) -> str:
        """A short word for ReplayStatus.rate_limiter."""
        if self.free_run:
            return "free-run"
        if self.inserts < self.min_size_to_sample:
            return "filling"
        if samples_waiting:
            return "holding-samples"
        if inserts_waiting:
            return "holding-inserts"
        return "ok"

    def state(self) -> RateLimiterState:
        return RateLimiterState(self.inserts, self.samples, self.surplus, self.min_surplus,
                                self.max_surplus)

    def resync_samples(self, samples: int) -> None:
        """Count `samples` minibatches sampled: what the learner's run has really kept, told
        by a learner process new to this replay. After a learner restart this is less than
        was served (the updates since its checkpoint were lost), so the surplus grows and the
        learner redoes them before more inserts are admitted; after a replay restart it
        replaces `restart_balanced`'s guess."""
        if samples < 0:
            raise ValueError(f"resync_samples: got {samples}, must be >= 0")
        self.samples = int(samples)

    def restart_balanced(self, inserts: int) -> None:
        """A restarted replay recovered `inserts` episodes from its log: count them as inserted
        and as sampled at exactly the ratio (the samples of its previous life are unknown),
        so that neither side is held for history it cannot see."""
        if inserts < 0:
            raise ValueError(f"restart_balanced: got {inserts} inserts, must be >= 0")
        self.inserts = int(inserts)
        self.samples = int(inserts * self.samples_per_insert)
