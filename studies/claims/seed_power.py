"""How many seeds a side would show HER-CS's gain over HER? (seed power)

    python -m studies.claims.seed_power          # ~1 min; writes docs/results/seed_power.{json,md}

Simulated studies of n runs a side, drawn from the committed runs (smoothed bootstrap); the
method is stated in docs/results/seed_power.md, why it is asked in docs/results/README.md."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hercs.apps.plots.numbers import rate
from studies.claims import claim_runs, claims
from studies.claims.claim_statistics import Score
from studies.study_output import REPO, write_report

NAME = "seed_power"
CLAIM_TITLES = ("HER-CS against HER, the authors' (v1)", "HER-CS against HER, v1",
                "HER-CS against HER, v4")
SEEDS = (5, 6, 10, 15, 20, 30)
SIMS = 400
REPS = 1000
RNG_SEED = 0
METRICS = ("success", "earlier")
"""success: P(X's success after epoch 50 > Y's); earlier: P(X passes 0.5 before Y)."""


@dataclass(frozen=True)
class Population:
    """One side's runs as a smoothed distribution of the number `metric` ranks them by,
    larger better: the success after epoch 50 in [0, 1], or minus the epoch at 0.5 in
    [-EPOCH, 0], where a censored run sits at -EPOCH (two censored runs tie)."""

    values: np.ndarray
    censored: np.ndarray
    low: float
    high: float

    @property
    def smoothed(self) -> np.ndarray:
        """The runs that get noise: those that are not censored."""
        return self.values[~self.censored]

    @property
    def bandwidth(self) -> float:
        """Silverman's rule of thumb over the uncensored runs, 0.9 · sd · n^(-1/5) (the IQR
        term dropped: with 5–6 runs it is as noisy as the sd); 0 with fewer than 2."""
        runs = self.smoothed
        if runs.size < 2:
            return 0.0
        return 0.9 * float(runs.std(ddof=1)) * runs.size ** -0.2

    def draw(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """n runs: a resampled run plus noise, shrunk about the uncensored runs' mean by
        1/sqrt(1 + h²/σ²) (σ² their variance as resampled, ddof 0), so that the uncensored
        draws have the variance a plain bootstrap would give, not σ² + h²."""
        i = rng.integers(0, self.values.size, n)
        h, runs = self.bandwidth, self.smoothed
        if h == 0.0:
            return self.values[i].copy()
        mean, var = float(runs.mean()), float(runs.var())
        noisy = mean + (self.values[i] - mean + rng.normal(0.0, h, n)) / np.sqrt(1 + h * h / var)
        return np.clip(np.where(self.censored[i], self.values[i], noisy), self.low, self.high)

    @staticmethod
    def pooled(a: Population, b: Population) -> Population:
        return Population(np.concatenate([a.values, b.values]),
                          np.concatenate([a.censored, b.censored]), a.low, a.high)


def population(scores: Sequence[Score], metric: str) -> Population:
    if metric == "success":
        return Population(np.array([s.success for s in scores], dtype=float),
                          np.zeros(len(scores), dtype=bool), 0.0, 1.0)
    return Population(-np.array([s.at_half for s in scores], dtype=float),
                      np.array([s.censored for s in scores], dtype=bool),
                      -float(claim_runs.EPOCH), 0.0)


def improvement_interval(x: np.ndarray, y: np.ndarray, reps: int, rng: np.random.Generator
                         ) -> tuple[float, float]:
    """The 95 % percentile interval of P(X > Y) (ties half) from resampling each side's runs
    on its own: rliable's independent stratified bootstrap for one task, vectorised."""
    a = x[rng.integers(0, x.size, (reps, x.size))][:, :, None]
    b = y[rng.integers(0, y.size, (reps, y.size))][:, None, :]
    p = (a > b).mean(axis=(1, 2)) + 0.5 * (a == b).mean(axis=(1, 2))
    low, high = np.percentile(p, [2.5, 97.5])
    return float(low), float(high)


