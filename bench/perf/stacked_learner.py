"""K seeds' DDPG updates stacked in one learner against K lone learners, side by side.

    python -m bench.perf.stacked_learner          # ~3 min: FetchPush, B = 256, one thread

CPU ms per seed-update of K lone `DDPGLearner`s updated one after another (today's grid, with
its processes' overheads left out) against one `StackedDDPG` of K slots (hercs/learner/
stacked.py), in fp32 and in bf16 autocast, for K = 1, 2, 4, in alternating rounds so that
every arm sees the same background load; and the memory (PSS) of a fresh process holding 1 or
4 cells (hercs.learner.stacked_cells), each in a child of its own. Writes docs/results/
stacked_learner.{json,md} (or --out); issue 56's update-alone target is ≤ 3.5 ms per
seed-update for stacked bf16 at K = 4.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any

import numpy as np
import torch

from bench.common import add_out_option, git_commit, show_report
from bench.perf.learner import bf16_note, cpu_features, cpu_flags, cpu_seconds, make_batch
from hercs.config import DDPGConfig
from hercs.learner.ddpg import DDPGLearner
from hercs.learner.stacked import StackedDDPG, stacked_inputs
from hercs.rl.task_registry import task_spec

ARMS = ("lone fp32", "stacked fp32", "stacked bf16")
MEMORY_KS = (1, 4)
"""The cells a child process holds for the memory figure: a lone learner's, and a stack of 4."""


def arms_for(k: int, spec: Any, config: DDPGConfig, batch_size: int
             ) -> dict[str, Callable[[], object]]:
    """One call of each arm: K seed-updates (each seed on its own minibatch)."""
    rng = np.random.default_rng(k)
    learners = [DDPGLearner(spec=spec, config=config, seed=s) for s in range(k)]
    batches = [make_batch(spec, batch_size, rng) for _ in range(k)]
    inputs = stacked_inputs(learners, batches)
    stacks = {p: StackedDDPG(spec=spec, config=config, learners=learners, precision=p)
              for p in ("fp32", "bf16")}

    def lone() -> None:
        for learner, batch in zip(learners, batches, strict=True):
            learner.train(batch)

    return {"lone fp32": lone,
            "stacked fp32": lambda: stacks["fp32"].train(*inputs),
            "stacked bf16": lambda: stacks["bf16"].train(*inputs)}


def measure(ks: tuple[int, ...], *, batch_size: int, updates: int, rounds: int
            ) -> dict[int, dict[str, float]]:
    """Median over `rounds` of CPU ms per seed-update, per K and arm."""
    spec, config = task_spec("push"), DDPGConfig()
    calls = {k: arms_for(k, spec, config, batch_size) for k in ks}
    times: dict[int, dict[str, list[float]]] = {k: {a: [] for a in ARMS} for k in ks}
    for _ in range(rounds):
        for k in ks:
            for arm in ARMS:
                times[k][arm].append(1e3 * cpu_seconds(calls[k][arm], updates) / k)
    return {k: {arm: float(np.median(t)) for arm, t in by_arm.items()}
            for k, by_arm in times.items()}


def pss_mib() -> float:
    """This process's proportional set size (its share of shared pages, so that processes'
    figures add up), MiB."""
    with open("/proc/self/smaps_rollup") as f:
        for line in f:
            if line.startswith("Pss:"):
                return int(line.split()[1]) / 1024
    raise RuntimeError("/proc/self/smaps_rollup has no Pss line")


def memory_child(k: int, batch_size: int) -> dict[str, float]:
    """In this (fresh) process: PSS after torch and the learner's imports, then after K
    FetchPush cells (learner and loop) stacked and trained 3 cycles of 2 minibatches."""
    from hercs.learner.loop import LearnerLoop
    from hercs.learner.stacked_cells import StackedCells
    from hercs.wire.served import ReplayCounters, ServedBatch

    imported = pss_mib()
    spec, config = task_spec("push"), DDPGConfig()
    cells = StackedCells()
    rng = np.random.default_rng(0)
    for seed in range(k):
        learner = DDPGLearner(spec=spec, config=config, seed=seed)
        cells.join(f"cell{seed}", LearnerLoop(
            learner=learner, epochs=1, cycles_per_epoch=10, clusters=3,
            replay_status=lambda n: ReplayCounters(samples=n)))
    o_stats, g_stats = cells.loops["cell0"].learner.normalizer_state()
    for _ in range(3):
        cells.step({name: ServedBatch(
            minibatches=[make_batch(spec, batch_size, rng) for _ in range(2)],
            o_stats=o_stats, g_stats=g_stats, cluster_draws=np.zeros(3, np.int64))
            for name in cells.names})
    return {"imported_mib": imported, "cells_mib": pss_mib()}


