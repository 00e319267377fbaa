"""Epochs per hour of a grid, runs one at a time against runs side by side.

    python -m bench.perf.grid_throughput                  # FetchPush, her and her-cs, 6 epochs

Writes docs/results/grid_throughput.{json,md} (or --out); method and results:
docs/PERFORMANCE.md §3, "The grid's jobs"."""

from __future__ import annotations

import argparse
import os
import tempfile
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from bench import common

METHODS = ("her", "her-cs")


def timed_grid(args: argparse.Namespace, jobs: int, work: Path) -> float:
    """Wall seconds of one two-run grid with `--jobs jobs`."""
    run_dir = work / f"grid-{len(list(work.iterdir()))}"
    return common.timed_cli("bench.perf.grid_throughput", [
        "sweep", "--tasks", args.task, "--methods", *METHODS, "--seeds", "1", "--epochs",
        str(args.epochs), "--jobs", str(jobs), "--run-dir", str(run_dir),
        *(item for kv in args.set for item in ("--set", kv))])


def usage_problem(args: argparse.Namespace) -> str | None:
    if args.epochs < 1 or args.rounds < 1 or min(args.jobs) < 1:
        return "--epochs, --rounds and every --jobs value must be ≥ 1"
    return None


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = common.script_parser("bench.perf.grid_throughput", __doc__)
    parser.add_argument("--task", default="push")
    parser.add_argument("--epochs", type=int, default=6)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    return common.parse_run_args(parser, argv, "grid_throughput", usage_problem,
                                 task="reach", epochs=2, rounds=1)


def render(summary: dict[str, Any]) -> str:
    lines = [
        *common.report_head(
            "bench.perf.grid_throughput", "Grid throughput by `--jobs`", summary,
            f"each grid: `hercs sweep --tasks {summary['task']} --methods "
            f"{' '.join(METHODS)} --seeds 1 --epochs {summary['epochs']}`"),
        "| --jobs | grid wall s, per round | epochs per hour (mean) | against --jobs "
        f"{summary['jobs'][0]} |",
        "|---:|---|---:|---:|",
    ]
    base = summary["epochs_per_hour"][str(summary["jobs"][0])]
    for jobs in summary["jobs"]:
        rate = summary["epochs_per_hour"][str(jobs)]
        walls = ", ".join(f"{w:.0f}" for w in summary["walls"][str(jobs)])
        lines.append(f"| {jobs} | {walls} | {rate:.0f} | {rate / base:.2f}× |")
    lines += ["", f"Best: `--jobs {summary['best_jobs']}`."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    walls: dict[str, list[float]] = {str(j): [] for j in args.jobs}
    with tempfile.TemporaryDirectory(prefix="hercs-grid-throughput-") as tmp:
        for round_ in range(args.rounds):
            order = args.jobs if round_ % 2 == 0 else args.jobs[::-1]
            for jobs in order:
                wall = timed_grid(args, jobs, Path(tmp))
                walls[str(jobs)].append(wall)
                print(f"round {round_ + 1}, --jobs {jobs}: {wall:.0f} s", flush=True)
    epochs = len(METHODS) * args.epochs
    per_hour = {j: float(np.mean([3600.0 * epochs / w for w in ws])) for j, ws in walls.items()}
    summary = {"date": datetime.now(UTC).strftime("%Y-%m-%d"), "commit": common.git_commit(),
               "machine": common.machine_identity(), "cores": os.cpu_count(), "task": args.task,
               "epochs": args.epochs, "jobs": args.jobs, "quick": args.quick, "walls": walls,
               "epochs_per_hour": per_hour,
               "best_jobs": int(max(per_hour, key=lambda j: per_hour[j]))}
    common.show_report(args, "grid_throughput", summary, render(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
