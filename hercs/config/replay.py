"""The replay's section of the configuration tree (`replay.*`): its buffer, its admission
rules and its episode log. Import it from hercs.config."""

from __future__ import annotations

from dataclasses import dataclass

from hercs.config.checks import _check, _positive

EVICTIONS = ("fifo", "random")


def least_rate_tolerance(*, max_request: float, samples_per_insert: float) -> float:
    """The narrowest rate limiter window (`replay.rate_tolerance_updates`, E) that can never
    hold inserts and samples both: the surplus must have room for one request of
    `max_request` minibatches plus one insert's `samples_per_insert`, so 2E ≥ n_max + ρ."""
    return (max_request + samples_per_insert) / 2


@dataclass
class ReplayConfig:
    buffer_transitions: int = 1_000_000
    """Capacity in transitions; the store holds buffer_transitions // T episodes [HER-py]."""
    min_episodes_to_sample: int = 4
    """Samples wait until this many episodes are stored (one cycle's worth) [DESIGN]."""
    rate_tolerance_updates: float = 40.0
    """How far updates may run ahead of or behind updates_per_episode × inserts, in
    minibatches (Reverb's error_buffer); one cycle's worth by default. Each cycle of it is a
    cycle of policy lag in the asynchronous schedule: 40 is the least stale setting that
    kept the epoch time of the old default (80) side by side (docs/PERFORMANCE.md §2) [DESIGN]."""
    free_run: bool = False
    """Disable the rate limiter: inserts and samples never wait [DESIGN]."""
    max_message_bytes: int = 8 * 1024 * 1024
    """Larger wire messages are rejected as oversized [DESIGN]."""
    sample_timeout_s: float = 600.0
    """How long the learner waits for one Batch (the rate limiter may hold its request while
    actors catch up) before it asks again; the replay drops a request parked longer [DESIGN]."""
    insert_workers: int = 4
    """Threads serving inserts: inserts that arrive while one group is being fsynced form the
    next group (group commit), so several workers share fsyncs [DESIGN]."""
    waiting_inserts_per_actor: int = 4
    """Fair sharing while the rate limiter holds inserts: they are admitted round-robin across
    actor ids, and at most this many of one actor wait (more are answered `actor_queue_full`,
    a retry) [DESIGN]. 0: arrival order, no bound (docs/DESIGN.md §3)."""
    log_scene: bool = True
    """Also log each episode's Foxglove scene (/scene, /scene/points), off the ack path
    [DESIGN]; false keeps only the episodes, for the highest insert rates."""
    eviction: str = "fifo"
    """Which episode a full buffer overwrites: `fifo` the oldest [DESIGN]; `random` a slot
    drawn uniformly, as the reference does [HER-py] (reproducible: a hash of the run's seed
    and the episode id, so a restarted replay rebuilds the same buffer from its log)."""
    log_max_bytes: int = 0
    """The episode log's size bound, in bytes [DESIGN]. The replay closes its live segment
    every buffer/`log_segments_per_buffer` episodes and starts the next with its state
    (`/replay_state`); then it deletes the oldest segments whose episodes have all left the
    buffer, while the log is above this bound. 0: keep only what resume needs (the buffer's
    episodes and the newest state: at most 1 + 2/`log_segments_per_buffer` buffers' worth,
    1.5 by default); N > 0: also keep older segments while the log stays under N bytes; -1:
    never delete nor split the log (one growing segment per replay start, as before)."""
    log_segments_per_buffer: int = 4
    """With a bounded log (`log_max_bytes` >= 0), a segment holds a buffer's episodes divided
    by this (rounded up): the log's slack over what resume needs is two segments [DESIGN]."""

    def __post_init__(self) -> None:
        _check(self.buffer_transitions >= 1, "replay.buffer_transitions",
               self.buffer_transitions, "be >= 1")
        _check(self.min_episodes_to_sample >= 1, "replay.min_episodes_to_sample",
               self.min_episodes_to_sample, "be >= 1")
        _check(self.rate_tolerance_updates >= 0, "replay.rate_tolerance_updates",
               self.rate_tolerance_updates, "be >= 0")
        _check(self.max_message_bytes >= 1024, "replay.max_message_bytes",
               self.max_message_bytes, "be >= 1024")
        _positive("replay.sample_timeout_s", self.sample_timeout_s)
        _check(self.insert_workers >= 1, "replay.insert_workers", self.insert_workers,
               "be >= 1")
        _check(self.waiting_inserts_per_actor >= 0, "replay.waiting_inserts_per_actor",
               self.waiting_inserts_per_actor, "be >= 0 (0: arrival order, no bound)")
        _check(self.eviction in EVICTIONS, "replay.eviction", self.eviction,
               "be fifo or random")
        _check(self.log_max_bytes >= -1, "replay.log_max_bytes", self.log_max_bytes,
               "be -1 (keep the whole log), 0 (keep only what resume needs) or a size in "
               "bytes")
        _check(self.log_segments_per_buffer >= 1, "replay.log_segments_per_buffer",
               self.log_segments_per_buffer, "be >= 1 (segments per buffer's worth of "
               "episodes)")

    def log_segment_episodes(self, capacity_episodes: int) -> int:
        """Episodes per log segment for a buffer of `capacity_episodes`; 0: the log is not
        split (`log_max_bytes` -1)."""
        if self.log_max_bytes < 0:
            return 0
        return -(-capacity_episodes // self.log_segments_per_buffer)
