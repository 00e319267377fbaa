"""`python -m studies.claims`: the committed runs and the authors' per-seed curves
(docs/reference/authors_success_rates.csv) → docs/results/claims.md.

    python -m studies.claims [--runs docs/results/runs] [--out docs/results] [--reps N]
"""
from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from studies.claims.claim_runs import load_groups
from studies.claims.claim_statistics import (
    REPS,
)
from studies.claims.claims import CLAIMS, evaluate
from studies.claims.claims_report import OUTPUT, report
from studies.study_output import REPO, show_and_write


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=Path, default=REPO / "docs" / "results" / "runs")
    p.add_argument("--out", type=Path, default=REPO / "docs" / "results")
    p.add_argument("--reps", type=int, default=REPS,
                   help=f"bootstrap replications (default {REPS:,})")
    args = p.parse_args(argv)
    if not args.runs.is_dir():
        p.error(f"--runs {args.runs}: not a directory")
    if args.reps < 100:
        p.error(f"--reps must be at least 100, got {args.reps}")
    groups = load_groups(args.runs)
    command = " ".join(["python -m studies.claims", *(sys.argv[1:] if argv is None else argv)])
    text = report(evaluate(CLAIMS, groups, reps=args.reps), groups, command, reps=args.reps)
    show_and_write(args.out / OUTPUT, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
