"""Wall time of whole runs, the old default against today's, side by side with the machine's limit.

    python -m bench.perf.run_time                       # FetchPush HER-CS, 3 seeds × 10 epochs
    python -m bench.perf.run_time --quick               # CI: FetchReach, 2 epochs of 5 cycles

Writes docs/results/run_time.{json,md} (or --out). Method and results: docs/PERFORMANCE.md §3."""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bench import common
from bench.perf.actor_envs import raw_slice
from bench.perf.learner import gemm_rate, make_batch, update_flops
from hercs.config import DDPGConfig, HercsConfig, apply_overrides
from hercs.learner.ddpg import DDPGLearner
from hercs.rl.envs import make_env
from hercs.rl.task_registry import task_spec
from hercs.run.metrics import read_rows
from hercs.run.rundir import RunDir

VARIANTS = (("old default", ("learner.parallel_halves=false", "task.indexed_reads=false")),
            ("default", ()))
"""The settings timed side by side: the defaults before this project's levers (a one-thread
learner, env observations read by name) and today's."""


def limit_s_per_epoch(task: str, config: HercsConfig, quick: bool) -> dict[str, float]:
    """The epoch's work at this machine's limits: GEMM-rate updates plus raw env steps, over
    the cores."""
    torch.set_num_threads(1)
    spec = task_spec(task)
    learner = DDPGLearner(spec=spec, config=DDPGConfig(), seed=0)
    flops = update_flops(learner, make_batch(spec, 256, np.random.default_rng(0)))
    rate = gemm_rate(256, 256, torch.float32, repeats=50 if quick else 2000)
    episodes = 2 if quick else 40
    step_rates = {}
    # the limit's definition predates the indexed reads: gymnasium-robotics' own step (by
    # name), a limit a run with today's env may beat; the indexed step's limit beside it
    for indexed in (False, True):
        env = make_env(spec, indexed=indexed)
        started = time.process_time()
        steps = raw_slice(spec, [env], np.random.default_rng(0), episodes)
        step_rates[indexed] = steps / (time.process_time() - started)
        env.close()
    training = config.training
    updates = training.cycles_per_epoch * training.minibatches_per_cycle
    env_steps = (training.episodes_per_epoch + training.eval_episodes) * spec.episode_steps
    cores = os.cpu_count() or 1
    limit, indexed_limit = ((updates * flops / rate + env_steps / step_rates[indexed]) / cores
                            for indexed in (False, True))
    return {"update_gflop": flops / 1e9, "gemm_gflops": rate / 1e9,
            "raw_steps_per_s": step_rates[False], "indexed_steps_per_s": step_rates[True],
            "updates_per_epoch": updates, "env_steps_per_epoch": env_steps, "cores": cores,
            "limit_s_per_epoch": limit, "indexed_limit_s_per_epoch": indexed_limit}


def timed_run(args: argparse.Namespace, seed: int, overrides: tuple[str, ...],
              work: Path) -> dict[str, float]:
    """One `hercs up` run: its process wall time and its steady seconds per epoch."""
    name = f"run-{len(list(work.iterdir()))}"
    wall = common.timed_cli("bench.perf.run_time", [
        "up", "--task", args.task, "--method", args.method, "--seed", str(seed), "--epochs",
        str(args.epochs), "--actors", "1", "--run", name, "--run-dir", str(work), "--listen",
        "tcp/127.0.0.1:0", *(item for kv in (*args.set, *overrides) for item in ("--set", kv))])
    rows = read_rows(RunDir(work / name).metrics)
    walls = [float(row["wall_s"]) for row in rows]
    steady = (walls[-1] - walls[0]) / (len(walls) - 1)
    start_up = wall - walls[-1]
    return {"wall_s": wall, "s_per_epoch": steady, "start_up_s": start_up,
            "projected_50_min": (start_up + walls[0] + 49 * steady) / 60.0,
            "final_success": float(rows[-1]["success_rate"])}


