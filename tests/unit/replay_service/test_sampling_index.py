"""`SamplingIndex`: the incrementally kept members and sum trees equal a from-scratch rebuild
after any sequence of inserts, evictions and relabels, and its draws have the promised law."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hercs.errors import ConfigError, SamplingError
from hercs.rl.samplers.sampling_index import WHOLE_BUFFER, SamplingIndex


def _reference(energy: np.ndarray, labels: np.ndarray) -> SamplingIndex:
    fresh = SamplingIndex(16)
    fresh.rebuild(energy, labels)
    return fresh


def _assert_same(index: SamplingIndex, energy: np.ndarray, labels: np.ndarray) -> None:
    """Same sizes, members (as sets), and row masses as a rebuild from the plain arrays."""
    assert index.size == len(energy)
    k = int(labels.max()) + 1 if labels.size and labels.max() >= 0 else 0
    want_counts = np.bincount(labels[labels >= 0], minlength=k)
    counts = index.counts
    assert counts[:k].tolist() == want_counts.tolist() and not counts[k:].any()
    for c in range(k):
        assert sorted(index.members(c).tolist()) == np.flatnonzero(labels == c).tolist()
    rows = np.arange(1 + len(counts))
    want_mass = [energy.sum()] + [energy[labels == c].sum() for c in range(len(counts))]
    sums = index._row_sums(0.0, 1.0)  # the prefix sums every energy draw reads
    mass = sums.cum[sums.start[rows + 1]] - sums.cum[sums.start[rows]]
    np.testing.assert_allclose(mass, want_mass, rtol=1e-9, atol=1e-12)


operation = st.one_of(
    st.tuples(st.just("insert"), st.floats(0, 5), st.integers(-1, 5)),
    st.tuples(st.just("relabel"), st.integers(0, 2**32 - 1), st.integers(1, 6)),
)


@settings(max_examples=200, deadline=None)
@given(st.lists(operation, max_size=80))
def test_incremental_index_equals_a_rebuild(ops) -> None:
    """Inserts into a ring of 16 slots (the 17th evicts slot 0, as the store does) and
    relabels by a new model, in any order: the index matches a rebuild at every step."""
    capacity = 16
    index = SamplingIndex(capacity)
    energy, labels = np.zeros(0), np.zeros(0, np.int64)
    next_id = 0
    for op in ops:
        if op[0] == "insert":
            _, e, label = op
            slot = next_id % capacity
            index.put(slot, energy=e, label=label)
            if slot < len(energy):
                energy[slot], labels[slot] = e, label
            else:
                energy, labels = np.append(energy, e), np.append(labels, label)
            next_id += 1
        else:
            _, seed, k = op
            labels = np.random.default_rng(seed).integers(-1, k, len(energy))
            index.relabel(labels)
        _assert_same(index, energy, labels)
    _assert_same(_reference(energy, labels), energy, labels)


def test_draws_follow_energy_plus_epsilon_in_each_row() -> None:
    """p(slot | row) = (e + ε) / Σ_row (e + ε), checked by chi-square over 400,000 draws, with
    zero-energy slots, a uniform row (ε only) and rows that lost members to evictions."""
    rng = np.random.default_rng(0)
    capacity = 50
    index = SamplingIndex(capacity)
    energy = np.zeros(capacity)
    labels = np.zeros(capacity, np.int64)
    for i in range(130):  # 2.6 rings: every slot overwritten at least twice
        slot = i % capacity
        e = float(rng.choice([0.0, rng.uniform(0, 2)]))
        label = int(rng.integers(-1, 3))
        index.put(slot, energy=e, label=label)
        energy[slot], labels[slot] = e, label
    epsilon = 0.05
    n = 400_000
    for row in (WHOLE_BUFFER, 1, 2, 3):
        members = np.arange(capacity) if row == WHOLE_BUFFER else np.flatnonzero(
            labels == row - 1)
        drawn = index.draw(np.full(n, row), np.random.default_rng(row), epsilon=epsilon)
        assert np.isin(drawn, members).all()
        weights = energy[members] + epsilon
        expected = n * weights / weights.sum()
        observed = np.bincount(drawn, minlength=capacity)[members]
        chi2 = float(np.sum((observed - expected) ** 2 / expected))
        df = len(members) - 1
        assert chi2 < df + 5 * np.sqrt(2 * df), (row, chi2, df)
        uniform = np.bincount(index.draw(np.full(n, row), np.random.default_rng(9)),
                              minlength=capacity)[members]
        flat = n / len(members)
        assert float(np.sum((uniform - flat) ** 2 / flat)) < df + 5 * np.sqrt(2 * df), row


def test_all_zero_energy_draws_uniformly_and_never_a_stray_slot() -> None:
    index = SamplingIndex(7)
    for slot in range(5):
        index.put(slot, energy=0.0, label=0)
    for row in (WHOLE_BUFFER, 1):
        drawn = index.draw(np.full(50_000, row), np.random.default_rng(row), epsilon=1e-6)
        counts = np.bincount(drawn, minlength=7)
        assert counts[5:].sum() == 0 and counts[:5].min() > 9_000


def test_a_write_invalidates_the_cached_sums() -> None:
    """Draws reuse the sums until the next write; after it they follow the new energies."""
    index = SamplingIndex(3)
    index.put(0, energy=1.0, label=0)
    index.put(1, energy=0.0, label=0)
    rng = np.random.default_rng(0)
    assert set(index.draw(np.ones(2000, np.int64), rng, epsilon=1e-9).tolist()) == {0}
    index.put(2, energy=5.0, label=0)
    drawn = np.bincount(index.draw(np.ones(60_000, np.int64), rng, epsilon=1e-9), minlength=3)
    assert drawn[1] == 0 and abs(drawn[2] / drawn.sum() - 5 / 6) < 0.01
    index.relabel(np.array([0, 0, 1]))
    assert set(index.draw(np.ones(500, np.int64), rng, epsilon=1e-9).tolist()) == {0}
    assert set(index.draw(np.full(500, 2), rng, epsilon=1e-9).tolist()) == {2}


def test_bad_writes_and_empty_rows_are_refused() -> None:
    index = SamplingIndex(4)
    with pytest.raises(ConfigError, match="slot 2 outside"):
        index.put(2, energy=1.0, label=0)  # slots fill in order: 0 first
    index.put(0, energy=1.0, label=0)
    with pytest.raises(SamplingError, match="empty row 2"):
        index.draw(np.array([2]), np.random.default_rng(0))  # cluster 1 has no member
    with pytest.raises(ConfigError, match="expected \\(1,\\)"):
        index.relabel(np.zeros(3, np.int64))
    with pytest.raises(ConfigError, match="capacity: got 0"):
        SamplingIndex(0)
