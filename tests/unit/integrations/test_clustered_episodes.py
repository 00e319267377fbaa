"""`ClusteredEpisodeIndex`, the core of the SB3 buffer: episodes leave whole, labels follow the
newest k-means fit of failed goals, and draws keep the replay sampler's share plan."""

from __future__ import annotations

import numpy as np
import pytest

from hercs.config import ClusterConfig
from hercs.errors import ConfigError
from hercs.integrations.clustered_episodes import ClusteredEpisodeIndex
from hercs.rl.samplers.cluster_balanced import plan_shares

T = 5
CENTRES = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
"""Four well-separated goal regions: k-means with k = 4 finds them whatever its seed."""


def _fill(index: ClusteredEpisodeIndex, episodes: int, *, region_of: np.ndarray,
          rng: np.random.Generator, env: int = 0, first_start: int = 0) -> None:
    """`episodes` failed episodes of T steps in env's column, the i-th ending in region
    region_of[i], written position by position as a library's buffer writes them."""
    for i in range(episodes):
        start = (first_start + i * T) % index.capacity
        for step in range(T):
            index.overwrite((start + step) % index.capacity)
        end = CENTRES[region_of[i]] + rng.normal(0, 0.01, 3)
        ag = np.linspace(end - 0.1, end, T + 1)
        index.end_episode(env=env, start=start, achieved_goals=ag, desired_goal=end + 0.5,
                          succeeded=False)


def test_every_cluster_gets_the_share_plans_draws_and_the_fill_is_uniform() -> None:
    """The contract of HER-CS: each batch holds at least the plan's member draws of every
    cluster, and over many batches the shares equal the plan's expectation (member draws plus
    the whole-buffer fill in proportion to cluster size)."""
    rng = np.random.default_rng(0)
    index = ClusteredEpisodeIndex(capacity=10_000, n_envs=1, goal_dim=3, seed=1,
                                  cluster=ClusterConfig(k=4, fgb_size=40, kmeans_n_init=1))
    # unequal regions: 60 %, 25 %, 10 %, 5 % of 400 episodes, so the shares differ from sizes
    regions = rng.choice(4, size=400, p=[0.6, 0.25, 0.1, 0.05])
    _fill(index, 400, region_of=regions, rng=rng)
    assert index.model is not None and index.model.version == 400 // 40
    table_sizes = np.bincount(index._label[index._live], minlength=4)
    plan = plan_shares(_table(index).sampling_index, k=4, repeat=4, batch_size=256)
    assert plan is not None
    expected = (plan.member_draws + plan.fill * table_sizes / table_sizes.sum()) / 256
    drawn = np.zeros(4)
    batches = 400
    for _ in range(batches):
        positions, envs = index.draw(256)
        labels = index.episode_labels(positions, envs)
        counts = np.bincount(labels, minlength=4)
        assert index.last_draw is not None
        np.testing.assert_array_equal(counts, index.last_draw.cluster_counts)
        assert (counts >= plan.member_draws).all()
        drawn += counts
    share = drawn / (256 * batches)
    # the fill is multinomial: 5 standard errors of its share of each cluster
    sigma = np.sqrt(expected * (1 - expected) / (256 * batches))
    assert np.all(np.abs(share - expected) < 5 * sigma + 1e-9), (share, expected)
    # and the shares are not the sizes: HER-CS draws the small regions more than HER would
    assert share[3] > 2 * table_sizes[3] / table_sizes.sum()


