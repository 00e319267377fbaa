"""The statistics of `hercs sweep report` over each arm's seeds (Agarwal et al. 2021): the IQM
with a 95 % percentile bootstrap interval, and the probability of improvement P(X > Y) (ties
half; Mann–Whitney U over n_X·n_Y) with an interval from resampling each arm on its own.

numpy only, so the product needs no statistics package; these equal rliable's for one task
(tests/studies/claims/test_claims.py pins them).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

REPS = 10_000
SEED = 0
LEVEL = 0.95


@dataclass(frozen=True)
class Interval:
    value: float
    low: float
    high: float

    def format(self, digits: int = 2) -> str:
        def short(v: float) -> str:
            text = f"{v:.{digits}f}"
            return text[1:] if text.startswith("0.") else text.replace("-0.", "-.")

        return f"{short(self.value)} [{short(self.low)}, {short(self.high)}]"


def iqm(values: Sequence[float] | np.ndarray) -> float:
    """The mean of the middle 50 %: 25 % trimmed off each end (scipy's trim_mean's rule: the
    floor of a quarter of the runs); below 4 runs nothing is trimmed."""
    v = np.sort(np.asarray(values, dtype=float).ravel())
    cut = int(0.25 * len(v))
    return float(v[cut:len(v) - cut].mean())


def probability_of_improvement(x: Sequence[float] | np.ndarray,
                               y: Sequence[float] | np.ndarray) -> float:
    """P(X > Y): the share of pairs (a of x, b of y) with a > b, ties counted half."""
    a = np.asarray(x, dtype=float).ravel()[:, None]
    b = np.asarray(y, dtype=float).ravel()[None, :]
    return float(((a > b).sum() + 0.5 * (a == b).sum()) / (a.size * b.size))


def _percentiles(samples: np.ndarray) -> tuple[float, float]:
    tail = (1 - LEVEL) / 2 * 100
    low, high = np.percentile(samples, [tail, 100 - tail])
    return float(low), float(high)


def bootstrap(values: Sequence[float], statistic: Callable[[np.ndarray], float] = iqm,
              reps: int = REPS, seed: int = SEED) -> Interval:
    """`statistic` of the runs with its percentile interval over `reps` resamples of them."""
    x = np.asarray(values, dtype=float)
    if x.size == 0:
        raise ValueError("no runs to bootstrap")
    rng = np.random.default_rng(seed)
    draws = x[rng.integers(0, x.size, (reps, x.size))]
    samples = np.array([statistic(row) for row in draws])
    return Interval(statistic(x), *_percentiles(samples))


def improvement(x: Sequence[float], y: Sequence[float], reps: int = REPS,
                seed: int = SEED) -> Interval:
    """P(X > Y) with its interval from resampling each side's runs on its own."""
    a, b = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if a.size == 0 or b.size == 0:
        raise ValueError("both sides need runs")
    rng = np.random.default_rng(seed)
    ra = a[rng.integers(0, a.size, (reps, a.size))][:, :, None]
    rb = b[rng.integers(0, b.size, (reps, b.size))][:, None, :]
    samples = (ra > rb).mean(axis=(1, 2)) + 0.5 * (ra == rb).mean(axis=(1, 2))
    return Interval(probability_of_improvement(a, b), *_percentiles(samples))
