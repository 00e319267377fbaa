"""k-means refit and nearest-centroid assignment: labels equal scikit-learn's predict, seeded
fits are reproducible, and the ClusterModel invariants."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.cluster import KMeans

from hercs.clusterer.kmeans import fit_cluster_model
from hercs.rl.cluster_model import ClusterModel, assign_clusters


@pytest.mark.parametrize(("k", "n", "seed"), [(8, 2000, 0), (3, 500, 1), (1, 10, 2)],
                         ids=["k8", "k3", "k1"])
def test_assign_clusters_equals_sklearn_predict(k: int, n: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    goals = rng.uniform(-1, 1, size=(150, 3))
    km = KMeans(n_clusters=k, n_init=3, random_state=seed).fit(goals)
    points = rng.uniform(-1.5, 1.5, size=(n, 3))
    labels = assign_clusters(points, km.cluster_centers_)
    assert labels.dtype == np.int32 and labels.shape == (n,)
    np.testing.assert_array_equal(labels, km.predict(points))


def test_assign_clusters_handles_no_points_and_rejects_bad_shapes() -> None:
    assert assign_clusters(np.zeros((0, 3)), np.zeros((4, 3))).shape == (0,)
    with pytest.raises(ValueError, match="centroids"):
        assign_clusters(np.zeros((5, 3)), np.zeros((4, 2)))


def test_fit_is_seeded() -> None:
    goals = np.random.default_rng(3).uniform(size=(150, 3))
    a = fit_cluster_model(goals, k=8, seed=7, n_init=4)
    b = fit_cluster_model(goals, k=8, seed=7, n_init=4)
    c = fit_cluster_model(goals, k=8, seed=8, n_init=1)
    assert a.shape == (8, 3) and a.dtype == np.float32
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_fit_finds_separated_clusters() -> None:
    rng = np.random.default_rng(4)
    centres = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    goals = np.concatenate([c + 0.01 * rng.standard_normal((50, 3)) for c in centres])
    found = fit_cluster_model(goals, k=3, seed=0, n_init=2)
    order = np.argsort(assign_clusters(centres, found))
    np.testing.assert_allclose(found[np.sort(assign_clusters(centres, found))],
                               centres[order], atol=0.01)


def test_fit_needs_at_least_k_goals() -> None:
    with pytest.raises(ValueError, match="k=8"):
        fit_cluster_model(np.zeros((5, 3)), k=8, seed=0, n_init=1)


def test_cluster_model_invariants() -> None:
    m = ClusterModel(version=1, centroids=np.eye(3, dtype=np.float64), n_goals=150,
                     failures_seen=400)
    assert m.centroids.dtype == np.float32 and m.k == 3
    np.testing.assert_array_equal(m.assign(np.array([[0.9, 0.1, 0], [0, 0, 2]])), [0, 2])
    with pytest.raises(ValueError, match="version"):
        ClusterModel(version=0, centroids=np.eye(3), n_goals=1, failures_seen=1)
    with pytest.raises(ValueError, match="NaN"):
        ClusterModel(version=1, centroids=np.full((2, 3), np.nan), n_goals=1, failures_seen=1)
