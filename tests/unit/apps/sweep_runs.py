"""Run folders as `hercs sweep` leaves them, for the tests of its report and manifest."""

from __future__ import annotations

import json
from pathlib import Path

from hercs.apps.sweep import cells as sweep_cells
from hercs.run.rundir import RunDir


def finished_run(root: Path, cell, success: list[float]) -> None:
    """A run folder as run_grid leaves it: config.yaml, metrics.csv, bench_done.json."""
    run = root / cell.name
    run.mkdir(parents=True)
    RunDir(run).config.write_text(
        f"run: {{method: {cell.method}, seed: {cell.seed}}}\n"
        f"task: {{name: {cell.task}, env_version: {cell.env_version}}}\n")
    rows = [f"{e},{v}" for e, v in enumerate(success, start=1)]
    RunDir(run).metrics.write_text("\n".join(["epoch,success_rate", *rows]) + "\n")
    (run / sweep_cells.DONE_FILE).write_text(json.dumps(
        {"task": cell.task, "method": cell.method, "seed": cell.seed,
         "env_version": cell.env_version, "env_id": cell.env_id, "epochs": len(success),
         "wall_s": 60.0, "commit": "abc"}))
