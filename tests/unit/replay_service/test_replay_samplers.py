"""Episode samplers: the distribution each one promises, checked over many seeded batches.

Frequencies are compared with a chi-square statistic against its 99.99% point (seeded, so
deterministic); mean per-batch counts with an absolute tolerance stated at each assertion.
The expected distributions are re-derived here with plain loops from the rules in the
sampler docstrings, independently of the vectorised code.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bench.synthetic_episodes import random_episode
from hercs.config import HercsConfig
from hercs.errors import ConfigError, SamplingError
from hercs.replay_service.store import EpisodeStore
from hercs.rl.methods import METHODS, make_sampler
from hercs.rl.samplers import (
    ClusterBalancedSampler,
    EnergyClusterSampler,
    EnergyPrioritisedSampler,
    UniformSampler,
)
from hercs.rl.samplers.cluster_balanced import plan_shares
from hercs.rl.task_registry import task_spec

SPEC = task_spec("push")
K = 8
REPEAT = 4
EPS = 1e-6
PAPER_LIKE = [2000, 500, 100, 40, 20, 9, 3, 0]
"""Very different sizes: six regular clusters, one small (3 < 32/4), one empty."""
THRESHOLD_EDGE = [300, 8, 7, 1, 0, 0, 0, 0]
"""With B=256 (share 32): 8 = ⌊32/4⌋ is regular (32 draws, each member ~4×); 7 is small
(28 draws + 4 fills)."""
THRESHOLD_EDGE_B250 = [300, 7, 6, 1, 0, 0, 0, 0]
"""With B=250 (share 31, remainder 2): 7 = ⌊31/4⌋ is regular (31 draws, not 28 + 3 fills);
6 is small (24 draws + 7 fills)."""


def _store(labels: np.ndarray, energy: np.ndarray | None = None) -> EpisodeStore:
    store = EpisodeStore(capacity_episodes=len(labels), spec=SPEC)
    episode = random_episode(SPEC, np.random.default_rng(0))
    energy = np.zeros(len(labels)) if energy is None else energy
    for e in energy:
        store.insert(episode, energy=float(e))
    store.set_clusters(labels)
    return store


def _labels(sizes: list[int], seed: int = 0) -> np.ndarray:
    """Cluster c repeated sizes[c] times, shuffled over the slots."""
    labels = np.repeat(np.arange(len(sizes)), sizes)
    return np.random.default_rng(seed).permutation(labels).astype(np.int32)


def _draw_counts(sampler, store, batch_size: int, batches: int, seed: int):
    """Per-slot draw counts over `batches` batches, and the SampleInfo of every batch."""
    rng = np.random.default_rng(seed)
    counts = np.zeros(store.size, np.int64)
    infos = []
    for _ in range(batches):
        idxs, info = sampler.sample(store, batch_size, rng)
        assert idxs.shape == (batch_size,) and idxs.dtype == np.int64
        counts += np.bincount(idxs, minlength=store.size)
        infos.append(info)
    return counts, infos


def _assert_reported(infos, labels: np.ndarray, counts: np.ndarray, k: int) -> None:
    """What a draw's SampleInfo is for (`ServedBatch.cluster_draws`): its per-cluster counts,
    summed over the draws, are the drawn episodes of each stored label; unlabelled ones (-1)
    are not counted, whether drawn by a cluster's share or a whole-buffer fill."""
    labelled = labels >= 0
    np.testing.assert_array_equal(
        np.sum([i.cluster_counts for i in infos], axis=0),
        np.bincount(labels[labelled], weights=counts[labelled], minlength=k))


def _expected_per_batch(
    labels: np.ndarray, weights: np.ndarray, batch_size: int
) -> tuple[np.ndarray, int]:
    """Expected draws of each slot per batch under the HER-CS rule, members ∝ weights within
    their cluster and fills ∝ weights over the buffer (weights = 1 for plain HER-CS)."""
    share = batch_size // K
    expected = np.zeros(len(labels))
    fill = batch_size - K * share
    for c in range(K):
        members = np.flatnonzero(labels == c)
        n = len(members)
        if n == 0:
            fill += share
            continue
        own = share if n >= share // REPEAT else REPEAT * n
        fill += share - own
        expected[members] += own * weights[members] / weights[members].sum()
    expected += fill * weights / weights.sum()
    return expected, fill


