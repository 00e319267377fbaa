"""What one invocation runs: the sizes and time windows of the full and the quick mode
(`Plan`), and the run's fixed settings."""

from __future__ import annotations

import dataclasses

RUN = "throughput"
SEED = 1
ACTOR_ID = "bench-actor"
K_CLUSTERS = 8
STORE_COLUMNS = ("obs", "ag", "g", "actions", "episode_id", "actor_id", "seq", "success",
                 "final_ag", "energy", "cluster", "policy_version")
"""The store's per-episode arrays (public views of `EpisodeStore`), for the raw byte count."""
EPISODE_POOL = 256
"""Distinct synthetic episodes cycled through by the synthetic actors."""
READY_TIMEOUT_S = 180.0
"""Longest wait for a child to come up (imports on a loaded 2-core machine are slow) or for
the replay to recover its log."""
REQUEST_TIMEOUT_S = 60.0
STOP_GRACE_S = 15.0
MAX_REPLY_BYTES = 1 << 30
MEMORY_FIELDS = ("VmRSS", "RssAnon", "RssFile", "RssShmem", "VmHWM")
"""VmRSS = RssAnon (heap, numpy arrays) + RssFile (mapped code and files) + RssShmem (shared
memory: here Zenoh's pools, see `own_rss_mib`); VmHWM = peak VmRSS."""
NO_SCENE = "her-no-scene"
"""The config of the replay of its own that logs without scenes (`insert_rate`)."""


@dataclasses.dataclass(frozen=True)
class Plan:
    """Sizes and time windows of one invocation."""

    mode: str
    env_rounds: int
    """Rounds of (raw env slice, actor slice); one more raw slice closes the last round."""
    env_slice_s: float
    actor_warmup_episodes: int
    """Acked episodes the actor produces before the first round (start-up, first reset)."""
    learner_rounds: int
    """Rounds of (in-process slice, learner slice); one more in-process slice closes them."""
    learner_slice_s: float
    """At most 4 s: the learner is paused (SIGSTOP) that long, within Zenoh's 5 s limit on a
    blocked link and its 10 s lease."""
    learner_warmup_cycles: int
    """Weights versions the learner broadcasts before the first round (start-up, first batch)."""
    minibatches_per_cycle: int
    learner_min_episodes: int
    """Episodes the replay holds (topped up with synthetic ones) before the learner starts."""
    insert_actor_counts: tuple[int, ...]
    insert_warmup_s: float
    insert_window_s: float
    insert_no_scene_counts: tuple[int, ...]
    """Insert levels measured again with `replay.log_scene=false` (a replay of its own)."""
    buffer_transitions: int
    sample_requests: int
    sample_warmup_requests: int
    sample_minibatches: int = 40
    sample_batch_size: int = 256
    methods: tuple[str, ...] = ("her", "her-cs", "her-ebp", "her-ebp-cs")
    actor_envs: int = 4
    """`actor.envs_per_process` of the measured actor."""
    roofline_updates: int = 400
    """Timed updates per precision against the GEMM limit (bench/perf/learner.py)."""
    roofline_gemms: int = 2000
    """Timed 256×256×256 products per precision for the core's GEMM rate."""


FULL = Plan(mode="full", env_rounds=12, env_slice_s=2.5, actor_warmup_episodes=3,
            learner_rounds=8, learner_slice_s=4.0, learner_warmup_cycles=2,
            minibatches_per_cycle=40, learner_min_episodes=200,
            insert_actor_counts=(1, 2, 4, 8, 16), insert_warmup_s=1.0, insert_window_s=10.0,
            insert_no_scene_counts=(8, 16), buffer_transitions=1_000_000,
            sample_requests=200, sample_warmup_requests=5)
QUICK = Plan(mode="quick", env_rounds=2, env_slice_s=1.0, actor_warmup_episodes=1,
             learner_rounds=2, learner_slice_s=1.5, learner_warmup_cycles=1,
             minibatches_per_cycle=10, learner_min_episodes=20,
             insert_actor_counts=(1, 2), insert_warmup_s=0.3, insert_window_s=1.5,
             insert_no_scene_counts=(2,), buffer_transitions=25_000, sample_requests=20,
             sample_warmup_requests=2,
             methods=("her", "her-cs"), actor_envs=2, roofline_updates=10,
             roofline_gemms=200)
