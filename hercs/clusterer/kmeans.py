"""k-means refit of the failed goals (scikit-learn `KMeans`, seeded, k-means++ init)."""

from __future__ import annotations

import numpy as np
from sklearn.cluster import KMeans


def fit_cluster_model(goals: np.ndarray, *, k: int, seed: int, n_init: int) -> np.ndarray:
    """Centroids (k, goal_dim) float32 of k-means on `goals` (N, goal_dim), N >= k.

    Same goals, k, seed and n_init ⇒ the same centroids. Fitting runs in float64.
    """
    x = np.asarray(goals, dtype=np.float64)
    if x.ndim != 2 or x.shape[0] < k:
        raise ValueError(f"fit_cluster_model: got goals of shape {x.shape}, need (N, d) "
                         f"with N >= k={k}")
    if not np.all(np.isfinite(x)):
        raise ValueError("fit_cluster_model: goals hold NaN or Inf")
    model = KMeans(n_clusters=k, n_init=n_init, random_state=seed).fit(x)
    return model.cluster_centers_.astype(np.float32)
