"""What every study shares: the checkout it runs from, the commit its results were computed
at, and how a report is written (a JSON summary beside its markdown). Kept apart from
bench/common.py so that studies and benchmarks do not import each other."""

from __future__ import annotations

from pathlib import Path

from hercs.apps import provenance
from hercs.apps.provenance import machine_identity
from reports import add_out_option, report_folder, write_report

__all__ = ["FINDINGS_HEADING", "REPO", "add_out_option", "git_commit", "kept_findings",
           "machine_identity", "report_folder", "show_and_write", "write_report"]

REPO = Path(__file__).resolve().parents[1]
FINDINGS_HEADING = "## What it shows"
"""The heading of a report's findings: words written by hand from its tables, which a
regenerated report keeps (`kept_findings`) instead of a study holding them in its code."""


def git_commit() -> str:
    """This checkout's short commit (hercs.apps.provenance.git_commit)."""
    return provenance.git_commit(REPO)


def show_and_write(path: Path, text: str) -> None:
    """A markdown-only report (no JSON summary beside it): printed, and written to `path`, its
    folder made if need be."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    print(text, end="")
    print(f"wrote {path}")


def kept_findings(report: Path, heading: str = FINDINGS_HEADING) -> str:
    """The findings of a report already written (the text under `heading`, to the next `## `
    heading or the end), for the regenerated report to keep; "" where there is no such
    report or section."""
    if not report.is_file():
        return ""
    _, found, rest = report.read_text().partition(f"\n{heading}\n")
    if not found:
        return ""
    findings = rest.split("\n## ", 1)[0].strip("\n")
    return findings + "\n" if findings else ""
