"""Synthetic episodes with valid shapes and random contents, which the benchmarks and the
tests feed the replay, the codec and the episode log with (hercs' own episodes come from
rollouts)."""

from __future__ import annotations

import numpy as np

from hercs.rl.task_registry import TaskSpec
from hercs.wire.episode import EpisodeData, expected_shapes


def random_episode(spec: TaskSpec, rng: np.random.Generator, *, actor_id: str = "test",
                   seq: int = 0) -> EpisodeData:
    """An episode of `spec`'s shapes: normal observations, uniform achieved goals and actions
    in [-1, 1], one uniform desired goal held for the whole episode (as Fetch's is)."""
    shapes = expected_shapes(spec)
    g = np.repeat(rng.uniform(-1, 1, size=(1, spec.goal_dim)), spec.episode_steps, axis=0)
    return EpisodeData(
        obs=rng.standard_normal(shapes["obs"]).astype(np.float32),
        ag=rng.uniform(-1, 1, size=shapes["ag"]).astype(np.float32),
        g=g.astype(np.float32),
        actions=rng.uniform(-1, 1, size=shapes["actions"]).astype(np.float32),
        actor_id=actor_id,
        seq=seq,
    )
