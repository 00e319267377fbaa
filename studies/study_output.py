"""What every study shares: the checkout it runs from, the commit its results were computed
at, and how a report is written (a JSON summary beside its markdown). Kept apart from
bench/common.py so that studies and benchmarks do not import each other."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from hercs.apps import provenance
from hercs.apps.provenance import machine_identity

__all__ = ["FINDINGS_HEADING", "REPO", "git_commit", "kept_findings", "machine_identity",
           "write_report"]

REPO = Path(__file__).resolve().parents[1]
FINDINGS_HEADING = "## What it shows"
"""The heading of a report's findings: words written by hand from its tables, which a
regenerated report keeps (`kept_findings`) instead of a study holding them in its code."""


def git_commit() -> str:
    """This checkout's short commit (hercs.apps.provenance.git_commit)."""
    return provenance.git_commit(REPO)


def write_report(out: Path | None, name: str, summary: Any, text: str) -> None:
    """`<out>/<name>.json` (the summary) and `<out>/<name>.md` (the rendered text), the folder
    made if need be; nothing where `out` is None (a quick run without --out)."""
    if out is None:
        return
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps(summary, indent=2) + "\n")
    (out / f"{name}.md").write_text(text)
    print(f"wrote {out / (name + '.md')}")


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
