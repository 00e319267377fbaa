"""What the samplers draw from, kept up to date as episodes come, go and are relabelled.

`SamplingIndex` keeps per-cluster member lists and counts (O(1) swap-remove), so HER-CS's draws
cost O(k + B), and cumulative sums of energy + ε per row (row 0 every slot, row c+1 cluster c),
recomputed once after a write, so an energy-weighted draw is a binary search, O(B log N).
A request's 40 minibatches are served in one go and the paper's schedule inserts one episode
per 10 minibatches, so the O(N) recomputation is paid at most once per request; sum trees
would avoid it but cost more per draw at the paper's buffer sizes (docs/PERFORMANCE.md §5).
Not thread-safe; the store owning it is called by one thread at a time.
"""

from __future__ import annotations

import numpy as np

from hercs.errors import ConfigError, SamplingError

WHOLE_BUFFER = 0
"""Row of every stored slot; row c + 1 is cluster c."""


class SamplingIndex:
    """Cluster member lists and per-row energy sums over `capacity` slots (module docstring).

    Slots are the store's: the valid ones are the prefix [0, size). Labels are cluster
    indices ≥ 0 or −1 (no cluster); rows for labels are added as labels appear.
    """

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ConfigError(f"SamplingIndex capacity: got {capacity!r}, must be >= 1")
        self.capacity = int(capacity)
        self._members = np.zeros((0, self.capacity), np.int64)
        self._counts = np.zeros(0, np.int64)
        self._position = np.full(self.capacity, -1, np.int64)
        self._label = np.full(self.capacity, -1, np.int64)
        self._energy = np.zeros(self.capacity, np.float64)
        self.size = 0
        self._sums: dict[tuple[float, float], _RowSums] = {}
        """The rows' cumulative energy^exponent + ε by (ε, exponent); emptied by a write (the
        next draw recomputes)."""

    # -- reads -------------------------------------------------------------------------------

    @property
    def counts(self) -> np.ndarray:
        """(labels,) int64: members of each cluster label seen so far (a copy)."""
        return self._counts.copy()

    @property
    def max_label(self) -> int:
        """The highest label with a member, −1 if none."""
        nonzero = np.flatnonzero(self._counts)
        return int(nonzero[-1]) if nonzero.size else -1

    def row_sizes(self, rows: np.ndarray) -> np.ndarray:
        """Slots in each row (0 for a label no episode has had)."""
        rows = np.asarray(rows, np.int64)
        counts = np.concatenate([[self.size], self._counts])
        return np.where(rows < counts.size, counts[np.minimum(rows, counts.size - 1)], 0)

    def members(self, label: int) -> np.ndarray:
        """The slots of cluster `label`, in no particular order (a copy)."""
        if not 0 <= label < len(self._counts):
            return np.zeros(0, np.int64)
        return self._members[label, : self._counts[label]].copy()

    # -- draws -------------------------------------------------------------------------------

    def draw(self, rows: np.ndarray, rng: np.random.Generator, *,
             epsilon: float | None = None, exponent: float = 1.0) -> np.ndarray:
        """One slot per entry of `rows` (row 0: any stored slot, row c+1: a member of c):
        uniform within the row, or with p ∝ energy^exponent + `epsilon` when `epsilon` is
        given. Every row drawn from must be non-empty."""
        rows = np.asarray(rows, np.int64)
        n = self.row_sizes(rows)
        if rows.size and int(n.min()) < 1:
            raise SamplingError(f"SamplingIndex.draw: a draw from empty row "
                                f"{int(rows[np.argmin(n)])}; no batch drawn")
        if epsilon is None or not rows.size:
            return self._uniform(rows, n, rng)
        if not epsilon > 0:
            raise ConfigError(f"SamplingIndex.draw: epsilon {epsilon!r} must be > 0")
        sums = self._row_sums(epsilon, exponent)
        first, end = sums.start[rows], sums.start[rows + 1]
        lo, hi = sums.cum[first], sums.cum[end]
        target = lo + rng.uniform(size=rows.size) * (hi - lo)
        # the last entry p with cum[p] ≤ target, so cum[p + 1] > target; the clip only
        # catches a target rounded up to its row's end (every entry weighs ≥ ε > 0)
        pos = np.clip(np.searchsorted(sums.cum, target, side="right") - 1, first, end - 1)
        return sums.order[pos]

    def _uniform(self, rows: np.ndarray, n: np.ndarray, rng: np.random.Generator
                 ) -> np.ndarray:
        rank = rng.integers(0, np.maximum(n, 1))
        if not len(self._counts):
            return rank
        cluster = np.maximum(rows - 1, 0)
        return np.where(rows == WHOLE_BUFFER, rank, self._members[cluster, rank])

    def _row_sums(self, epsilon: float, exponent: float) -> _RowSums:
        sums = self._sums.get((epsilon, exponent))
        if sums is None:
            sums = self._sums[(epsilon, exponent)] = _RowSums.of(self, epsilon, exponent)
        return sums

    # -- writes ------------------------------------------------------------------------------

    def put(self, slot: int, *, energy: float, label: int) -> None:
        """Slot `slot` now holds an episode with this energy and label (an insert; a slot
        below `size` is an overwrite: its previous episode leaves its cluster)."""
        if not 0 <= slot < self.capacity or slot > self.size:
            raise ConfigError(f"SamplingIndex.put: slot {slot} outside [0, {self.size}] "
                              f"(capacity {self.capacity})")
        if slot < self.size:
            self._leave(slot)
        else:
            self.size += 1
        self._energy[slot] = energy
        self._join(slot, label)
        self._sums.clear()

    def relabel(self, labels: np.ndarray) -> None:
        """Every stored slot's new label, (size,) — a new cluster model."""
        labels = np.asarray(labels, np.int64)
        if labels.shape != (self.size,):
            raise ConfigError(f"SamplingIndex.relabel: labels have shape {labels.shape}, "
                              f"expected ({self.size},)")
        self.rebuild(self._energy[: self.size].copy(), labels)

    def rebuild(self, energy: np.ndarray, labels: np.ndarray) -> None:
        """Start over from the stored slots' energies and labels, (size,) each."""
        energy = np.asarray(energy, np.float64)
        labels = np.asarray(labels, np.int64)
        size = len(energy)
        if labels.shape != (size,) or size > self.capacity:
            raise ConfigError(f"SamplingIndex.rebuild: {size} energies and labels of shape "
                              f"{labels.shape} for capacity {self.capacity}")
        self.size = size
        self._energy[:] = 0.0
        self._energy[:size] = energy
        self._label[:] = -1
        self._label[:size] = labels
        k = int(labels.max()) + 1 if size and labels.max() >= 0 else 0
        self._members = np.zeros((k, self.capacity), np.int64)
        self._counts = np.zeros(k, np.int64)
        self._position[:] = -1
        labelled = np.flatnonzero(labels >= 0)
        if labelled.size:
            order = labelled[np.argsort(labels[labelled], kind="stable")]
            counts = np.bincount(labels[labelled], minlength=k)
            starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
            rank = np.arange(order.size) - np.repeat(starts, counts)
            self._members[labels[order], rank] = order
            self._position[order] = rank
            self._counts[:] = counts
        self._sums.clear()

    # -- internals ---------------------------------------------------------------------------

    def _leave(self, slot: int) -> None:
        label = int(self._label[slot])
        if label < 0:
            return
        pos, last = int(self._position[slot]), int(self._counts[label]) - 1
        moved = int(self._members[label, last])
        self._members[label, pos] = moved
        self._position[moved] = pos
        self._position[slot] = -1
        self._counts[label] = last
        self._label[slot] = -1

    def _join(self, slot: int, label: int) -> None:
        self._label[slot] = label
        if label < 0:
            return
        if label >= len(self._counts):
            extra = label + 1 - len(self._counts)
            self._members = np.concatenate([self._members,
                                            np.zeros((extra, self.capacity), np.int64)])
            self._counts = np.concatenate([self._counts, np.zeros(extra, np.int64)])
        pos = int(self._counts[label])
        self._members[label, pos] = slot
        self._position[slot] = pos
        self._counts[label] = pos + 1


class _RowSums:
    """Every row's slots laid end to end (`order`: row 0 = 0..size−1, then each cluster's
    member list) with the cumulative energy + ε along them: row r is entries
    [start[r], start[r+1]) of `order`, its mass cum[start[r+1]] − cum[start[r]]."""

    def __init__(self, order: np.ndarray, cum: np.ndarray, start: np.ndarray) -> None:
        self.order, self.cum, self.start = order, cum, start

    @classmethod
    def of(cls, index: SamplingIndex, epsilon: float, exponent: float) -> _RowSums:
        parts = [np.arange(index.size)] + [index._members[c, :n]
                                           for c, n in enumerate(index._counts)]
        order = np.concatenate(parts)
        energy = index._energy[order]
        weight = (energy if exponent == 1.0 else np.power(energy, exponent)) + epsilon
        cum = np.concatenate([[0.0], np.cumsum(weight)])
        start = np.concatenate([[0], np.cumsum([len(p) for p in parts])])
        return cls(order, cum, start)
