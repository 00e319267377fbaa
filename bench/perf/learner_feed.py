"""How many actors one learner feeds at the paper's 10 updates per episode.

    python -m bench.perf.learner_feed --device cuda            # on a GPU machine: 1–12 actors

One `hercs up --actors N` run per N; the learner is fed from the smallest N whose updates per
second reach 0.95 of the best N's. Writes docs/results/learner_feed.{json,md}; PERFORMANCE §10."""

from __future__ import annotations

import argparse
import os
import tempfile
from datetime import UTC, datetime
from pathlib import Path
from statistics import median
from typing import Any

from bench import common
from hercs.run.metrics import read_rows
from hercs.run.rundir import RunDir

FED_SHARE = 0.95
"""A learner is fed at N actors when its updates per second reach this share of the best."""


def one_run(args: argparse.Namespace, actors: int, work: Path) -> dict[str, Any]:
    name = f"actors-{actors}"
    wall = common.timed_cli("bench.perf.learner_feed", [
        "up", "--task", args.task, "--method", "her", "--seed", "1", "--epochs",
        str(args.epochs), "--actors", str(actors), "--run", name, "--run-dir", str(work),
        "--listen", "tcp/127.0.0.1:0", "--set", f"learner.device={args.device}",
        *(item for kv in args.set for item in ("--set", kv))])
    rows = read_rows(RunDir(work / name).metrics)
    steady = rows[1:] or rows
    return {"actors": actors, "wall_s": wall,
            "updates_per_s": median(float(r["updates_per_s"]) for r in steady),
            "env_steps_per_s": median(float(r["env_steps_per_s"]) for r in steady),
            "batch_wait_s": median(float(r.get("batch_wait_s") or 0.0) for r in steady)}


def fed_at(runs: list[dict[str, Any]]) -> int:
    """The smallest actor count whose updates per second reach FED_SHARE of the best."""
    best = max(r["updates_per_s"] for r in runs)
    return min(r["actors"] for r in runs if r["updates_per_s"] >= FED_SHARE * best)


def usage_problem(args: argparse.Namespace) -> str | None:
    if args.epochs < 2 or min(args.actors) < 1:
        return "--epochs must be ≥ 2 (the first is start-up) and every --actors ≥ 1"
    return None


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = common.script_parser("bench.perf.learner_feed", __doc__)
    parser.add_argument("--device", default="cuda", help="learner.device (default cuda)")
    parser.add_argument("--actors", type=int, nargs="+", default=[1, 2, 4, 6, 8, 12])
    parser.add_argument("--task", default="push")
    parser.add_argument("--epochs", type=int, default=3)
    return common.parse_run_args(parser, argv, "learner_feed", usage_problem,
                                 device="cpu", task="reach", actors=[1, 2], epochs=2)


def render(summary: dict[str, Any]) -> str:
    lines = [
        *common.report_head(
            "bench.perf.learner_feed", "Actors one learner feeds", summary,
            f"learner on `{summary['device']}`, `hercs up --task {summary['task']} --method "
            f"her --epochs {summary['epochs']} --actors N`"),
        "| actors | updates/s | env steps/s | learner's wait for batches, s per epoch |",
        "|---:|---:|---:|---:|",
    ]
    lines += [f"| {r['actors']} | {r['updates_per_s']:.0f} | {r['env_steps_per_s']:.0f} | "
              f"{r['batch_wait_s']:.1f} |" for r in summary["runs"]]
    lines += ["", f"Fed from **{summary['fed_at']} actor(s)** (updates/s ≥ {FED_SHARE:.0%} of "
              "the best)."]
    if not summary.get("complete", True):
        lines += ["", f"Partial: {len(summary['runs'])} of the actor counts "
                  f"{summary['planned']} were run."]
    return "\n".join(lines) + "\n"


def summarise(args: argparse.Namespace, runs: list[dict[str, Any]]) -> dict[str, Any]:
    return {"date": datetime.now(UTC).strftime("%Y-%m-%d"), "commit": common.git_commit(),
            "machine": common.machine_identity(), "cores": os.cpu_count(), "device": args.device,
            "task": args.task, "epochs": args.epochs, "quick": args.quick, "runs": runs,
            "fed_at": fed_at(runs), "complete": len(runs) == len(args.actors),
            "planned": args.actors}


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    runs: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="hercs-learner-feed-") as tmp:
        for i, n in enumerate(args.actors):
            runs.append(one_run(args, n, Path(tmp)))
            if args.out is not None and i < len(args.actors) - 1:
                # the counts so far, kept if a later run fails or a lent machine's time runs out
                # (only into a folder given: a partial run never replaces the published report)
                summary = summarise(args, runs)
                common.write_report(args.out, "learner_feed", summary, render(summary))
    summary = summarise(args, runs)
    common.show_report(args, "learner_feed", summary, render(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
