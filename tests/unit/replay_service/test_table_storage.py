"""ReplayTable's storage: dedup by (actor, seq), cluster labels under new models, normaliser
coverage, sampled batches."""

import numpy as np
import pytest

from bench.synthetic_episodes import random_episode
from hercs.config import HercsConfig, apply_overrides
from hercs.replay_service.builder import ReplayBuilder
from hercs.replay_service.table import ReplayTable, Stored
from hercs.rl.cluster_model import ClusterModel, assign_clusters


def make_table(method: str = "her-cs", **extra: str) -> ReplayTable:
    overrides = [f"run.method={method}", "replay.buffer_transitions=5000", "cluster.k=4",
                 "cluster.fgb_size=8"] + [f"{k}={v}" for k, v in extra.items()]
    config = apply_overrides(HercsConfig(), overrides)
    return ReplayBuilder(config).table(rng=np.random.default_rng(0))


def fill(table: ReplayTable, n: int, *, actor: str = "a", start: int = 0) -> list[Stored]:
    rng = np.random.default_rng(start + 1000)
    return [table.store_episode(random_episode(table.spec, rng, actor_id=actor, seq=start + i))
            for i in range(n)]


def test_retry_of_a_stored_episode_is_not_stored_again() -> None:
    table = make_table()
    first = fill(table, 5)
    again = table.store_episode(random_episode(table.spec, np.random.default_rng(9),
                                               actor_id="a", seq=3))
    assert again.duplicate and again.episode_id == first[3].episode_id
    assert table.store.size == 5 and table.inserts == 5 and table.duplicates == 1
    other_actor = table.store_episode(random_episode(table.spec, np.random.default_rng(9),
                                                     actor_id="b", seq=3))
    assert not other_actor.duplicate and table.store.size == 6


def test_dedup_memory_is_bounded_by_the_ring() -> None:
    table = make_table()  # 5000 transitions = 100 episodes
    fill(table, 250)
    assert table.store.size == 100
    assert len(table._seen) == 100
    assert ("a", 249) in table._seen and ("a", 10) not in table._seen


def test_new_model_relabels_stored_and_labels_new_episodes() -> None:
    table = make_table()
    fill(table, 40)
    assert (table.store.cluster == -1).all()
    centroids = np.random.default_rng(3).uniform(-1, 1, (4, 3)).astype(np.float32)
    assert table.adopt_cluster_model(ClusterModel(1, centroids, 8, 40), None)
    np.testing.assert_array_equal(table.store.cluster,
                                  assign_clusters(table.store.final_ag, centroids))
    fill(table, 10, start=40)
    np.testing.assert_array_equal(table.store.cluster,
                                  assign_clusters(table.store.final_ag, centroids))
    assert sum(table.cluster_sizes()) == 50
    assert not table.adopt_cluster_model(ClusterModel(1, centroids[::-1], 8, 40), None), \
        "stale version"


def test_normalizer_covers_inserted_observations() -> None:
    table = make_table(**{"ddpg.clip_obs": "0.5"})
    fill(table, 30)
    o_state, g_state = table.normalizers.state()
    assert o_state["count"] == 30 * table.spec.episode_steps
    assert g_state["count"] == 30 * table.spec.episode_steps
    # random_episode's obs are N(0,1); clipping to ±0.5 bounds the mean square.
    assert (o_state["sumsq"] / o_state["count"] <= 0.25 + 1e-9).all()


@pytest.mark.parametrize("method", ["her", "her-cs", "her-ebp", "her-ebp-cs"])
def test_sample_shapes_and_cluster_draw_counts(method: str) -> None:
    table = make_table(method)
    fill(table, 60)
    table.adopt_cluster_model(ClusterModel(1, np.eye(4, 3, dtype=np.float32), 8, 60), None)
    result = table.draw(5, 32)
    assert len(result.minibatches) == 5
    mb = result.minibatches[0]
    assert mb.o.shape == (32, 25) and mb.g.shape == (32, 3) and mb.r.shape == (32,)
    assert result.cluster_draws.sum() == 5 * 32
    assert table.samples == 5
