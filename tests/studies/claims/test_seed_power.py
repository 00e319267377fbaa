"""studies/claims/seed_power.py: its interval is claims.md's (rliable's independent bootstrap), a
study of two sides that differ in every run is always shown and one of equal sides seldom is, power
grows with the seeds, the smoothed draws stay in range, keep censored runs censored and keep the
runs' variance, and the committed report is what its JSON renders."""

from __future__ import annotations

import itertools
import json
import subprocess
import sys

import numpy as np
import pytest

from studies.claims import claim_runs
from studies.claims.claim_statistics import Score, improvement
from studies.claims.seed_power import (
    Population,
    improvement_interval,
    population,
    power,
    render,
)
from studies.study_output import REPO

REPORT = REPO / "docs" / "results" / "seed_power.json"


def _scores(successes: list[float], epochs: list[int]) -> list[Score]:
    return [Score(f"r{i}", s, e, e >= claim_runs.EPOCH)
            for i, (s, e) in enumerate(zip(successes, epochs, strict=True))]


def test_the_interval_is_the_one_claims_md_reports() -> None:
    x = _scores([.66, .83, .86, .61, .53], [45, 36, 38, 45, 48])
    y = _scores([.62, .11, .18, .37, .76], [47, 50, 50, 50, 42])
    success, _ = improvement(x, y, reps=4000)
    low, high = improvement_interval(population(x, "success").values,
                                     population(y, "success").values, 4000,
                                     np.random.default_rng(1))
    # two bootstraps of 4,000 reps over 5 runs a side: percentiles agree to a few hundredths
    assert abs(low - success.low) < 0.05 and abs(high - success.high) < 0.05


def test_power_is_one_for_sides_apart_and_small_for_equal_sides() -> None:
    rng = np.random.default_rng(0)
    good = population(_scores([.9, .95, .85, .92, .97], [20] * 5), "success")
    bad = population(_scores([.1, .05, .15, .12, .02], [50] * 5), "success")
    assert power(good, bad, 5, sims=50, reps=200, rng=rng) == 1.0
    mixed = Population.pooled(good, bad)
    # the interval's low end above .5 for equal sides: at most the bootstrap's own error rate
    # (nominal 2.5 %, a percentile bootstrap at n = 10 lets a few percent more through)
    assert power(mixed, mixed, 10, sims=200, reps=200, rng=rng) <= 0.10


def test_power_grows_with_the_seeds() -> None:
    rng = np.random.default_rng(0)
    x = population(_scores([.66, .83, .86, .61, .53], [45] * 5), "success")
    y = population(_scores([.62, .11, .18, .37, .76], [47] * 5), "success")
    few, many = (power(x, y, n, sims=150, reps=200, rng=rng) for n in (4, 20))
    assert many > few + 0.2


def test_draws_stay_in_range_and_censored_runs_stay_censored() -> None:
    rng = np.random.default_rng(0)
    p = population(_scores([0.0, 1.0, .5], [50, 10, 30]), "earlier")
    assert p.censored.tolist() == [True, False, False]
    d = p.draw(10_000, rng)
    assert d.min() >= -claim_runs.EPOCH and d.max() <= 0.0
    censored = np.isclose(d, -claim_runs.EPOCH)
    # a third of the draws are the censored run, exactly at -EPOCH; a crossing run reaches it
    # only through clipping, rarely with this spread
    assert 0.30 < censored.mean() < 0.40
    s = population(_scores([0.0, 1.0, .5], [50, 10, 30]), "success").draw(10_000, rng)
    assert s.min() >= 0.0 and s.max() <= 1.0 and len(np.unique(s)) > 1000


def test_smoothed_draws_keep_the_runs_mean_and_variance() -> None:
    # Runs well inside [0, 1], so that clipping does not touch the draws: the noise of
    # Silverman's bandwidth alone would add h² to the variance (+40 % with 6 runs).
    p = population(_scores([.40, .45, .50, .55, .60, .52], [30] * 6), "success")
    d = p.draw(400_000, np.random.default_rng(0))
    assert abs(d.mean() - p.values.mean()) < 0.001
    assert abs(d.var() / p.values.var() - 1) < 0.02
    assert len(np.unique(d)) > 100_000  # smoothed: not the six values again


def test_a_side_with_one_uncensored_run_is_drawn_without_noise() -> None:
    p = population(_scores([.2, .1, .9], [50, 50, 20]), "earlier")
    assert p.bandwidth == 0.0
    d = p.draw(1000, np.random.default_rng(0))
    assert set(d.tolist()) == {-claim_runs.EPOCH, -20.0}


def test_quick_mode_runs_and_writes_its_json_rendered(tmp_path) -> None:
    done = subprocess.run([sys.executable, "-m", "studies.claims.seed_power", "--quick", "--out",
                           str(tmp_path)], cwd=REPO, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    quick = json.loads((tmp_path / "seed_power.json").read_text())
    assert quick["claims"][0]["claim"] == "HER-CS against HER, the authors' (v1)"
    assert (tmp_path / "seed_power.md").read_text() == render(quick)


@pytest.mark.skipif(not REPORT.exists(), reason="docs/results/seed_power.json not committed")
@pytest.mark.docs_check
def test_docs_check_the_committed_report_is_its_json_rendered_and_power_grows() -> None:
    """A regeneration check of docs/results/seed_power.md, and of what it shows (more seeds,
    more power; few false gains) against the json committed beside it."""
    committed = json.loads(REPORT.read_text())
    assert REPORT.with_suffix(".md").read_text() == render(committed)
    for row in committed["claims"]:
        for metric in ("success", "earlier"):
            if row[metric] is None:
                continue
            powers = [row[metric]["power"][str(n)] for n in committed["seeds"]]
            # more seeds, more power: allow simulation noise between neighbours
            assert powers[-1] >= powers[0]
            assert all(b >= a - 0.08 for a, b in itertools.pairwise(powers))
            assert all(v <= 0.10 for v in row[metric]["false_gain"].values())
