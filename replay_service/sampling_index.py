"""What the samplers draw from, kept up to date as episodes come, go and are relabelled.

A draw used to rebuild its structures from the whole store on every minibatch: a bincount and
an argsort of the labels for the cluster shares, a cumulative sum of the energies for EBP.
That is O(N) per minibatch (about 1 ms at 20,000 episodes = 1e6 transitions). `SamplingIndex`
keeps them instead, and pays on the write side:

- per-cluster member lists (slots, with each slot's position for an O(1) swap-remove) and
  counts: HER-CS's plan and its uniform within-cluster draws are O(k + B);
- per-row energy sum trees: row 0 holds every stored slot's trajectory energy, row c+1 only
  cluster c's members' (0 elsewhere). An energy-weighted draw is one descent of depth
  ⌈log2 capacity⌉ for the whole batch at once, each draw in its own row.

Writes: `put` (an insert, which may evict the slot's previous episode) changes at most three
leaves, each with one vectorised add along its path to the root; `relabel` (a new cluster
model relabels every episode) and `rebuild` (a restored checkpoint) rebuild every row from
the leaves, which also clears the rounding that the adds accumulate.

EBP's p(slot) ∝ e + ε, with ε the sampler's, is drawn as a mixture, so the trees hold raw
energies and serve any ε: over a set S of n slots with energy mass E,
(e_i + ε) / (E + εn) = E/(E + εn) · e_i/E + εn/(E + εn) · 1/n,
i.e. with probability E/(E + εn) a draw descends the energy tree, otherwise it is uniform
over S.

Not thread-safe; the store owning it is called by one thread at a time.
"""

from __future__ import annotations

import numpy as np

from hercs.errors import ConfigError, SamplingError

WHOLE_BUFFER = 0
"""Row of every stored slot; row c + 1 is cluster c."""


