"""claims.md against the committed runs (`make studies-check`): every committed run is either
in a claim or listed with the reason it is not."""

from __future__ import annotations

from pathlib import Path

import pytest

from hercs.run.rundir import RunDir
from tests.support import load_module

claim_runs = load_module("studies.claims.claim_runs")
claims = load_module("studies.claims.claims")
claims_report = load_module("studies.claims.claims_report")


@pytest.mark.docs_check
def test_docs_check_every_committed_run_a_claim_leaves_out_is_listed_with_the_reason() -> None:
    """The audit's finding: chaos and fault-free runs were left out silently by the
    "longest run per seed" rule. The committed runs are grouped as claims.md groups them:
    with hercs.config's own default (test_claims.py fixes its own)."""
    runs_dir = Path(__file__).resolve().parents[3] / "docs" / "results" / "runs"
    groups = claim_runs.load_groups(runs_dir)
    results = claims.evaluate(claims.CLAIMS, groups, reps=10)
    text = claims_report.report(results, groups, "test", reps=10)
    used = {s.run for r in results for side in (r.x, r.y) for s in side.scores}
    used |= {name for r in results for side in (r.x, r.y) for name in side.short}
    committed = {p.name for p in runs_dir.iterdir() if RunDir(p).metrics.is_file()}
    listed = {line.split(" | ")[0].removeprefix("| ") for line in text.splitlines()
              if " | its group is in no claim" in line or " | a longer run of its" in line}
    assert committed - used == listed
    assert "| nofault-push-her-ebp-cs-s1 | a longer run of its group and seed is counted: " \
           "push-her-ebp-cs-s1 |" in text
    # a run dropped for a longer one whose group is in no claim says that, not "is counted"
    assert "| chaos2-reach-her-cs-s1 | its group is in no claim (FetchReach, " in text
    assert "counted: chaos1-reach-her-cs-s1" not in text
