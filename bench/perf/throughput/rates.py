"""Rates from timestamped progress: percentiles, rates pooled over time slices, and the
alternation of a system's slices with a reference's (`Alternation`)."""

from __future__ import annotations

import bisect
import dataclasses
import math
from collections.abc import Sequence
from typing import Any

from bench.perf.throughput import BenchError


def percentile(values: Sequence[float], q: float) -> float:
    """The q-th percentile (0 ≤ q ≤ 100), linear between the two closest ranks.

    Same definition as numpy's default (`method="linear"`): sorted x, position
    p = (n − 1)·q/100, result x[⌊p⌋] + (p − ⌊p⌋)·(x[⌊p⌋+1] − x[⌊p⌋]).
    """
    if not values:
        raise ValueError("percentile: got no values")
    if not 0.0 <= q <= 100.0:
        raise ValueError(f"percentile: got q={q}, must lie in [0, 100]")
    xs = sorted(float(v) for v in values)
    pos = (len(xs) - 1) * q / 100.0
    lo = math.floor(pos)
    hi = min(lo + 1, len(xs) - 1)
    return xs[lo] + (pos - lo) * (xs[hi] - xs[lo])


def pooled_rate(slices: Sequence[Sequence[tuple[float, float]]]) -> float:
    """Rate over several time slices from (arrival time, cumulative count) samples.

    Σ (count_last − count_first) / Σ (t_last − t_first) over the slices with at least two
    samples: each slice contributes only whole intervals between its own arrivals, so the
    pauses between slices (and partial intervals at their edges) are never counted.
    """
    amount = span = 0.0
    for samples in slices:
        if len(samples) < 2:
            continue
        ordered = sorted(samples)
        amount += ordered[-1][1] - ordered[0][1]
        span += ordered[-1][0] - ordered[0][0]
    if span <= 0:
        raise BenchError(f"pooled_rate: no slice of {len(slices)} holds two distinct arrivals")
    return amount / span


def work_in_windows(samples: Sequence[tuple[float, float]],
                    windows: Sequence[tuple[float, float]]) -> float:
    """Work done inside time windows, from (time, cumulative count) samples.

    Per window (start, end]: count at the last sample at or before `end` minus count at the
    last sample at or before `start` (0 before the first sample: counts start at 0). Unlike
    `pooled_rate` it counts work that straddles a window's edges as falling in the window it
    finished in, which evens out over many windows; it pairs with CPU time measured over the
    same windows.
    """
    ordered = sorted(samples)
    times = [t for t, _ in ordered]

    def count_at(t: float) -> float:
        i = bisect.bisect_right(times, t)
        return ordered[i - 1][1] if i else 0.0

    return sum(count_at(end) - count_at(start) for start, end in windows)


@dataclasses.dataclass
class Alternation:
    """What `Harness.alternate` measured."""

    slice_s: float
    """Seconds each side ran per turn."""
    rounds: int
    """System slices, each between two reference slices."""
    reference: list[tuple[float, float, float]] = dataclasses.field(default_factory=list)
    """(work done, wall seconds, CPU seconds of this thread) per reference slice."""
    windows: list[tuple[float, float]] = dataclasses.field(default_factory=list)
    """(start, end) monotonic times of each system slice."""
    system_cpu_s: list[float] = dataclasses.field(default_factory=list)
    """CPU seconds the system's child used in each slice (its threads included)."""

    @property
    def reference_rate(self) -> float:
        return sum(w for w, _, _ in self.reference) / sum(s for _, s, _ in self.reference)

    @property
    def reference_rate_per_cpu(self) -> float:
        return sum(w for w, _, _ in self.reference) / sum(c for _, _, c in self.reference)

    def rates(self, samples: Sequence[tuple[float, float]]) -> tuple[float, float, float, float]:
        """(system rate, its rate per CPU second, reference rate, its rate per CPU second), the
        system's from (time, cumulative count) samples of its progress."""
        work = work_in_windows(samples, self.windows)
        return (pooled_rate(self._slices(samples)), work / sum(self.system_cpu_s),
                self.reference_rate, self.reference_rate_per_cpu)

    def _slices(self, samples: Sequence[tuple[float, float]]) -> list[list[tuple[float, float]]]:
        return [[(t, c) for t, c in samples if a <= t <= b] for a, b in self.windows]

    def details(self, samples: Sequence[tuple[float, float]], *, system: str,
                reference: str) -> dict[str, Any]:
        """For the JSON details: per-slice rates and CPU shares of both sides, then `slice_s`
        and `rounds`; the per-slice keys are `<side>_<unit>_per_s_by_slice` and
        `<side>_cpu_share_by_slice` with `system` and `reference` naming the sides (e.g.
        "actor_steps", "raw_steps")."""
        return {
            f"{reference}_per_s_by_slice": [w / sec for w, sec, _ in self.reference],
            f"{system}_per_s_by_slice": [pooled_rate([x]) if len(x) > 1 else None
                                         for x in self._slices(samples)],
            f"{system.rsplit('_', 1)[0]}_cpu_share_by_slice": [
                c / (b - a) for c, (a, b) in zip(self.system_cpu_s, self.windows, strict=True)],
            f"{reference.rsplit('_', 1)[0]}_cpu_share_by_slice": [
                c / sec for _, sec, c in self.reference],
            "slice_s": self.slice_s, "rounds": self.rounds,
        }