def usage_problem(args: argparse.Namespace) -> str | None:
    if args.epochs < 2 or args.seeds < 1:
        return (f"--epochs must be ≥ 2 (a steady state needs two epochs) and --seeds ≥ 1 "
                f"(got {args.epochs}, {args.seeds})")
    return None


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = common.script_parser("bench.perf.run_time", __doc__)
    parser.add_argument("--task", default="push")
    parser.add_argument("--method", default="her-cs")
    parser.add_argument("--epochs", type=int, default=10)
    parser.add_argument("--seeds", type=int, default=3)
    return common.parse_run_args(parser, argv, "run_time", usage_problem,
                                 task="reach", epochs=2, seeds=1)


def render(summary: dict[str, Any]) -> str:
    limit = summary["limit"]
    names = [name for name, _ in VARIANTS]
    lines = [
        *common.report_head(
            "bench.perf.run_time", "Run time side by side", summary,
            f"`hercs up --task {summary['task']} --method {summary['method']} --epochs "
            f"{summary['epochs']}`"),
        f"Limit: {limit['updates_per_epoch']} updates of {limit['update_gflop']:.3f} GFLOP at "
        f"{limit['gemm_gflops']:.1f} GFLOP/s plus {limit['env_steps_per_epoch']} env steps at "
        f"{limit['raw_steps_per_s']:.0f} raw steps/s, over {limit['cores']} cores: "
        f"**{limit['limit_s_per_epoch']:.1f} s per epoch** "
        f"({limit['limit_s_per_epoch'] * 50 / 60:.1f} min for 50 epochs). With the indexed "
        f"reads' {limit['indexed_steps_per_s']:.0f} steps/s: "
        f"{limit['indexed_limit_s_per_epoch']:.1f} s per epoch.", "",
        "| seed | setting | s per epoch | start-up s | 50 epochs (min) | limit ÷ s per epoch "
        "| success, last epoch |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for row in summary["runs"]:
        lines.append(f"| {row['seed']} | {row['setting']} | {row['s_per_epoch']:.1f} | "
                     f"{row['start_up_s']:.1f} | {row['projected_50_min']:.1f} | "
                     f"{limit['limit_s_per_epoch'] / row['s_per_epoch']:.2f} | "
                     f"{row['final_success']:.2f} |")
    ratios = summary["ratios"]
    lines += ["", f"{names[0]} ÷ {names[1]}, seconds per epoch, per seed: "
              + ", ".join(f"{r:.2f}" for r in ratios)
              + f"; geometric mean **{summary['ratio_geomean']:.2f}×**."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    config = apply_overrides(HercsConfig(), args.set)
    limit = limit_s_per_epoch(args.task, config, args.quick)
    runs: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="hercs-run-time-") as tmp:
        for seed in range(1, args.seeds + 1):
            order = VARIANTS if seed % 2 else VARIANTS[::-1]
            for setting, overrides in order:
                result = timed_run(args, seed, overrides, Path(tmp))
                runs.append({"seed": seed, "setting": setting, **result})
                print(f"seed {seed}, {setting}: {result['s_per_epoch']:.1f} s per epoch",
                      flush=True)
    by = {(r["seed"], r["setting"]): r["s_per_epoch"] for r in runs}
    old, new = (name for name, _ in VARIANTS)
    ratios = [by[(s, old)] / by[(s, new)] for s in range(1, args.seeds + 1)]
    summary = {"date": datetime.now(UTC).strftime("%Y-%m-%d"), "commit": common.git_commit(),
               "machine": common.machine_identity(), "cores": limit["cores"], "task": args.task,
               "method": args.method,
               "epochs": args.epochs, "quick": args.quick, "limit": limit, "runs": runs,
               "ratios": ratios, "ratio_geomean": float(np.exp(np.mean(np.log(ratios))))}
    common.show_report(args, "run_time", summary, render(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
