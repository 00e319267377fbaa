"""The cluster model of HER-CS and nearest-centroid assignment, shared by clusterer and replay.

The clusterer fits k-means on failed desired goals and publishes a `ClusterModel`; the replay
labels each stored episode by the centroid nearest to its last achieved goal ag_T
(`assign_clusters`), all episodes on a new model and each new episode on insert.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(eq=False)
class ClusterModel:
    """One k-means fit of the failed-goal buffer.

    Invariants (checked): version >= 1, centroids float32 of shape (k, goal_dim), finite.
    """

    version: int
    """1 for the first fit, +1 per refit."""
    centroids: np.ndarray
    """(k, goal_dim) float32 cluster centres."""
    n_goals: int
    """Failed goals the model was fitted on (the buffer's capacity)."""
    failures_seen: int
    """Failed episodes the clusterer had counted when it fitted this model (the fit point
    from which the lockstep gate counts `fgb_size` more failures, docs/DESIGN.md §9.1)."""

    def __post_init__(self) -> None:
        self.centroids = np.ascontiguousarray(self.centroids, dtype=np.float32)
        if self.version < 1:
            raise ValueError(f"ClusterModel.version: got {self.version!r}, must be >= 1")
        if self.centroids.ndim != 2 or self.centroids.shape[0] < 1:
            raise ValueError(f"ClusterModel.centroids: got shape {self.centroids.shape}, "
                             "must be (k, goal_dim) with k >= 1")
        if not np.all(np.isfinite(self.centroids)):
            raise ValueError("ClusterModel.centroids: holds NaN or Inf")

    @property
    def k(self) -> int:
        return int(self.centroids.shape[0])

    def assign(self, points: np.ndarray) -> np.ndarray:
        """Cluster index (int32) of each row of `points` (N, goal_dim)."""
        return assign_clusters(points, self.centroids)


def assign_clusters(points: np.ndarray, centroids: np.ndarray) -> np.ndarray:
    """Index of the nearest centroid (squared Euclidean, float64) per point, as int32.

    points (N, d), centroids (k, d) → labels (N,). Ties go to the lowest index. Works in
    O(N·k·d) memory, which is small for the replay's ≤ 20,000 episodes and k = 8.
    """
    p = np.asarray(points, dtype=np.float64)
    c = np.asarray(centroids, dtype=np.float64)
    if p.ndim != 2 or c.ndim != 2 or p.shape[1] != c.shape[1] or c.shape[0] < 1:
        raise ValueError(f"assign_clusters: got points {p.shape} and centroids {c.shape}, "
                         "need (N, d) and (k, d) with k >= 1")
    d2 = np.square(p[:, None, :] - c[None, :, :]).sum(axis=-1)
    return np.argmin(d2, axis=1).astype(np.int32)
