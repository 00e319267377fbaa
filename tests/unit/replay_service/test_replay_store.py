"""EpisodeStore: ids and slots, ring overwrite, metadata, refused shapes, checkpoint round trip."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest

from bench.synthetic_episodes import random_episode
from hercs.errors import ConfigError
from hercs.replay_service.store import EpisodeStore
from hercs.rl.task_registry import task_spec
from hercs.wire.episode import EpisodeData

SPEC = task_spec("push")
T = SPEC.episode_steps


def _episode(seq: int, *, seed: int = 0) -> EpisodeData:
    ep = random_episode(SPEC, np.random.default_rng([seed, seq]), actor_id=f"a{seq % 3}", seq=seq)
    return dataclasses.replace(ep, success=bool(seq % 2), policy_version=10 + seq)


def test_insert_assigns_monotonic_ids_and_stores_metadata() -> None:
    store = EpisodeStore(capacity_episodes=8, spec=SPEC)
    episodes = [_episode(i) for i in range(5)]
    ids = [store.insert(ep, energy=0.1 * i, cluster=i - 1) for i, ep in enumerate(episodes)]

    assert ids == [0, 1, 2, 3, 4]
    assert (store.size, store.num_transitions, store.num_inserted) == (5, 5 * T, 5)
    np.testing.assert_array_equal(store.episode_id, ids)
    np.testing.assert_array_equal(store.actor_id, [ep.actor_id for ep in episodes])
    np.testing.assert_array_equal(store.seq, [ep.seq for ep in episodes])
    np.testing.assert_array_equal(store.success, [ep.success for ep in episodes])
    np.testing.assert_array_equal(store.policy_version, [ep.policy_version for ep in episodes])
    np.testing.assert_allclose(store.energy, [0.0, 0.1, 0.2, 0.3, 0.4])
    np.testing.assert_array_equal(store.cluster, [-1, 0, 1, 2, 3])
    for slot, ep in enumerate(episodes):
        np.testing.assert_array_equal(store.obs[slot], ep.obs)
        np.testing.assert_array_equal(store.ag[slot], ep.ag)
        np.testing.assert_array_equal(store.g[slot], ep.g)
        np.testing.assert_array_equal(store.actions[slot], ep.actions)
        np.testing.assert_array_equal(store.final_ag[slot], ep.ag[-1])
    assert store.obs.dtype == store.ag.dtype == store.g.dtype == np.float32


def test_ring_overwrites_oldest_and_keeps_slot_equal_id_mod_capacity() -> None:
    store = EpisodeStore(capacity_episodes=3, spec=SPEC)
    episodes = [_episode(i) for i in range(7)]
    for ep in episodes:
        store.insert(ep)

    assert (store.size, store.num_inserted, store.num_transitions) == (3, 7, 3 * T)
    np.testing.assert_array_equal(store.episode_id, [6, 4, 5])
    np.testing.assert_array_equal(store.seq, [6, 4, 5])
    np.testing.assert_array_equal(store.obs[0], episodes[6].obs)
    assert [store.slot_of(i) for i in range(8)] == [None] * 4 + [1, 2, 0, None]


def test_episode_by_id_is_a_copy_of_what_was_inserted_until_overwritten() -> None:
    store = EpisodeStore(capacity_episodes=3, spec=SPEC)
    episodes = [_episode(i) for i in range(5)]
    for ep in episodes:
        store.insert(ep, energy=1.0, cluster=2)

    got = store.episode(3)
    assert got is not None
    for name in ("obs", "ag", "g", "actions"):
        np.testing.assert_array_equal(getattr(got, name), getattr(episodes[3], name))
    assert (got.actor_id, got.seq, got.success, got.policy_version) == (
        episodes[3].actor_id, 3, episodes[3].success, episodes[3].policy_version)
    got.obs[:] = 0  # a copy: the stored episode is untouched
    np.testing.assert_array_equal(store.episode(3).obs, episodes[3].obs)
    assert [store.episode(i) is None for i in range(6)] == [True, True, False, False, False,
                                                              True]


@pytest.mark.parametrize(
    ("field", "shape"),
    [
        ("obs", (T + 1, 10)),  # a FetchReach observation sent to a Push replay
        ("obs", (T, SPEC.obs_dim)),
        ("ag", (T, 3)),
        ("g", (T, 2)),
        ("actions", (T, 3)),
        ("actions", (T * SPEC.action_dim,)),
    ],
    ids=["obs-reach-dim", "obs-missing-last", "ag-missing-last", "g-2d", "actions-3d", "flat"],
)
def test_insert_refuses_wrong_shape_and_stores_nothing(field: str, shape: tuple) -> None:
    store = EpisodeStore(capacity_episodes=4, spec=SPEC)
    bad = dataclasses.replace(_episode(0), **{field: np.zeros(shape, np.float32)})
    with pytest.raises(ConfigError, match=rf"episode\.{field} has shape \({shape[0]},"):
        store.insert(bad)
    assert (store.size, store.num_inserted) == (0, 0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"energy": float("nan")}, "nan"), ({"energy": -1.0}, "-1.0"), ({"cluster": -2}, "-2")],
    ids=["nan-energy", "negative-energy", "cluster-below-minus-one"],
)
def test_insert_refuses_bad_metadata(kwargs: dict, match: str) -> None:
    store = EpisodeStore(capacity_episodes=4, spec=SPEC)
    with pytest.raises(ConfigError, match=match):
        store.insert(_episode(0), **kwargs)
    assert store.size == 0


def test_set_clusters_relabels_all_and_validates() -> None:
    store = EpisodeStore(capacity_episodes=4, spec=SPEC)
    for i in range(3):
        store.insert(_episode(i))
    store.set_clusters(np.array([2, 0, 7]))
    np.testing.assert_array_equal(store.cluster, [2, 0, 7])

    with pytest.raises(ConfigError, match=r"shape \(2,\), expected \(3,\)"):
        store.set_clusters(np.array([1, 1]))
    np.testing.assert_array_equal(store.cluster, [2, 0, 7])


def test_views_are_read_only_prefixes() -> None:
    store = EpisodeStore(capacity_episodes=4, spec=SPEC)
    store.insert(_episode(0))
    assert store.obs.shape == (1, T + 1, SPEC.obs_dim)
    with pytest.raises(ValueError, match="read-only"):
        store.cluster[0] = 3


def test_random_eviction_overwrites_uniformly_as_the_reference() -> None:
    """Once full, each insert overwrites a uniformly drawn slot: after C more inserts into a
    buffer of C, a fraction (1 − 1/C)^C ≈ e^−1 of the first C episodes is still there (FIFO
    keeps none). Every id is found exactly where `slot_of` says, or reported gone."""
    spec, capacity = task_spec("reach"), 1000
    store = EpisodeStore(capacity_episodes=capacity, spec=spec, eviction="random",
                         eviction_seed=7)
    episode = random_episode(spec, np.random.default_rng(0))
    for cluster in range(2 * capacity):
        store.insert(episode, cluster=cluster % 5)
    kept = int(np.count_nonzero(store.episode_id < capacity))
    # binomial-like: mean C·e^−1 ≈ 368, sd ≈ 15; 5 sd either side
    assert 290 < kept < 445, kept
    held = set(store.episode_id.tolist())
    assert len(held) == capacity
    for episode_id in range(2 * capacity):
        slot = store.slot_of(episode_id)
        assert (slot is not None) == (episode_id in held)
        assert slot is None or store.episode_id[slot] == episode_id
    np.testing.assert_array_equal(store.sampling_index.counts,
                                  np.bincount(store.cluster, minlength=5))


def test_random_eviction_is_a_function_of_the_seed() -> None:
    """The slots come from (seed, id) alone, so a replay rebuilt from its log in id order holds
    the same buffer; another seed overwrites other slots."""
    def filled(seed: int) -> EpisodeStore:
        store = EpisodeStore(capacity_episodes=4, spec=SPEC, eviction="random",
                             eviction_seed=seed)
        for i in range(12):
            store.insert(_episode(i))
        return store

    first, again, other = filled(1), filled(1), filled(2)
    np.testing.assert_array_equal(first.episode_id, again.episode_id)
    assert [first.slot_for(i) for i in range(4, 40)] != [other.slot_for(i) for i in range(4, 40)]
    with pytest.raises(ConfigError, match="eviction: got 'lifo'"):
        EpisodeStore(capacity_episodes=4, spec=SPEC, eviction="lifo")


_MEASURE_EMPTY_STORE = """
from hercs.rl.task_registry import task_spec
from hercs.replay_service.store import EpisodeStore

