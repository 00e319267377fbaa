"""Epochs per hour of a grid, runs one at a time against runs side by side.

    python -m bench.perf.grid_throughput                  # FetchPush, her and her-cs, 6 epochs
    python -m bench.perf.grid_throughput --seeds 2 --epochs 10 --jobs 2 --stacked
                                        # issue 56's arms: 4 runs, --jobs 2 against one
                                        # stacked learner (fp32, bf16) for all 4 at once

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


STACKED_PRECISIONS = ("fp32", "bf16")


def timed_grid(args: argparse.Namespace, jobs: int, work: Path,
               stacked: str | None = None) -> float:
    """Wall seconds of one grid (METHODS × `--seeds`) with `--jobs jobs`; `stacked`: with one
    learner process in that precision (`hercs sweep --stacked --precision P`)."""
    run_dir = work / f"grid-{len(list(work.iterdir()))}"
    extra = ["--stacked", "--precision", stacked] if stacked else []
    return common.timed_cli("bench.perf.grid_throughput", [
        "sweep", "--tasks", args.task, "--methods", *METHODS, "--seeds", str(args.seeds),
        "--epochs", str(args.epochs), "--jobs", str(jobs), "--run-dir", str(run_dir), *extra,
        *(item for kv in args.set for item in ("--set", kv))])


def arms(args: argparse.Namespace) -> list[tuple[str, int, str | None]]:
    """(label, --jobs, stacked precision) of each grid timed: each --jobs value, and with
    --stacked one stacked learner in each precision for all the grid's runs at once."""
    out: list[tuple[str, int, str | None]] = [(str(j), j, None) for j in args.jobs]
    if args.stacked:
        runs = len(METHODS) * args.seeds
        out += [(f"stacked {p}", runs, p) for p in STACKED_PRECISIONS]
    return out


def usage_problem(args: argparse.Namespace) -> str | None:
    if args.epochs < 1 or args.rounds < 1 or args.seeds < 1 or min(args.jobs) < 1:
        return "--epochs, --rounds, --seeds and every --jobs value must be ≥ 1"
    return None


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = common.script_parser("bench.perf.grid_throughput", __doc__)
    parser.add_argument("--task", default="push")
    parser.add_argument("--epochs", type=int, default=6)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--seeds", type=int, default=1, help="seeds of each method (runs: "
                        f"{len(METHODS)} × this)")
    parser.add_argument("--stacked", action="store_true",
                        help="also time the grid with one stacked learner for all its runs, "
                             "in fp32 and in bf16 (`hercs sweep --stacked`)")
    return common.parse_run_args(parser, argv, "grid_throughput", usage_problem,
                                 task="reach", epochs=2, rounds=1)


def render(summary: dict[str, Any]) -> str:
    lines = [
        *common.report_head(
            "bench.perf.grid_throughput", "Grid throughput by `--jobs`", summary,
            f"each grid: `hercs sweep --tasks {summary['task']} --methods "
            f"{' '.join(METHODS)} --seeds {summary.get('seeds', 1)} --epochs "
            f"{summary['epochs']}`; a stacked arm adds `--stacked --precision P --jobs "
            "<all its runs>`"),
        "| --jobs | grid wall s, per round | epochs per hour (mean) | against --jobs "
        f"{summary['jobs'][0]} |",
        "|---|---|---:|---:|",
    ]
    base = summary["epochs_per_hour"][str(summary["jobs"][0])]
    for label, rate in summary["epochs_per_hour"].items():
        walls = ", ".join(f"{w:.0f}" for w in summary["walls"][label])
        lines.append(f"| {label} | {walls} | {rate:.0f} | {rate / base:.2f}× |")
    lines += ["", f"Best: `--jobs {summary['best_jobs']}`" + (
        f"; best of all: {summary['best_arm']}." if "best_arm" in summary else ".")]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    timed = arms(args)
    walls: dict[str, list[float]] = {label: [] for label, _, _ in timed}
    with tempfile.TemporaryDirectory(prefix="hercs-grid-throughput-") as tmp:
        for round_ in range(args.rounds):
            order = timed if round_ % 2 == 0 else timed[::-1]
            for label, jobs, stacked in order:
                wall = timed_grid(args, jobs, Path(tmp), stacked)
                walls[label].append(wall)
                print(f"round {round_ + 1}, --jobs {label}: {wall:.0f} s", flush=True)
    epochs = len(METHODS) * args.seeds * args.epochs
    per_hour = {j: float(np.mean([3600.0 * epochs / w for w in ws])) for j, ws in walls.items()}
    lone = {str(j): per_hour[str(j)] for j in args.jobs}
    summary = {"date": datetime.now(UTC).strftime("%Y-%m-%d"), "commit": common.git_commit(),
               "machine": common.machine_identity(), "cores": os.cpu_count(), "task": args.task,
               "epochs": args.epochs, "seeds": args.seeds, "jobs": args.jobs,
               "stacked": args.stacked, "quick": args.quick, "walls": walls,
               "epochs_per_hour": per_hour,
               "best_jobs": int(max(lone, key=lambda j: lone[j])),
               **({"best_arm": max(per_hour, key=lambda j: per_hour[j])} if args.stacked
                  else {})}
    common.show_report(args, "grid_throughput", summary, render(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
