"""`python -m studies.fig2`: docs/results/fig2.{png,md} from the committed runs, by running
`hercs plot --figure 2 docs/results/runs/*/ -o … --table …` itself: the figure, its labels
and its series are the product's, so what a user's command draws is what is committed."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from hercs.apps.cli.main import main as hercs
from hercs.apps.plots.curves import BANDS, DEFAULT_BAND
from studies.study_output import REPO

RESULTS = REPO / "docs" / "results"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m studies.fig2",
                                     description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--runs", type=Path, default=RESULTS / "runs",
                        help="a folder of run folders (default docs/results/runs)")
    parser.add_argument("-o", "--output", type=Path, default=RESULTS / "fig2.png")
    parser.add_argument("--table", type=Path, default=RESULTS / "fig2.md")
    parser.add_argument("--band", choices=BANDS, default=DEFAULT_BAND)
    args = parser.parse_args(argv)
    if not args.runs.is_dir():
        parser.error(f"--runs {args.runs}: not a directory")
    runs = sorted(str(p) for p in args.runs.iterdir() if p.is_dir())  # the shell's runs/*/
    return hercs(["plot", "--figure", "2", *runs, "-o", str(args.output),
                  "--table", str(args.table), "--band", args.band])
