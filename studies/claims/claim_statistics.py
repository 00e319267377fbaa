"""The statistics of studies/claims/claims.py over runs' scores: IQM and mean with rliable's
stratified bootstrap intervals, the probability of improvement of one side over another
(rliable's functions; inside the bootstraps, the IQM and P(X > Y) of `hercs sweep report`'s
statistics, hercs/apps/sweep/stats.py, the one numpy implementation, at a fraction of scipy's
cost and pinned equal to rliable's by tests/studies/claims/test_claims.py), and the exact
permutation p of P(X > Y) (`rank_test_p`)."""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from hercs.apps.sweep.stats import iqm, probability_of_improvement

REPS = 10_000
"""Bootstrap replications. With 2–5 runs a side has at most 126 distinct resamples: at 10,000
the printed digits of the committed claims are the same with RNG seeds 0 and 1."""
RNG_SEED = 0
EXACT_SPLITS = 200_000
"""`rank_test_p` enumerates every split of the pooled runs up to this many (C(12, 6) = 924
for 6 seeds a side); above, it draws REPS random ones."""


@dataclass(frozen=True)
class Score:
    """One run's two numbers at epoch EPOCH."""

    run: str
    success: float
    """The 10-epoch trailing mean of the test success after epoch EPOCH."""
    at_half: int
    """The first epoch (counted from 0) whose trailing mean exceeds 0.5; `epoch` when none
    does by then (censored)."""
    censored: bool
    at_high: int | None = None
    """The same for 0.9 (None where not computed)."""
    censored_high: bool = False


@contextmanager
def _numpy_global_seed(seed: int) -> Iterator[None]:
    """rliable's bootstraps draw their resamples with `np.random.choice` from numpy's global
    RNG (StratifiedBootstrap.update_indices), whatever `random_state` says: seed it for the
    call and put the caller's state back."""
    state = np.random.get_state()
    np.random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(state)


@dataclass(frozen=True)
class Estimate:
    value: float
    low: float
    high: float


@dataclass(frozen=True)
class SideStats:
    """IQM and mean of the success after EPOCH and of the epoch at 0.5, with intervals."""

    success_iqm: Estimate
    success_mean: Estimate
    epoch_iqm: Estimate
    epoch_mean: Estimate


def _matrix(scores: Sequence[Score]) -> np.ndarray:
    """(runs × 2): success after EPOCH, epoch at 0.5; rliable's (runs × tasks) layout, the
    two numbers as two tasks so that each is resampled over runs on its own."""
    return np.array([[s.success, float(s.at_half)] for s in scores], dtype=float)


def _estimates(point: Sequence[float], interval: np.ndarray) -> list[Estimate]:
    return [Estimate(float(point[i]), float(interval[0, i]), float(interval[1, i]))
            for i in range(len(point))]


def side_stats(scores: Sequence[Score], reps: int = REPS, seed: int = RNG_SEED) -> SideStats:
    """IQM and mean of both numbers over the runs, with rliable's stratified bootstrap
    intervals; the point estimates are rliable's own functions'."""
    from rliable import library, metrics

    def func(m: np.ndarray) -> np.ndarray:
        return np.array([iqm(m[:, :1]), m[:, 0].mean(), iqm(m[:, 1:]), m[:, 1].mean()])

    m = _matrix(scores)
    with _numpy_global_seed(seed):
        _, interval = library.get_interval_estimates({"side": m}, func, reps=reps)
    point = [metrics.aggregate_iqm(m[:, :1]), metrics.aggregate_mean(m[:, :1]),
             metrics.aggregate_iqm(m[:, 1:]), metrics.aggregate_mean(m[:, 1:])]
    return SideStats(*_estimates(point, interval["side"]))


def improvement(x: Sequence[Score], y: Sequence[Score], reps: int = REPS,
                seed: int = RNG_SEED) -> tuple[Estimate, Estimate]:
    """P(X > Y) for the success after EPOCH, and P(X reaches 0.5 earlier than Y): the
    probability that a run of X beats a run of Y, ties half; two runs both censored at
    EPOCH are a tie, and a censored run loses to every run that crossed. Intervals from
    rliable's independent stratified bootstrap of both sides; the point estimates are
    rliable's own function's."""
    from rliable import library, metrics

    def func(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.array([probability_of_improvement(a[:, 0], b[:, 0]),
                         probability_of_improvement(-a[:, 1], -b[:, 1])])

    mx, my = _matrix(x), _matrix(y)
    with _numpy_global_seed(seed):
        _, interval = library.get_interval_estimates({"xy": [mx, my]}, func, reps=reps)
    point = [metrics.probability_of_improvement(mx[:, :1], my[:, :1]),
             metrics.probability_of_improvement(-mx[:, 1:], -my[:, 1:])]
    success, earlier = _estimates(point, interval["xy"])
    return success, earlier


@dataclass(frozen=True)
class EpochStats:
    """One more epoch milestone (the epoch at 0.9) for a claim: each side's IQM and mean with
    intervals, and P(X gets there earlier). Bootstrapped on its own, so that the 0.5 and
    success numbers are the same draws as before it existed."""

    x_iqm: Estimate
    y_iqm: Estimate
    x_mean: Estimate
    y_mean: Estimate
    earlier: Estimate


def epoch_stats(x: Sequence[int], y: Sequence[int], reps: int = REPS,
                seed: int = RNG_SEED) -> EpochStats:
    """IQM and mean of each side's epochs (censored runs at the cut, as for 0.5) with
    rliable's stratified bootstrap intervals, and P(X earlier) with its independent one."""
    from rliable import library, metrics

    mx, my = (np.asarray(v, dtype=float)[:, None] for v in (x, y))

    def side(m: np.ndarray) -> np.ndarray:
        return np.array([iqm(m), m.mean()])

    def earlier(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.array([probability_of_improvement(-a, -b)])

    out: list[Estimate] = []
    for m in (mx, my):
        with _numpy_global_seed(seed):
            _, interval = library.get_interval_estimates({"side": m}, side, reps=reps)
        out += _estimates([metrics.aggregate_iqm(m), metrics.aggregate_mean(m)],
                          interval["side"])
    with _numpy_global_seed(seed):
        _, interval = library.get_interval_estimates({"xy": [mx, my]}, earlier, reps=reps)
    [p] = _estimates([metrics.probability_of_improvement(-mx, -my)], interval["xy"])
    return EpochStats(out[0], out[2], out[1], out[3], p)


def _splits(nx: int, ny: int) -> int:
    return math.comb(nx + ny, nx)


def rank_test_p(x: Sequence[float], y: Sequence[float], seed: int = RNG_SEED) -> float:
    """Two-sided p of P(X > Y) under the null that the runs of both sides are exchangeable:
    the share of the splits of the pooled runs into sides of these sizes whose P(X > Y) lies
    at least as far out (scipy.stats.permutation_test: twice the smaller tail, at most 1).
    Exact, every split, up to EXACT_SPLITS; a Mann–Whitney test whose ties count half. Unlike
    the bootstrap interval it is honest at 2–5 seeds: with n_X = n_Y = 3 no outcome can give
    less than 2/20 = .10, and with 2 a side less than 2/6 = .33."""
    from scipy import stats

    exact = _splits(len(x), len(y)) <= EXACT_SPLITS
    result = stats.permutation_test(
        (np.asarray(x, dtype=float), np.asarray(y, dtype=float)),
        lambda a, b: probability_of_improvement(a, b), permutation_type="independent",
        alternative="two-sided", vectorized=False,
        n_resamples=np.inf if exact else REPS, random_state=seed)
    return float(result.pvalue)
