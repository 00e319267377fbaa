"""How a benchmark (bench/) or a study (studies/) writes its result: a JSON summary beside its
rendered markdown, in docs/results unless `--out` says where, and nowhere for a quick run.
A package of its own below both (bench and studies do not import each other; the product,
hercs, has no use for it)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def add_out_option(parser: argparse.ArgumentParser, name: str) -> None:
    """The `--out` folder of a script writing `<name>.json` and `<name>.md` (report_folder)."""
    parser.add_argument("--out", type=Path, help=f"where {name}.{{json,md}} go (default "
                        "docs/results; not written with --quick unless given)")


def report_folder(out: Path | None, quick: bool, repo: Path) -> Path | None:
    """`--out` where given; else the checkout's docs/results, or None for a quick run (a CI
    smoke run that writes nothing over the published results)."""
    return out or (None if quick else repo / "docs" / "results")


def write_report(out: Path | None, name: str, summary: Any, text: str) -> None:
    """`<out>/<name>.json` (the summary) and `<out>/<name>.md` (the rendered text), the folder
    made if need be; nothing where `out` is None (a quick run without --out)."""
    if out is None:
        return
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps(summary, indent=2) + "\n")
    (out / f"{name}.md").write_text(text)
    print(f"wrote {out / (name + '.md')}")