def power(x: Population, y: Population, n: int, sims: int, reps: int,
          rng: np.random.Generator) -> float:
    """The share of `sims` studies of n runs a side, drawn from x and y, whose interval of
    P(X > Y) lies above .5."""
    shown = 0
    for _ in range(sims):
        low, _ = improvement_interval(x.draw(n, rng), y.draw(n, rng), reps, rng)
        shown += low > 0.5
    return shown / sims


def run(runs_dir: Path, seeds: Sequence[int], sims: int, reps: int) -> dict[str, Any]:
    groups = claim_runs.load_groups(runs_dir)
    by_title = {c.title: c for c in claims.CLAIMS}
    rows = []
    for title in CLAIM_TITLES:
        x_side, y_side = claims.resolve(by_title[title], groups)
        row: dict[str, Any] = {"claim": title, "x": x_side.group.label,
                               "y": y_side.group.label, "seeds": [x_side.n, y_side.n]}
        for metric in METRICS:
            if min(x_side.n, y_side.n) < claim_runs.MIN_SEEDS:
                row[metric] = None
                continue
            x, y = population(x_side.scores, metric), population(y_side.scores, metric)
            rng = np.random.default_rng(RNG_SEED)
            pooled = Population.pooled(x, y)
            row[metric] = {
                "power": {str(n): power(x, y, n, sims, reps, rng) for n in seeds},
                "false_gain": {str(n): power(pooled, pooled, n, sims, reps, rng)
                               for n in seeds}}
        rows.append(row)
    return {"seeds": list(seeds), "sims": sims, "reps": reps, "claims": rows}


def render(summary: dict[str, Any]) -> str:
    seeds = summary["seeds"]
    head = "| claim | seeds now X / Y | metric | " + " | ".join(
        f"n = {n}" for n in seeds) + " |"
    lines = [
        "# How many seeds a side would show HER-CS's gain over HER",
        "",
        "Drawn by `python -m studies.claims.seed_power` from the committed runs and the authors' "
        "curves (the sides of docs/results/claims.md). Each cell: the share of "
        f"{summary['sims']} simulated studies with n runs a side, drawn from the sides' "
        "runs (a smoothed bootstrap that keeps the runs' variance, studies/claims/seed_power.py "
        "says "
        "why), whose 95 % bootstrap "
        f"interval of P(HER-CS > HER) lies above .5 (each study's interval from "
        f"{summary['reps']:,} bootstrap reps; claims.md uses 10,000 for its one interval a "
        "line, which would make these 14,400 studies ten times slower). *success*: the success "
        "after epoch 50; *earlier*: passing 0.5 (10-epoch mean) first. In brackets: the same "
        "with both sides drawn from the pooled runs, i.e. how often a gain is shown where "
        "there is none. A plug-in estimate: it takes the spread of 5–6 seeds as the truth.",
        "",
        head,
        "|---|---|---|" + "---|" * len(seeds),
    ]
    for row in summary["claims"]:
        for metric in METRICS:
            cell = row[metric]
            if cell is None:
                values_ = ["–"] * len(seeds)
            else:
                values_ = [f"{rate(cell['power'][str(n)])} ({rate(cell['false_gain'][str(n)])})"
                           for n in seeds]
            lines.append(f"| {row['claim']} | {row['seeds'][0]} / {row['seeds'][1]} | "
                         f"{metric} | " + " | ".join(values_) + " |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=Path, default=REPO / "docs" / "results" / "runs")
    p.add_argument("--out", type=Path, default=None,
                   help="folder for seed_power.{json,md} (default docs/results; none with "
                        "--quick)")
    p.add_argument("--quick", action="store_true", help="40 simulations of 200 reps, n = 5, 10")
    args = p.parse_args(argv)
    if not args.runs.is_dir():
        p.error(f"--runs {args.runs}: not a directory")
    seeds, sims, reps = ((5, 10), 40, 200) if args.quick else (SEEDS, SIMS, REPS)
    out = args.out if args.out is not None or args.quick else REPO / "docs" / "results"
    summary = run(args.runs, seeds, sims, reps)
    text = render(summary)
    print(text, end="")
    write_report(out, NAME, summary, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
