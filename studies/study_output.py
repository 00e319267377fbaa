"""What every study shares: the checkout it runs from, the commit its results were computed
at, and how a report is written (a JSON summary beside its markdown). Kept apart from
bench/common.py so that studies and benchmarks do not import each other."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from hercs.apps import provenance
from hercs.apps.provenance import machine_identity

__all__ = ["REPO", "git_commit", "machine_identity", "write_report"]

REPO = Path(__file__).resolve().parents[1]


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