def _chi2(observed: np.ndarray, expected: np.ndarray) -> float:
    return float(np.sum((observed - expected) ** 2 / expected))


def _chi2_9999(df: int) -> float:
    """99.99% point of χ²(df), Wilson–Hilferty approximation (accurate to <1% for df ≥ 10)."""
    z = 3.719
    return df * (1 - 2 / (9 * df) + z * np.sqrt(2 / (9 * df))) ** 3


# ---------------------------------------------------------------------------- her, her-ebp


def test_uniform_sampler_is_uniform() -> None:
    labels = _labels([100, 100])
    store = _store(labels)
    counts, infos = _draw_counts(UniformSampler(num_clusters=2), store, 256, 800, seed=0)
    expected = np.full(store.size, 256 * 800 / store.size)
    assert _chi2(counts, expected) < _chi2_9999(store.size - 1)
    _assert_reported(infos, labels, counts, 2)


def test_energy_sampler_frequencies_are_proportional_to_energy() -> None:
    """~200k draws over 200 episodes with energies in [0.05, 2]: chi-square against
    p ∝ e + ε, and a zero-energy episode among them is (almost) never drawn."""
    rng = np.random.default_rng(1)
    energy = rng.uniform(0.05, 2.0, size=200)
    energy[17] = 0.0
    store = _store(np.full(200, -1, np.int32), energy)
    counts, _ = _draw_counts(EnergyPrioritisedSampler(epsilon=EPS), store, 256, 800, seed=2)
    p = (energy + EPS) / (energy + EPS).sum()
    drawable = energy > 0
    total = counts.sum()
    assert _chi2(counts[drawable], total * p[drawable]) < _chi2_9999(drawable.sum() - 1)
    assert counts[17] <= 2  # expected 0.001 draws


def test_energy_sampler_all_zero_energy_is_uniform() -> None:
    store = _store(np.full(200, -1, np.int32), np.zeros(200))
    counts, _ = _draw_counts(EnergyPrioritisedSampler(epsilon=EPS), store, 256, 800, seed=3)
    assert _chi2(counts, np.full(200, counts.sum() / 200)) < _chi2_9999(199)


# ---------------------------------------------------------------------------- her-cs


@pytest.mark.parametrize(
    ("sizes", "batch_size"),
    [(PAPER_LIKE, 256), (THRESHOLD_EDGE, 256), (PAPER_LIKE, 250), (THRESHOLD_EDGE_B250, 250)],
    ids=["paper-like-B256", "threshold-edge-B256", "paper-like-B250", "threshold-edge-B250"],
)
def test_cluster_balanced_shares(sizes: list[int], batch_size: int) -> None:
    """Over 2000 batches:
    - each regular (n_c ≥ ⌊share/4⌋) cluster's own share is 1/k of the batch: its mean draws
      per batch minus the whole-buffer fills' expected part n_c/N·fill equals ⌊B/k⌋ ± 0.5
      (the fills' per-batch s.d. is ≤ 3.2, so the mean's is ≤ 0.08);
    - each small-cluster member appears 4 + fill/N ± 0.15 times per batch (s.d. ≈ 0.04);
    - per slot, counts match the rule (empty/small shares and remainder uniform over the
      whole buffer, members uniform within their cluster): chi-square below its 99.99% point;
    - SampleInfo reports the per-cluster counts of the drawn episodes, every draw labelled."""
    labels = _labels(sizes)
    store = _store(labels)
    batches = 2000
    counts, infos = _draw_counts(ClusterBalancedSampler(K), store, batch_size, batches, seed=4)
    expected, fill = _expected_per_batch(labels, np.ones(len(labels)), batch_size)
    share = batch_size // K
    n_total = len(labels)

    for c, n in enumerate(sizes):
        per_batch = counts[labels == c].sum() / batches
        if n >= share // REPEAT:
            own = per_batch - fill * n / n_total
            assert abs(own - share) < 0.5, (c, n, own)
        elif n > 0:
            per_member = counts[labels == c] / batches
            assert np.all(np.abs(per_member - (REPEAT + fill / n_total)) < 0.15), (c, per_member)
    assert _chi2(counts, batches * expected) < _chi2_9999(n_total - 1)

    assert all(i.cluster_counts.sum() == batch_size for i in infos)
    _assert_reported(infos, labels, counts, K)