def test_an_overwritten_episode_leaves_whole_and_is_never_drawn() -> None:
    rng = np.random.default_rng(1)
    index = ClusteredEpisodeIndex(capacity=4 * T, n_envs=1, goal_dim=3, seed=0, method="her")
    _fill(index, 4, region_of=np.arange(4), rng=rng)
    assert index.episodes == 4
    index.overwrite(T + 2)  # a step in the middle of episode 1 (positions T..2T-1)
    assert index.episodes == 3
    positions, _ = index.draw(2000)
    assert not ((positions >= T) & (positions < 2 * T)).any()
    assert set(np.unique(positions // T)) == {0, 2, 3}


def test_episodes_wrap_around_the_ring_and_steps_are_uniform_within_them() -> None:
    rng = np.random.default_rng(2)
    index = ClusteredEpisodeIndex(capacity=3 * T + 2, n_envs=1, goal_dim=3, seed=0,
                                  method="her")
    _fill(index, 4, region_of=np.zeros(4, int), rng=rng)  # the 4th wraps and evicts the 1st
    assert index.episodes == 3
    positions, _ = index.draw(30_000)
    starts = index._start_of[positions, 0]
    steps = (positions - starts) % index.capacity
    np.testing.assert_allclose(np.bincount(steps, minlength=T) / positions.size,
                               np.full(T, 1 / T), atol=0.02)
    wrapped = (3 * T) % index.capacity
    assert (starts == wrapped).any() and ((positions < T) & (starts == wrapped)).any()


def test_a_new_fit_relabels_every_live_episode_and_later_ones_on_arrival() -> None:
    rng = np.random.default_rng(3)
    index = ClusteredEpisodeIndex(capacity=10_000, n_envs=2, goal_dim=3, seed=5,
                                  cluster=ClusterConfig(k=4, fgb_size=8, kmeans_n_init=1))
    _fill(index, 7, region_of=np.arange(7) % 4, rng=rng, env=1)
    assert index.model is None and (index._label[index._live] == -1).all()
    _fill(index, 1, region_of=np.array([3]), rng=rng, env=0)  # the 8th failure: a fit
    assert index.model is not None
    live = np.nonzero(index._live)
    np.testing.assert_array_equal(index._label[live],
                                  index.model.assign(index._final_ag[live]))
    _fill(index, 1, region_of=np.array([1]), rng=rng, env=0, first_start=5 * T)
    assert index._label[5 * T, 0] == index.model.assign(CENTRES[1:2])[0]


def test_successes_never_enter_the_failed_goal_buffer_and_unknown_outcomes_are_not_guessed(
) -> None:
    index = ClusteredEpisodeIndex(capacity=100, n_envs=1, goal_dim=3, seed=0)
    ag = np.zeros((T + 1, 3))
    index.end_episode(env=0, start=0, achieved_goals=ag, desired_goal=np.zeros(3),
                      succeeded=True)
    index.end_episode(env=0, start=T, achieved_goals=ag, desired_goal=np.zeros(3),
                      succeeded=None)
    assert index.clusterer is not None
    assert (len(index.clusterer.fgb), index.clusterer.episodes_seen, index.episodes) == (0, 1, 2)


def test_her_ebp_draws_in_proportion_to_trajectory_energy() -> None:
    """EBP through the same core: an episode that lifts its goal 0.1 has energy, a resting
    one only ε (1e-3 on MuJoCo 3), so the moving episode is drawn nearly always."""
    index = ClusteredEpisodeIndex(capacity=100, n_envs=1, goal_dim=3, seed=0, method="her-ebp")
    rest = np.zeros((T + 1, 3))
    lift = rest.copy()
    lift[:, 2] = np.linspace(0.0, 0.1, T + 1)
    index.end_episode(env=0, start=0, achieved_goals=rest, desired_goal=np.ones(3),
                      succeeded=False)
    index.end_episode(env=0, start=T, achieved_goals=lift, desired_goal=np.ones(3),
                      succeeded=False)
    energy = index._energy[T, 0]
    assert energy > 0.1
    positions, _ = index.draw(20_000)
    expected = (energy + 1e-3) / (energy + 2e-3)
    assert abs(np.mean(positions >= T) - expected) < 0.01


@pytest.mark.parametrize("ag, goal, what", [
    (np.zeros((T + 1, 2)), np.zeros(3), "achieved goals of shape"),
    (np.zeros((1, 3)), np.zeros(3), "achieved goals of shape"),
    (np.full((T + 1, 3), np.nan), np.zeros(3), "NaN"),
    (np.zeros((T + 1, 3)), np.zeros(4), "desired goal of shape"),
])
def test_a_malformed_episode_is_refused_by_name_and_the_index_is_unchanged(
        ag: np.ndarray, goal: np.ndarray, what: str) -> None:
    index = ClusteredEpisodeIndex(capacity=100, n_envs=1, goal_dim=3, seed=0)
    with pytest.raises(ValueError, match=what):
        index.end_episode(env=0, start=10, achieved_goals=ag, desired_goal=goal,
                          succeeded=False)
    assert index.episodes == 0 and (index._start_of == -1).all()
    assert index.clusterer is not None and index.clusterer.episodes_seen == 0


def test_an_unknown_method_is_named() -> None:
    with pytest.raises(ConfigError, match="method: got 'her-xx'"):
        ClusteredEpisodeIndex(capacity=10, n_envs=1, goal_dim=3, seed=0, method="her-xx")


def _table(index: ClusteredEpisodeIndex):  # type: ignore[no-untyped-def]
    from hercs.integrations.clustered_episodes import _EpisodeTable
    return _EpisodeTable.of(index)
