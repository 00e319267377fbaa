"""`python -m studies.claims`: the committed runs and the authors' per-seed curves
(docs/reference/authors_success_rates.csv) → docs/results/claims.md, and README.md's Results
tables (studies/claims/readme_table.py).

    python -m studies.claims [--runs docs/results/runs] [--out docs/results] [--reps N]
                             [--readme README.md]
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
from studies.claims.readme_table import replace_block
from studies.study_output import REPO, show_and_write


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=Path, default=REPO / "docs" / "results" / "runs")
    p.add_argument("--out", type=Path, default=REPO / "docs" / "results")
    p.add_argument("--reps", type=int, default=REPS,
                   help=f"bootstrap replications (default {REPS:,})")
    p.add_argument("--readme", type=Path, default=REPO / "README.md",
                   help="the README whose Results tables to rewrite (default README.md)")
    args = p.parse_args(argv)
    if not args.runs.is_dir():
        p.error(f"--runs {args.runs}: not a directory")
    if args.reps < 100:
        p.error(f"--reps must be at least 100, got {args.reps}")
    groups = load_groups(args.runs)
    command = " ".join(["python -m studies.claims", *(sys.argv[1:] if argv is None else argv)])
    results = evaluate(CLAIMS, groups, reps=args.reps)
    show_and_write(args.out / OUTPUT, report(results, groups, command, reps=args.reps))
    try:
        args.readme.write_text(replace_block(args.readme.read_text(), results))
    except (OSError, ValueError) as exc:
        print(f"python -m studies.claims: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
