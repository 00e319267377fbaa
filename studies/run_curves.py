"""The curves of every run in a folder, as the studies read a grid's run-dir (hercs plot
reads the run folders it is given, one by one: `hercs.apps.plots.curves.load_run`)."""

from __future__ import annotations

from pathlib import Path

from hercs.apps.plots.curves import Curve, PlotError, VariantOf, load_run


def load_runs(folder: str | Path, variant_of: VariantOf | None = None) -> list[Curve]:
    """Every run directly under `folder`, by name (`load_run`); folders that are not runs, or
    have no metrics yet, are passed over (a grid's run-dir holds logs and unfinished runs)."""
    curves = []
    for run_dir in sorted(p for p in Path(folder).iterdir() if p.is_dir()):
        try:
            curves.append(load_run(run_dir, variant_of))
        except PlotError:
            continue
    return curves