class SamplingIndex:
    """Cluster member lists and energy sum trees over `capacity` slots (module docstring).

    Slots are the store's: the valid ones are the prefix [0, size). Labels are cluster
    indices ≥ 0 or −1 (no cluster); rows for labels are added as labels appear.
    """

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ConfigError(f"SamplingIndex capacity: got {capacity!r}, must be >= 1")
        self.capacity = int(capacity)
        self._depth = max(0, (self.capacity - 1).bit_length())
        self._leaves = 1 << self._depth
        self._tree = np.zeros((1, 2 * self._leaves), np.float64)
        self._members = np.zeros((0, self.capacity), np.int64)
        self._counts = np.zeros(0, np.int64)
        self._position = np.full(self.capacity, -1, np.int64)
        self._label = np.full(self.capacity, -1, np.int64)
        self._energy = np.zeros(self.capacity, np.float64)
        self.size = 0

    # -- reads -------------------------------------------------------------------------------

    @property
    def counts(self) -> np.ndarray:
        """(labels,) int64: members of each cluster label seen so far (read-only copy)."""
        return self._counts.copy()

    @property
    def max_label(self) -> int:
        """The highest label with a member, −1 if none."""
        nonzero = np.flatnonzero(self._counts)
        return int(nonzero[-1]) if nonzero.size else -1

    def energy_mass(self, rows: np.ndarray) -> np.ndarray:
        """Σ energy of each row (≥ 0; the adds' rounding can leave a tiny residue)."""
        return np.maximum(self._tree[rows, 1], 0.0)

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
             epsilon: float | None = None) -> np.ndarray:
        """One slot per entry of `rows` (row 0: any stored slot, row c+1: a member of c):
        uniform within the row, or with p ∝ energy + `epsilon` when `epsilon` is given.
        Every row drawn from must be non-empty."""
        rows = np.asarray(rows, np.int64)
        n = self.row_sizes(rows)
        if rows.size and int(n.min()) < 1:
            raise SamplingError(f"SamplingIndex.draw: a draw from empty row "
                                f"{int(rows[np.argmin(n)])}; no batch drawn")
        out = self._uniform(rows, n, rng)
        if epsilon is not None and rows.size:
            mass = self.energy_mass(rows)
            by_energy = rng.uniform(size=rows.size) * (mass + epsilon * n) < mass
            if by_energy.any():
                out[by_energy] = self._descend(rows[by_energy], mass[by_energy], rng)
        return out

    def _uniform(self, rows: np.ndarray, n: np.ndarray, rng: np.random.Generator
                 ) -> np.ndarray:
        rank = rng.integers(0, np.maximum(n, 1))
        if not len(self._counts):
            return rank
        cluster = np.maximum(rows - 1, 0)
        return np.where(rows == WHOLE_BUFFER, rank, self._members[cluster, rank])

    def _descend(self, rows: np.ndarray, mass: np.ndarray, rng: np.random.Generator
                 ) -> np.ndarray:
        """Inverse-CDF draws down each row's tree; a draw that float rounding steers onto a
        zero-energy leaf (at a boundary, about 1e-16 of the time) is drawn uniformly in its
        row instead, so a slot with no energy is never picked by energy."""
        target = rng.uniform(size=rows.size) * mass
        flat = self._tree.reshape(-1)  # a view: row r's node i is flat[r · width + i]
        base = rows * self._tree.shape[1]
        node = np.ones(rows.size, np.int64)
        for _ in range(self._depth):
            node <<= 1  # the left child
            left = flat.take(base + node)
            go_right = target >= left
            target -= left * go_right
            node += go_right
        slots = node - self._leaves
        stray = (slots >= self.size) | (self._tree[rows, node] <= 0.0)
        if stray.any():
            slots[stray] = self._uniform(rows[stray], self.row_sizes(rows[stray]), rng)
        return slots

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
        self._set_leaf(WHOLE_BUFFER, slot, energy)
        self._energy[slot] = energy
        self._join(slot, label)

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
        rows = int(labels.max()) + 2 if size else 1
        self._tree = np.zeros((max(rows, 1), 2 * self._leaves), np.float64)
        self._tree[WHOLE_BUFFER, self._leaves: self._leaves + size] = energy
        self._members = np.zeros((rows - 1, self.capacity), np.int64)
        self._counts = np.zeros(rows - 1, np.int64)
        self._position[:] = -1
        labelled = np.flatnonzero(labels >= 0)
        if labelled.size:
            order = labelled[np.argsort(labels[labelled], kind="stable")]
            counts = np.bincount(labels[labelled], minlength=rows - 1)
            starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
            rank = np.arange(order.size) - np.repeat(starts, counts)
            self._members[labels[order], rank] = order
            self._position[order] = rank
            self._counts[:] = counts
            self._tree[labels[labelled] + 1, self._leaves + labelled] = energy[labelled]
        for level in range(self._depth - 1, -1, -1):  # parents from children, exactly
            lo, hi = 1 << level, 1 << (level + 1)
            self._tree[:, lo:hi] = self._tree[:, 2 * lo: 2 * hi: 2] + self._tree[:, 2 * lo + 1:
                                                                                 2 * hi: 2]

    # -- internals ---------------------------------------------------------------------------

    def _set_leaf(self, row: int, slot: int, value: float) -> None:
        node = self._leaves + slot
        delta = value - self._tree[row, node]
        if delta:
            path = node >> np.arange(self._depth + 1)
            self._tree[row, path] += delta
            self._tree[row, node] = value  # the leaf itself stays exact

    def _leave(self, slot: int) -> None:
        label = int(self._label[slot])
        if label < 0:
            return
        self._set_leaf(label + 1, slot, 0.0)
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
            self._grow(label + 1)
        pos = int(self._counts[label])
        self._members[label, pos] = slot
        self._position[slot] = pos
        self._counts[label] = pos + 1
        self._set_leaf(label + 1, slot, float(self._energy[slot]))

    def _grow(self, labels: int) -> None:
        extra = labels - len(self._counts)
        self._tree = np.concatenate([self._tree, np.zeros((extra, self._tree.shape[1]))])
        self._members = np.concatenate([self._members,
                                        np.zeros((extra, self.capacity), np.int64)])
        self._counts = np.concatenate([self._counts, np.zeros(extra, np.int64)])
