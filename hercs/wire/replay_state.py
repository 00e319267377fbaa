"""`ReplayState`: what a replay derived from the episodes inserted so far, beyond the episodes
its buffer holds. The replay logs one at the start of each log segment it opens while running
(`/replay_state`, hercs.run.runlog); a restarted replay starts from the newest one, then stores the
logged episodes from `first_held_id` on, so that the log's older segments may be deleted
(`replay.log_max_bytes`) without changing what resume rebuilds. Encoded by hercs.wire.codec."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hercs.rl.cluster_model import ClusterModel
from hercs.rl.normalizer import NormalizerState


@dataclass(frozen=True)
class ReplayState:
    next_episode_id: int
    """Episodes 0 .. next_episode_id − 1 made this state (the id the next insert gets)."""
    first_held_id: int
    """The oldest episode the buffer held then (0 while empty): a restarted replay needs the
    logged episodes from it on, so the log keeps them; the ones before may be deleted."""
    failures: int
    """Failed episodes among them (`ReplayTable.failures`)."""
    recent_failed_goals: np.ndarray
    """(≤ cluster.fgb_size, goal_dim) float32: desired goals of the newest failed episodes,
    oldest first."""
    o_stats: NormalizerState
    g_stats: NormalizerState
    """The observation and goal normalisers' statistics, as the running replay had them."""
    cluster_model: ClusterModel | None
    """The adopted cluster model, None before the first."""
    stored_per_version: dict[int, int] = field(default_factory=dict)
    """Lockstep: stored episodes per policy version (empty in the asynchronous schedule)."""

    def __post_init__(self) -> None:
        if not 0 <= self.first_held_id <= self.next_episode_id:
            raise ValueError(f"ReplayState: first_held_id={self.first_held_id} must be in "
                             f"[0, next_episode_id={self.next_episode_id}]")
        if self.failures < 0 or self.failures > self.next_episode_id:
            raise ValueError(f"ReplayState: failures={self.failures} must be in [0, "
                             f"next_episode_id={self.next_episode_id}]")
