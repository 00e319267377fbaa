"""Clusterer core: only failed episodes feed the FGB, a model per `fgb_size` failures,
versions from 1, reproducible fits, and the state round trip."""

from __future__ import annotations

import numpy as np
import pytest

from hercs.clusterer.clusterer_core import Clusterer
from hercs.config import ClusterConfig
from hercs.rl.task_registry import task_spec

PUSH = task_spec("push")


def _episodes(n: int, seed: int, p_fail: float) -> list[tuple[np.ndarray, np.ndarray, bool]]:
    """(final_ag, desired_goal, failed) with failures 0.2 away and successes 0.01 away."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        g = rng.uniform([1.0, 0.4, 0.42], [1.6, 1.1, 0.6])
        failed = bool(rng.random() < p_fail)
        offset = 0.2 if failed else 0.01
        out.append((g + np.array([offset, 0.0, 0.0]), g, failed))
    return out


def test_models_exactly_every_fgb_size_failures_never_counting_successes() -> None:
    clusterer = Clusterer(config=ClusterConfig(), seed=1, goal_dim=PUSH.goal_dim,
                          is_success=PUSH.is_success)
    fails = 0
    models = []
    for ag, g, failed in _episodes(1200, seed=0, p_fail=0.5):
        model = clusterer.observe(final_ag=ag, desired_goal=g)
        fails += failed
        if model is not None:
            assert failed and fails % 150 == 0
            models.append((fails, model))
    assert [f for f, _ in models] == list(range(150, fails + 1, 150))
    assert [m.version for _, m in models] == list(range(1, len(models) + 1))
    assert clusterer.episodes_seen == 1200 and clusterer.failures_seen == fails
    m = models[0][1]
    assert m.centroids.shape == (8, 3) and m.centroids.dtype == np.float32
    assert m.n_goals == 150 and m.failures_seen <= 1200
    assert clusterer.model is models[-1][1]


@pytest.mark.parametrize(("distance", "fails"), [(0.049, False), (0.05, True), (0.051, True)],
                         ids=["inside", "on-threshold", "outside"])
def test_failure_is_not_success_by_the_tasks_rule(distance: float, fails: bool) -> None:
    """The env's `is_success` is d < 0.05: an episode ending exactly on the radius failed."""
    clusterer = Clusterer(config=ClusterConfig(), seed=0, goal_dim=PUSH.goal_dim,
                          is_success=PUSH.is_success)
    g = np.zeros(3)  # so that ‖ag − g‖ is exactly `distance`
    clusterer.observe(final_ag=np.array([0.0, distance, 0.0]), desired_goal=g)
    assert len(clusterer.fgb) == int(fails)


def test_failed_goal_stored_is_the_desired_goal_not_the_achieved_one() -> None:
    clusterer = Clusterer(config=ClusterConfig(), seed=0, goal_dim=PUSH.goal_dim,
                          is_success=PUSH.is_success)
    g = np.array([1.3, 0.7, 0.42])
    clusterer.observe(final_ag=g + 0.3, desired_goal=g)
    np.testing.assert_allclose(clusterer.fgb.goals()[0], g, rtol=1e-6)


def test_same_seed_same_models() -> None:
    config = ClusterConfig(k=4, fgb_size=40)
    episodes = _episodes(300, seed=5, p_fail=0.6)
    a, b = (Clusterer(config=config, seed=3, goal_dim=PUSH.goal_dim, is_success=PUSH.is_success)
            for _ in range(2))
    half = len(episodes) // 2
    for ag, g, _ in episodes[:half]:
        ma, mb = a.observe(final_ag=ag, desired_goal=g), b.observe(final_ag=ag, desired_goal=g)
        assert (ma is None) == (mb is None)
        if ma is not None:
            np.testing.assert_array_equal(ma.centroids, mb.centroids)


def test_rejects_non_finite_input() -> None:
    clusterer = Clusterer(config=ClusterConfig(), seed=0, goal_dim=PUSH.goal_dim,
                          is_success=PUSH.is_success)
    with pytest.raises(ValueError, match="NaN"):
        clusterer.observe(final_ag=np.array([np.nan, 0, 0]), desired_goal=np.zeros(3))
    assert clusterer.episodes_seen == 0
