"""Regeneration checks: the committed figures are what studies/fig2 (`hercs plot`'s Fig. 2 with
the studies' styling), studies/schedule_effect and studies/claims compute from the committed
runs: a run added under docs/results/runs/ without redrawing docs/results/fig2.md,
asynchrony.md and claims.md (`make figures`) fails here."""

from __future__ import annotations

from pathlib import Path

import pytest

from hercs.apps import plot_tables, plots
from hercs.run.rundir import RunDir
from studies.legacy_runs import LEGACY_STYLE, legacy_lag
from tests.support import load_module

RESULTS = Path(__file__).resolve().parents[3] / "docs" / "results"


def committed_runs() -> list[Path]:
    return sorted(p for p in (RESULTS / "runs").iterdir() if RunDir(p).metrics.is_file())


def test_fig2_tables_equal_what_studies_fig2_computes_from_the_committed_runs() -> None:
    runs = committed_runs()
    assert runs, "docs/results/runs/ holds no run"
    ours = plots.group(plots.load_run(run, legacy_lag) for run in runs)
    expected = plot_tables.fig2_text(ours, plots.group(plots.load_reference()),
                                     style=LEGACY_STYLE)
    assert (RESULTS / "fig2.md").read_text() == expected, (
        "docs/results/fig2.md is not what the committed runs give: run `make figures`")
    assert (RESULTS / "fig2.png").stat().st_size > 10_000


def test_asynchrony_report_equals_what_schedule_effect_computes_from_the_committed_runs() -> None:
    effect = load_module("studies.schedule_effect.schedule_pairs")
    curves = [plots.load_run(run, legacy_lag) for run in committed_runs()]
    expected = effect.report(effect.compare_all(curves, 50), "python -m studies.schedule_effect")
    assert (RESULTS / effect.OUTPUT).read_text() == expected, (
        "docs/results/asynchrony.md is not what the committed runs give: run `make figures`")


@pytest.mark.slow  # the bootstrap at the committed file's 10,000 reps: ~10 s
def test_claims_equal_what_claims_py_computes_from_the_committed_runs() -> None:
    claim_runs = load_module("studies.claims.claim_runs")
    claims = load_module("studies.claims.claims")
    claims_report = load_module("studies.claims.claims_report")
    groups = claim_runs.load_groups(RESULTS / "runs")
    expected = claims_report.report(claims.evaluate(claims.CLAIMS, groups), groups,
                                    "python -m studies.claims")
    assert (RESULTS / claims_report.OUTPUT).read_text() == expected, (
        "docs/results/claims.md is not what the committed runs give: run `make figures`")
