"""One finite, huge episode cannot poison the running statistics (issue 57): after the warm-up
an episode of 3e38-valued observations is refused `implausible` and counted, the normalisers
are untouched by it, and an admitted edge case moves them by no more than the winsorised bound
that hercs/rl/plausibility.py derives; honest episodes are all admitted."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hercs.proto import hercs_pb2 as pb
from hercs.reasons import Disposition, Reason
from hercs.rl.normalizer import Normalizer
from hercs.rl.plausibility import (
    IMPLAUSIBLE_SIGMAS,
    WARMUP_SAMPLES,
    WINSOR_SIGMAS,
    implausible,
    winsorised,
)
from hercs.wire.episode import EpisodeData
from tests.unit.replay_service.table_harness import Harness, Recorder, insert_acted
from tests.unit.replay_service.table_harness import make as make_table

FREE = "replay.free_run=true"  # no learner samples here: the limiter would hold the inserts


def make() -> Harness:
    return make_table(FREE)


def warmed(h: Harness, episodes: int = 30) -> None:
    for seq in range(episodes):
        assert not insert_acted(h, seq, 0).failures
    assert h.table.normalizers.o_norm.count >= WARMUP_SAMPLES


def test_the_3e38_episode_is_refused_counted_and_leaves_the_statistics_as_they_were() -> None:
    h = make()
    warmed(h)
    table = h.table
    norms = table.normalizers
    before = (norms.o_norm.state_dict(), norms.g_norm.state_dict(), table.store.num_inserted)
    poison = h.episode(1000)
    poison.obs[:] = np.float32(3e38)
    waiter = insert_episode(h, poison)
    assert [r for r, _ in waiter.failures] == [Reason.IMPLAUSIBLE], waiter.failures
    assert "obs[..., " in waiter.failures[0][1] and "= 3e+38 lies" in waiter.failures[0][1]
    assert Reason.IMPLAUSIBLE.disposition is Disposition.DROP
    assert table.rejects[Reason.IMPLAUSIBLE] == 1
    after = (norms.o_norm.state_dict(), norms.g_norm.state_dict(), table.store.num_inserted)
    for old, new in zip(before[:2], after[:2], strict=True):
        assert all(np.array_equal(old[k], new[k]) for k in old)
    assert before[2] == after[2]


def insert_episode(h: Harness, episode: EpisodeData) -> Recorder:
    waiter = Recorder("poison", h.journal)
    h.table.insert(dataclasses.replace(episode, policy_version=0),
                   record=pb.Episode(seq=episode.seq), waiter=waiter)
    return waiter


def test_a_goal_far_off_is_refused_too() -> None:
    h = make()
    warmed(h)
    poison = h.episode(2000)
    poison.g[:] = np.float32(-1e20)
    waiter = insert_episode(h, poison)
    assert waiter.failures and "desired_goal" in waiter.failures[0][1]


def test_before_the_warm_up_nothing_is_refused_for_its_values() -> None:
    norm = Normalizer(3)
    norm.update(np.zeros((WARMUP_SAMPLES - 1, 3)))
    norm.recompute_stats()
    assert implausible(norm, np.full((5, 3), 1e30), what="obs") is None
    assert np.array_equal(winsorised(norm, np.full((2, 3), 7.0)), np.full((2, 3), 7.0))


@pytest.mark.parametrize("sigmas, refused", [(IMPLAUSIBLE_SIGMAS * 0.99, False),
                                             (IMPLAUSIBLE_SIGMAS * 1.01, True)],
                         ids=["inside", "outside"])
def test_the_bound_is_in_std_of_the_statistics(sigmas: float, refused: bool) -> None:
    rng = np.random.default_rng(0)
    norm = Normalizer(2)
    norm.update(rng.normal(1.0, 0.5, size=(4 * WARMUP_SAMPLES, 2)))
    norm.recompute_stats()
    v = norm.mean + sigmas * norm.std
    assert (implausible(norm, v[None], what="obs") is not None) is refused


def test_an_admitted_edge_value_moves_the_variance_by_at_most_the_derived_bound() -> None:
    """WINSOR_SIGMAS² · std² · T / n, the module docstring's bound, for T values at 500 std."""
    rng = np.random.default_rng(1)
    n, T = 10_000, 50
    norm = Normalizer(1)
    norm.update(rng.normal(0.0, 0.1, size=(n, 1)))
    norm.recompute_stats()
    var0, std0 = float(norm.std[0]) ** 2, float(norm.std[0])
    norm.update(winsorised(norm, np.full((T, 1), norm.mean + 500 * norm.std)))
    norm.recompute_stats()
    assert float(norm.std[0]) ** 2 - var0 <= WINSOR_SIGMAS ** 2 * std0 ** 2 * T / n


def test_honest_episodes_are_all_admitted() -> None:
    h = make()
    warmed(h, episodes=200)
    assert h.table.rejects[Reason.IMPLAUSIBLE] == 0