def test_cluster_balanced_before_any_model_is_uniform() -> None:
    store = _store(np.full(300, -1, np.int32))
    counts, infos = _draw_counts(ClusterBalancedSampler(K), store, 256, 600, seed=5)
    assert _chi2(counts, np.full(300, counts.sum() / 300)) < _chi2_9999(299)
    assert not any(i.cluster_counts.any() for i in infos), "no label to count yet"


def test_unlabelled_episodes_are_reached_only_through_fills() -> None:
    """Once a model exists, an unlabelled episode is drawn fill/N times per batch (± 0.02)."""
    labels = _labels([200, 100, 0, 0, 0, 0, 0, 0])
    labels[:50] = -1
    store = _store(labels)
    counts, infos = _draw_counts(ClusterBalancedSampler(K), store, 256, 2000, seed=6)
    fill = 256 - 2 * 32
    per_episode = counts[labels == -1] / 2000
    assert abs(per_episode.mean() - fill / len(labels)) < 0.02
    _assert_reported(infos, labels, counts, K)


def _reference_plan(sizes: list[int], batch_size: int) -> tuple[list[int], int]:
    """The reference code's rule, restated: the clusters 0..m (m the highest label held)
    share the batch, ⌊B/(m+1)⌋ each; a cluster of n ≥ ⌊share/4⌋ draws its share from its
    members, a smaller one 4·n, and the rest of its share and the remainder come from the
    whole buffer. Returns each cluster's member draws and the fill."""
    top = max(c for c, n in enumerate(sizes) if n)
    share = batch_size // (top + 1)
    own = [0 if n == 0 else (share if n >= share // 4 else 4 * n) for n in sizes]
    return own, batch_size - sum(own)


@pytest.mark.parametrize("sizes", [PAPER_LIKE, THRESHOLD_EDGE, [40, 0, 30, 9, 8, 0, 0, 2],
                                   [50, 40, 30, 20, 10, 9, 8, 7]],
                         ids=["top-empty", "four-top-empty", "gaps", "none-empty"])
def test_reference_share_rule_plans_as_the_reference_code(sizes: list[int]) -> None:
    """`share_rule=reference`: the clusters up to the highest label share the batch (with
    cluster 7 empty, 7 shares of 36 at B = 256, where every-cluster gives 8 of 32)."""
    index = _store(_labels(sizes)).sampling_index
    plan = plan_shares(index, k=K, repeat=REPEAT, batch_size=256, share_rule="reference")
    assert plan is not None
    own, fill = _reference_plan(sizes, 256)
    assert plan.member_draws.tolist() == own and plan.fill == fill
    every = plan_shares(index, k=K, repeat=REPEAT, batch_size=256)
    assert every is not None
    if sizes[-1] == 0:  # the case where the two rules differ
        assert plan.member_draws.sum() > every.member_draws.sum()
    else:
        assert plan.member_draws.tolist() == every.member_draws.tolist()


def test_reference_share_rule_draws_its_plan() -> None:
    """Over 2000 batches of PAPER_LIKE (cluster 7 empty), each regular cluster's own draws
    per batch are 36 (± 0.5 after the fills' expected part), the small one's members 4 each."""
    labels = _labels(PAPER_LIKE)
    store = _store(labels)
    sampler = ClusterBalancedSampler(K, share_rule="reference")
    counts, infos = _draw_counts(sampler, store, 256, 2000, seed=9)
    own, fill = _reference_plan(PAPER_LIKE, 256)
    for c, n in enumerate(PAPER_LIKE):
        if n:
            per_batch = counts[labels == c].sum() / 2000 - fill * n / len(labels)
            assert abs(per_batch - own[c]) < 0.5, (c, per_batch, own[c])
    _assert_reported(infos, labels, counts, K)


# ---------------------------------------------------------------------------- her-ebp-cs


def test_energy_cluster_balanced_shares_and_energy_within_clusters() -> None:
    """PAPER_LIKE layout with energies in [0.05, 1] over 2000 batches: every regular cluster's
    own share is ⌊B/k⌋ ± 0.5 after removing the energy-weighted fills' expected part; the
    per-slot counts follow member_draws_c·w_i/W_c + fill·w_i/W (chi-square)."""
    labels = _labels(PAPER_LIKE, seed=1)
    energy = np.random.default_rng(8).uniform(0.05, 1.0, size=len(labels))
    store = _store(labels, energy)
    batches = 2000
    counts, infos = _draw_counts(EnergyClusterSampler(K, epsilon=EPS), store, 256, batches, 9)
    weights = energy + EPS
    expected, fill = _expected_per_batch(labels, weights, 256)

    for c, n in enumerate(PAPER_LIKE):
        if n >= 32 // REPEAT:
            per_batch = counts[labels == c].sum() / batches
            own = per_batch - fill * weights[labels == c].sum() / weights.sum()
            assert abs(own - 32) < 0.5, (c, n, own)
    assert _chi2(counts, batches * expected) < _chi2_9999(len(labels) - 1)
    # Not vacuous: uniform-within-cluster draws are far from this distribution.
    uniform_expected, _ = _expected_per_batch(labels, np.ones(len(labels)), 256)
    assert _chi2(counts, batches * uniform_expected) > 2 * _chi2_9999(len(labels) - 1)
    _assert_reported(infos, labels, counts, K)


def test_energy_cluster_before_any_model_is_energy_prioritised() -> None:
    energy = np.random.default_rng(10).uniform(0.05, 2.0, size=200)
    store = _store(np.full(200, -1, np.int32), energy)
    counts, infos = _draw_counts(EnergyClusterSampler(K, epsilon=EPS), store, 256, 800, 11)
    p = (energy + EPS) / (energy + EPS).sum()
    assert _chi2(counts, counts.sum() * p) < _chi2_9999(199)
    assert not any(i.cluster_counts.any() for i in infos), "no label to count yet"


def test_energy_temperature_raises_energies_to_the_reference_exponent() -> None:
    """temperature T: p ∝ e^(1/(T+0.01)) + ε (the reference's form); T = 0.2 makes the
    exponent 4.76, far from p ∝ e (checked not to fit)."""
    energy = np.random.default_rng(12).uniform(0.05, 1.0, size=150)
    store = _store(np.full(150, -1, np.int32), energy)
    exponent = 1 / (0.2 + 0.01)
    sampler = EnergyPrioritisedSampler(epsilon=EPS, exponent=exponent)
    counts, _ = _draw_counts(sampler, store, 256, 800, 13)
    p = (energy**exponent + EPS) / (energy**exponent + EPS).sum()
    assert _chi2(counts, counts.sum() * p) < _chi2_9999(149)
    linear = (energy + EPS) / (energy + EPS).sum()
    assert _chi2(counts, counts.sum() * linear) > 2 * _chi2_9999(149)


def test_energy_cluster_with_uniform_fill_draws_members_uniformly() -> None:
    """energy.cluster_fill=uniform: HER-CS's draw inside each cluster, EBP only in the
    whole-buffer fills: per-slot counts follow member_draws_c/n_c + fill·w_i/W."""
    labels = _labels(PAPER_LIKE, seed=1)
    energy = np.random.default_rng(8).uniform(0.05, 1.0, size=len(labels))
    store = _store(labels, energy)
    batches = 2000
    sampler = EnergyClusterSampler(K, epsilon=EPS, cluster_fill="uniform")
    counts, infos = _draw_counts(sampler, store, 256, batches, 14)
    weights = energy + EPS
    members_part, fill = _expected_per_batch(labels, np.ones(len(labels)), 256)
    expected = members_part - fill / len(labels) + fill * weights / weights.sum()
    assert _chi2(counts, batches * expected) < _chi2_9999(len(labels) - 1)
    energy_within, _ = _expected_per_batch(labels, weights, 256)
    assert _chi2(counts, batches * energy_within) > 2 * _chi2_9999(len(labels) - 1)
    _assert_reported(infos, labels, counts, K)
    with pytest.raises(ConfigError, match=r"energy\.cluster_fill: got 'x'"):
        EnergyClusterSampler(K, epsilon=EPS, cluster_fill="x")


# ---------------------------------------------------------------------------- errors, factory


@pytest.mark.parametrize(
    "sampler",
    [UniformSampler(), EnergyPrioritisedSampler(epsilon=EPS), ClusterBalancedSampler(K),
     EnergyClusterSampler(K, epsilon=EPS)],
    ids=["her", "her-ebp", "her-cs", "her-ebp-cs"],
)
def test_empty_store_and_bad_batch_size_are_refused(sampler) -> None:
    rng = np.random.default_rng(0)
    with pytest.raises(SamplingError, match="store is empty"):
        sampler.sample(EpisodeStore(capacity_episodes=4, spec=SPEC), 256, rng)
    with pytest.raises(SamplingError, match="batch_size got 0"):
        sampler.sample(_store(np.zeros(4, np.int32)), 0, rng)


@pytest.mark.parametrize(
    "sampler", [ClusterBalancedSampler(K), EnergyClusterSampler(K, epsilon=EPS)],
    ids=["her-cs", "her-ebp-cs"],
)
def test_label_from_a_bigger_model_is_refused(sampler) -> None:
    with pytest.raises(SamplingError, match="cluster label 8 >= k=8"):
        sampler.sample(_store(np.array([0, 8], np.int32)), 256, np.random.default_rng(0))


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: ClusterBalancedSampler(0), "cluster.k: got 0"),
        (lambda: ClusterBalancedSampler(K, small_cluster_repeat=0), "repeat: got 0"),
        (lambda: EnergyPrioritisedSampler(epsilon=0.0), "epsilon: got 0.0"),
        (lambda: EnergyClusterSampler(K, epsilon=-1.0), "epsilon: got -1.0"),
    ],
    ids=["k-zero", "repeat-zero", "ebp-eps-zero", "ebp-cs-eps-negative"],
)
def test_constructor_errors_name_the_value(make, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        make()


@pytest.mark.parametrize(
    ("method", "cls"),
    [("her", UniformSampler), ("her-cs", ClusterBalancedSampler),
     ("her-ebp", EnergyPrioritisedSampler), ("her-ebp-cs", EnergyClusterSampler)],
    ids=["her", "her-cs", "her-ebp", "her-ebp-cs"],
)
def test_make_sampler_maps_methods_with_config_values(method: str, cls: type) -> None:
    config = HercsConfig()
    config = dataclasses.replace(
        config,
        cluster=dataclasses.replace(config.cluster, k=5, small_cluster_repeat=3),
        energy=dataclasses.replace(config.energy, epsilon=1e-3),
    )
    sampler = make_sampler(method, config.sampler_settings)
    assert type(sampler) is cls
    assert getattr(sampler, "k", 5) == 5
    assert getattr(sampler, "small_cluster_repeat", 3) == 3
    assert getattr(sampler, "epsilon", 1e-3) == 1e-3


def test_every_method_has_a_sampler_of_its_kind() -> None:
    kinds = {(True, True): EnergyClusterSampler, (True, False): ClusterBalancedSampler,
             (False, True): EnergyPrioritisedSampler, (False, False): UniformSampler}
    for name, method in METHODS.items():
        sampler = make_sampler(name, HercsConfig().sampler_settings)
        assert type(sampler) is kinds[method.needs.clusters, method.needs.energy], name


@pytest.mark.parametrize("method", ["her-ebp", "her-ebp-cs"])
def test_an_ebp_sampler_takes_its_simulators_epsilon_where_the_config_sets_none(
        method: str) -> None:
    """energy.epsilon unset: 1e-3 on v4, 1e-6 on the authors' v1 (docs/DESIGN.md §9.3)."""
    assert HercsConfig().energy.epsilon is None
    assert make_sampler(method, HercsConfig().sampler_settings).epsilon == 1e-3
    v1 = HercsConfig(task=dataclasses.replace(HercsConfig().task, env_version="v1"))
    assert make_sampler(method, v1.sampler_settings).epsilon == 1e-6


def test_make_sampler_refuses_unknown_method() -> None:
    with pytest.raises(ConfigError, match="'her-per'"):
        make_sampler("her-per", HercsConfig().sampler_settings)