def rss():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096

before = rss()
store = EpisodeStore(capacity_episodes=20_000, spec=task_spec("push"))
print(store.capacity_episodes, rss() - before)
"""


def test_preallocation_commits_memory_only_when_written() -> None:
    """A 1e6-transition Push store is ~142 MB nominal; creating it must add < 20 MB RSS.

    Measured in a fresh interpreter, as the replay service starts: in a long test process,
    calloc may reuse freed heap memory and zero it, which commits the pages.
    """
    out = subprocess.run([sys.executable, "-c", _MEASURE_EMPTY_STORE], capture_output=True,
                         text=True, check=True).stdout.split()
    capacity, grown = int(out[0]), int(out[1])
    assert capacity == 20_000
    assert grown < 20e6, f"creating an empty store committed {grown / 1e6:.0f} MB"


def _still(seq: int, *, moved_by: float) -> EpisodeData:
    """An episode whose achieved goal rests at one point, then is moved by `moved_by` metres."""
    ep = _episode(seq)
    ag = np.repeat(ep.ag[:1], len(ep.ag), axis=0)
    ag[-1, 0] += moved_by
    return dataclasses.replace(ep, ag=ag)


def test_moved_flags_and_their_count_follow_inserts_and_evictions() -> None:
    from hercs.replay_service.store import MOVED_THRESHOLD_M

    store = EpisodeStore(capacity_episodes=3, spec=SPEC)
    for seq, moved_by in enumerate([0.0, 2 * MOVED_THRESHOLD_M, MOVED_THRESHOLD_M / 2]):
        store.insert(_still(seq, moved_by=moved_by))
    np.testing.assert_array_equal(store.moved, [False, True, False])
    assert store.moved_count == 1
    store.insert(_still(3, moved_by=0.1))        # evicts episode 0 (still): 2 moved now
    store.insert(_still(4, moved_by=0.0))        # evicts episode 1 (moved): 1 moved now
    np.testing.assert_array_equal(store.moved, [True, False, False])
    assert store.moved_count == 1

