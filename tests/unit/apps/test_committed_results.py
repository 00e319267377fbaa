"""Regeneration checks: the committed figures are what `hercs plot --figure 2` (run here as a
user runs it), studies/schedule_effect and studies/claims compute from the committed runs: a
run added under docs/results/runs/ without redrawing docs/results/fig2.md, asynchrony.md and
claims.md (`make figures`) fails here."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from hercs.apps.plots import curves as plots
from hercs.run.rundir import RunDir
from tests.support import REPO, load_module

RESULTS = Path(__file__).resolve().parents[3] / "docs" / "results"


def committed_runs() -> list[Path]:
    return sorted(p for p in (RESULTS / "runs").iterdir() if RunDir(p).metrics.is_file())


@pytest.mark.docs_check
def test_the_committed_fig2_is_what_hercs_plot_figure_2_writes(tmp_path: Path) -> None:
    """The README's and `make figures`' command, in its own process, over every committed
    run folder (the shell's docs/results/runs/*/): its table is the committed one, byte for
    byte, and stderr names each panel's series left out and the flags that draw them."""
    runs = committed_runs()
    assert runs, "docs/results/runs/ holds no run"
    figure, table = tmp_path / "fig2.png", tmp_path / "fig2.md"
    done = subprocess.run(
        [sys.executable, "-m", "hercs.apps.cli", "plot", "--figure", "2",
         *(f"{run}/" for run in runs), "-o", str(figure), "--table", str(table)],
        cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert table.read_text() == (RESULTS / "fig2.md").read_text(), (
        "docs/results/fig2.md is not what `hercs plot --figure 2` writes: run `make figures`")
    assert figure.stat().st_size > 10_000 and (RESULTS / "fig2.png").stat().st_size > 10_000
    assert "FetchPush: HER vs HER-CS: 3 more series not drawn" in done.stderr
    assert ("HER-CS, no lag bound, prefetch 3, actor queue 2, rate tolerance 80" in done.stderr
            and "--all-series" in done.stderr)


@pytest.mark.docs_check
def test_asynchrony_report_equals_what_schedule_effect_computes_from_the_committed_runs() -> None:
    effect = load_module("studies.schedule_effect.schedule_pairs")
    curves = [plots.load_run(run) for run in committed_runs()]
    expected = effect.report(effect.compare_all(curves, 50), "python -m studies.schedule_effect")
    assert (RESULTS / effect.OUTPUT).read_text() == expected, (
        "docs/results/asynchrony.md is not what the committed runs give: run `make figures`")


@pytest.fixture(scope="module")
def claim_results() -> tuple[dict, list]:
    """The committed runs' groups and claims.py's results for every claim, as
    `python -m studies.claims` computes them for claims.md and the README's tables alike: its
    bootstrap (10,000 reps a claim) is the cost of these checks, so it is made once."""
    claim_runs = load_module("studies.claims.claim_runs")
    claims = load_module("studies.claims.claims")
    groups = claim_runs.load_groups(RESULTS / "runs")
    return groups, claims.evaluate(claims.CLAIMS, groups)


# The bootstrap over every claim took 191 CPU s, 496 s on one core of the 2-core development
# machine beside its training grid: the suite's 600 s would fail a machine twice as slow, which
# is no hang; this bound is one.
CLAIMS_TIMEOUT_S = 3600


@pytest.mark.slow
@pytest.mark.timeout(CLAIMS_TIMEOUT_S)
@pytest.mark.docs_check
def test_claims_equal_what_claims_py_computes_from_the_committed_runs(claim_results) -> None:
    claims_report = load_module("studies.claims.claims_report")
    groups, results = claim_results
    expected = claims_report.report(results, groups, "python -m studies.claims")
    assert (RESULTS / claims_report.OUTPUT).read_text() == expected, (
        "docs/results/claims.md is not what the committed runs give: run `make figures`")


@pytest.mark.slow
@pytest.mark.timeout(CLAIMS_TIMEOUT_S)
@pytest.mark.docs_check
def test_the_readmes_results_tables_are_what_the_claims_give(claim_results) -> None:
    """README.md's Results tables are claims.py's numbers for its claims (the same results as
    claims.md, which `python -m studies.claims` writes them from), between readme_table's
    markers: `make figures` rewrites them."""
    readme_table = load_module("studies.claims.readme_table")
    _, results = claim_results  # every claim's, as the command gives them to readme_table
    readme = (REPO / "README.md").read_text()
    assert readme_table.block(results) in readme, (
        "README.md's Results tables are not what the committed runs give: run `make figures`")
    assert readme_table.replace_block(readme, results) == readme
    # each claim's P with its interval, the tables' rows among them, is claims.md's
    claims_md = (RESULTS / "claims.md").read_text()
    for r in results:
        if r.improvement is not None:
            p = r.improvement[0]
            assert readme_table.interval(p) in claims_md
