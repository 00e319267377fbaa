"""`python -m studies.fig2`: docs/results/fig2.{png,md} from the committed runs, drawn by
hercs.apps.plot_figures.run_plot (the layout and the tables' rule are the product's) with the
legacy variant of studies/legacy_runs.py kept apart, as every committed figure does."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from hercs.apps.plot_figures import run_plot
from hercs.apps.plots import BANDS, DEFAULT_BAND
from studies.legacy_runs import LEGACY_STYLE
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
    runs = sorted(str(p) for p in args.runs.iterdir() if p.is_dir())
    return run_plot(runs, str(args.output), table=str(args.table), figure=2, band=args.band,
                    style=LEGACY_STYLE)
