"""ReplayCore: dedup by (actor, seq), cluster labels under new models, normaliser coverage,
sampled batches, checkpoint round trip."""

import numpy as np
import pytest

from hercs.config import HercsConfig, apply_overrides
from hercs.replay_service.replay_core import ReplayCore
from hercs.rl.cluster_model import ClusterModel, assign_clusters
from hercs.wire.episode import random_episode


def make_core(method: str = "her-cs", **extra: str) -> ReplayCore:
    overrides = [f"run.method={method}", "replay.buffer_transitions=5000", "cluster.k=4",
                 "cluster.fgb_size=8"] + [f"{k}={v}" for k, v in extra.items()]
    config = apply_overrides(HercsConfig(), overrides)
    return ReplayCore(config=config, rng=np.random.default_rng(0))


def fill(core: ReplayCore, n: int, *, actor: str = "a", start: int = 0) -> list:
    rng = np.random.default_rng(start + 1000)
    return [core.insert(random_episode(core.spec, rng, actor_id=actor, seq=start + i))
            for i in range(n)]


def test_retry_of_a_stored_episode_is_not_stored_again() -> None:
    core = make_core()
    first = fill(core, 5)
    again = core.insert(random_episode(core.spec, np.random.default_rng(9), actor_id="a", seq=3))
    assert again.duplicate and again.episode_id == first[3].episode_id
    assert core.store.size == 5 and core.inserts == 5 and core.duplicates == 1
    other_actor = core.insert(random_episode(core.spec, np.random.default_rng(9), actor_id="b",
                                             seq=3))
    assert not other_actor.duplicate and core.store.size == 6


def test_dedup_memory_is_bounded_by_the_ring() -> None:
    core = make_core()  # 5000 transitions = 100 episodes
    fill(core, 250)
    assert core.store.size == 100
    assert len(core._seen) == 100
    assert core.lookup("a", 249) is not None and core.lookup("a", 10) is None


def test_new_model_relabels_stored_and_labels_new_episodes() -> None:
    core = make_core()
    fill(core, 40)
    assert (core.store.cluster == -1).all()
    centroids = np.random.default_rng(3).uniform(-1, 1, (4, 3)).astype(np.float32)
    assert core.set_cluster_model(ClusterModel(1, centroids, 8, 40))
    np.testing.assert_array_equal(core.store.cluster,
                                  assign_clusters(core.store.final_ag, centroids))
    fill(core, 10, start=40)
    np.testing.assert_array_equal(core.store.cluster,
                                  assign_clusters(core.store.final_ag, centroids))
    assert core.cluster_sizes().sum() == 50
    assert not core.set_cluster_model(ClusterModel(1, centroids[::-1], 8, 40)), "stale version"


def test_normalizer_covers_inserted_observations() -> None:
    core = make_core(**{"ddpg.clip_obs": "0.5"})
    fill(core, 30)
    o_state, g_state = core.normalizer_state()
    assert o_state["count"] == 30 * core.spec.episode_steps
    assert g_state["count"] == 30 * core.spec.episode_steps
    # random_episode's obs are N(0,1); clipping to ±0.5 bounds the mean square.
    assert (o_state["sumsq"] / o_state["count"] <= 0.25 + 1e-9).all()


@pytest.mark.parametrize("method", ["her", "her-cs", "her-ebp", "her-ebp-cs"])
def test_sample_shapes_and_cluster_draw_counts(method: str) -> None:
    core = make_core(method)
    fill(core, 60)
    core.set_cluster_model(ClusterModel(1, np.eye(4, 3, dtype=np.float32), 8, 60))
    result = core.sample(5, 32)
    assert len(result.minibatches) == 5
    mb = result.minibatches[0]
    assert mb.o.shape == (32, 25) and mb.g.shape == (32, 3) and mb.r.shape == (32,)
    assert result.cluster_draws.sum() == 5 * 32
    assert core.samples == 5