def measure_memory(batch_size: int) -> dict[str, dict[str, float]]:
    """`memory_child` for each of MEMORY_KS, each in a process of its own."""
    out = {}
    for k in MEMORY_KS:
        done = subprocess.run([sys.executable, "-m", "bench.perf.stacked_learner",
                               "--memory-child", str(k), "--batch-size", str(batch_size)],
                              capture_output=True, text=True, timeout=600, check=False)
        if done.returncode != 0:
            raise RuntimeError(f"the memory child of K = {k} failed:\n{done.stderr[-3000:]}")
        out[str(k)] = json.loads(done.stdout.strip().splitlines()[-1])
    return out


def render(summary: dict[str, Any]) -> str:
    lines = ["# Stacked learner against lone learners (`python -m bench.perf.stacked_learner`)",
             "", f"{summary['date']}, commit `{summary['commit']}`, {summary['cpu']}; FetchPush, "
             f"B = {summary['batch_size']}, 3 × 256, one torch thread, median of "
             f"{summary['rounds']} alternating rounds of {summary['updates']} calls"
             f"{', quick mode' if summary['quick'] else ''}.", "",
             "CPU ms per seed-update (lower is better), and the speed-up over K lone fp32 "
             "learners measured in the same rounds:", "",
             "| K | lone fp32 | stacked fp32 | stacked bf16 | stacked fp32 speed-up | "
             "stacked bf16 speed-up |", "|---:|---:|---:|---:|---:|---:|"]
    for k, row in summary["ms_per_seed_update"].items():
        lone = row["lone fp32"]
        lines.append(f"| {k} | {lone:.2f} | {row['stacked fp32']:.2f} | "
                     f"{row['stacked bf16']:.2f} | {lone / row['stacked fp32']:.2f}× | "
                     f"{lone / row['stacked bf16']:.2f}× |")
    memory = summary["memory_pss_mib"]
    one, four = memory["1"], memory["4"]
    per_slot = (four["cells_mib"] - one["cells_mib"]) / 3
    lines += ["", "Memory (PSS, MiB) of a fresh process holding K cells' learners, stacked and "
              "trained 3 cycles:", "", "| K | after imports | with the cells |",
              "|---:|---:|---:|"]
    lines += [f"| {k} | {m['imported_mib']:.0f} | {m['cells_mib']:.0f} |"
              for k, m in memory.items()]
    lines += ["", f"Each cell beyond the first adds {per_slot:.1f} MiB to the process, where a "
              f"learner process of its own costs {one['cells_mib']:.0f} MiB: a stack of 4 "
              f"saves {3 * one['cells_mib'] - 3 * per_slot:.0f} MiB and 3 processes."]
    lines += ["", f"bf16 on this CPU: {summary['bf16_note']}", "",
              "A stacked fp32 slot is the same experiment as a lone learner "
              "(tests/unit/learner/test_stacked.py: weights, targets, Adam moments and losses "
              "agree within float tolerance); bf16's learning is a parity study's to measure, "
              "not this benchmark's.", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--batch-size", type=int, default=256)
    parser.add_argument("--updates", type=int, default=20, help="timed calls per round")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--quick", action="store_true", help="CI: K = 1, 2; 2 calls, 1 round")
    parser.add_argument("--memory-child", type=int, metavar="K", help=argparse.SUPPRESS)
    add_out_option(parser, "stacked_learner")
    args = parser.parse_args(argv)
    if args.memory_child is not None:
        torch.set_num_threads(1)
        print(json.dumps(memory_child(args.memory_child, args.batch_size)))
        return 0
    if args.batch_size < 1 or args.updates < 1 or args.rounds < 1:
        parser.error("--batch-size, --updates and --rounds must be >= 1")
    torch.set_num_threads(1)
    ks = (1, 2) if args.quick else (1, 2, 4)
    updates, rounds = (2, 1) if args.quick else (args.updates, args.rounds)
    results = measure(ks, batch_size=args.batch_size, updates=updates, rounds=rounds)
    summary = {"date": datetime.now(UTC).strftime("%Y-%m-%d"), "commit": git_commit(),
               "cpu": cpu_features(), "cores": os.cpu_count(),
               "bf16_note": bf16_note(cpu_flags()), "batch_size": args.batch_size,
               "updates": updates, "rounds": rounds, "quick": args.quick,
               "ms_per_seed_update": {str(k): row for k, row in results.items()},
               "memory_pss_mib": measure_memory(args.batch_size)}
    show_report(args, "stacked_learner", summary, render(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
