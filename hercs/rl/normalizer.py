"""Running mean/std normaliser for observations and goals, as in the reference DDPG+HER.

mean = Σv / n, std = sqrt(max(eps², Σv²/n − mean²)), normalize(v) = clip((v − mean) / std).
`update` only accumulates float64 sums; `mean`/`std` change only in `recompute_stats`, so a
policy uses one fixed set of statistics between recomputations, as the reference's within a
cycle. The count starts at 0 (the reference's sums are float32 and its count n+1:
docs/DESIGN.md §9.5). Before any data mean = 0 and std = 1. `state_dict()` holds exactly sum,
sumsq, count, mean and std: what the replay sends the learner and the learner the actors.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

STAT_KEYS = ("sum", "sumsq", "count", "mean", "std")
"""Keys of a normaliser state dict, in wire order."""


NormalizerState = dict[str, np.ndarray | float]
"""One normaliser's statistics {sum, sumsq, count, mean, std}: what `Normalizer.state_dict`
returns, what `Weights` and `Batch` messages carry (hercs.wire.codec) and what `load_state_dict`
takes. `count` is a 0-d array from `state_dict` and a float off the wire; both load."""


class Normalizer:
    """Running statistics over vectors of length `size`; see the module docstring."""

    def __init__(self, size: int, *, eps: float = 0.01, clip_range: float = 5.0) -> None:
        if size < 1:
            raise ValueError(f"Normalizer size: got {size!r}, must be >= 1")
        if eps <= 0:
            raise ValueError(f"Normalizer eps: got {eps!r}, must be > 0")
        if clip_range <= 0:
            raise ValueError(f"Normalizer clip_range: got {clip_range!r}, must be > 0")
        self.size = int(size)
        self.eps = float(eps)
        self.clip_range = float(clip_range)
        self.sum = np.zeros(self.size, np.float64)
        self.sumsq = np.zeros(self.size, np.float64)
        self.count = 0
        self.mean = np.zeros(self.size, np.float64)
        self.std = np.ones(self.size, np.float64)

    def update(self, v: np.ndarray) -> None:
        """Accumulate vectors `v` of shape (..., size); any leading shape is flattened."""
        v = np.asarray(v, dtype=np.float64)
        if v.ndim == 0 or v.shape[-1] != self.size:
            raise ValueError(
                f"Normalizer.update: got shape {v.shape}, last axis must be size={self.size}"
            )
        v = v.reshape(-1, self.size)
        self.sum += v.sum(axis=0)
        self.sumsq += np.square(v).sum(axis=0)
        self.count += v.shape[0]

    def recompute_stats(self) -> None:
        """Set `mean` and `std` from the accumulated sums (no-op while count is 0)."""
        if self.count == 0:
            return
        self.mean = self.sum / self.count
        var = self.sumsq / self.count - np.square(self.mean)
        self.std = np.sqrt(np.maximum(self.eps**2, var))

    def normalize(self, v: np.ndarray) -> np.ndarray:
        """clip((v − mean)/std, ±clip_range) over the last axis, as float32 (network input)."""
        v = np.asarray(v, dtype=np.float64)
        out = np.clip((v - self.mean) / self.std, -self.clip_range, self.clip_range)
        return out.astype(np.float32)

    def state_dict(self) -> NormalizerState:
        """The five statistics as float64 arrays (count as a 0-d array); copies."""
        return {
            "sum": self.sum.copy(),
            "sumsq": self.sumsq.copy(),
            "count": np.asarray(self.count, dtype=np.float64),
            "mean": self.mean.copy(),
            "std": self.std.copy(),
        }

    def with_state(self, state: Mapping[str, np.ndarray | float]) -> Normalizer:
        """A new normaliser of the same size and settings holding `state`; self is untouched,
        so callers can validate several normalisers before adopting any."""
        fresh = Normalizer(self.size, eps=self.eps, clip_range=self.clip_range)
        fresh.load_state_dict(state)
        return fresh

    def load_state_dict(self, state: Mapping[str, np.ndarray | float]) -> None:
        """Adopt statistics produced by another normaliser's `state_dict` (e.g. off the wire),
        as `checked_state` requires them; on error nothing is changed."""
        vectors, count = checked_state(state, self.size)
        self.sum, self.sumsq = vectors["sum"], vectors["sumsq"]
        self.mean, self.std = vectors["mean"], vectors["std"]
        self.count = count


def checked_state(state: Mapping[str, np.ndarray | float], size: int
                  ) -> tuple[dict[str, np.ndarray], int]:
    """A normaliser state's vectors (float64 copies) and count, if a normaliser of `size` may
    hold it: all five keys, vectors of shape (size,), everything finite, `std` positive and
    `count` a non-negative whole number; else ValueError saying which."""
    missing = [k for k in STAT_KEYS if k not in state]
    if missing:
        raise ValueError(f"Normalizer.load_state_dict: missing key(s) {missing}; "
                         f"need {list(STAT_KEYS)}")
    vectors = {}
    for key in ("sum", "sumsq", "mean", "std"):
        arr = np.asarray(state[key], dtype=np.float64)
        if arr.shape != (size,):
            raise ValueError(f"Normalizer.load_state_dict: {key!r} has shape {arr.shape}, "
                             f"expected ({size},)")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"Normalizer.load_state_dict: {key!r} holds NaN or Inf")
        vectors[key] = arr.copy()
    if np.any(vectors["std"] <= 0):
        raise ValueError("Normalizer.load_state_dict: 'std' must be > 0 everywhere, "
                         f"got min {vectors['std'].min()!r}")
    count = float(np.asarray(state["count"]).reshape(()))
    if not (np.isfinite(count) and count >= 0 and count.is_integer()):
        raise ValueError(f"Normalizer.load_state_dict: 'count' got {count!r}, "
                         "must be a whole number >= 0")
    return vectors, int(count)
