"""studies/study_output.py: a report's hand-written findings are found under their heading (to
the next one) and kept by a regenerated report (studies/env_diff/early_policy.py's render),
and reports are written as JSON beside markdown."""

from __future__ import annotations

import json
from pathlib import Path

from studies.env_diff.early_policy import render
from studies.study_output import FINDINGS_HEADING, kept_findings, write_report

FINDINGS = "Written by hand.\n\n- **A finding.** With its numbers: 0.36 m against 0.18 m.\n"


def test_findings_are_the_text_under_their_heading_to_the_end(tmp_path: Path) -> None:
    report = tmp_path / "report.md"
    assert kept_findings(report) == ""  # no report yet
    report.write_text("# Title\n\n## 1. A table\n\n| a |\n|---|\n| 1 |\n")
    assert kept_findings(report) == ""  # a report without findings
    report.write_text(f"# Title\n\n| a |\n\n{FINDINGS_HEADING}\n\n{FINDINGS}\n")
    assert kept_findings(report) == FINDINGS


def test_a_section_above_the_tables_ends_at_the_next_heading(tmp_path: Path) -> None:
    report = tmp_path / "report.md"
    report.write_text(f"# Title\n\n## The reading\n\n{FINDINGS}\n## Push\n\n| a |\n")
    assert kept_findings(report, "## The reading") == FINDINGS
    assert kept_findings(report, "## Pick") == ""


def test_a_regenerated_early_policy_report_keeps_its_findings(tmp_path: Path) -> None:
    result = {"when": "2026-11-27 12:00 UTC", "commit": "abc1234", "committed": [],
              "episodes": {}, "open_loop": {"skipped": "--no-open-loop"}}
    report = tmp_path / "early_policy.md"
    report.write_text(render(FINDINGS, result))
    assert kept_findings(report) == FINDINGS
    again = render(kept_findings(report), result)
    assert again == report.read_text() and again.count(FINDINGS_HEADING) == 1
    assert FINDINGS_HEADING not in render("", result)  # nothing to keep: no empty section


def test_write_report_writes_the_summary_beside_the_text(tmp_path: Path) -> None:
    write_report(None, "nothing", {"a": 1}, "text")  # a quick run without --out
    assert not list(tmp_path.iterdir())
    write_report(tmp_path / "out", "name", {"a": 1}, "# text\n")
    assert json.loads((tmp_path / "out" / "name.json").read_text()) == {"a": 1}
    assert (tmp_path / "out" / "name.md").read_text() == "# text\n"
