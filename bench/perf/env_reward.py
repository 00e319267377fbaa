"""What rewards computed by the environment cost against the built-in vectorised rules.

    python -m bench.perf.env_reward           # ~1 min

Per minibatch of B = 256 and 1,024, beside a whole `ReplayTable.draw` minibatch. Writes
docs/results/env_reward.{json,md} (or --out), which states the method."""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import sys
import time
from collections.abc import Callable
from datetime import UTC, datetime

import numpy as np

import hercs.rl.goal_env  # noqa: F401  (installs the env rule that reward_rule="env" specs use)
from bench.common import add_out_option, git_commit, show_report
from bench.synthetic_episodes import random_episode
from hercs.config import HercsConfig, apply_overrides
from hercs.replay_service.builder import ReplayBuilder
from hercs.rl.task_registry import TaskSpec, task_spec

TASKS = ("push", "HandReach-v3", "HandManipulateBlock-v1")


def seconds_per_call(fn: Callable[[], object], repeats: int) -> float:
    """Median of 5 rounds of `repeats` calls, per call (CPU time of this thread)."""
    fn()
    rounds = []
    for _ in range(5):
        start = time.thread_time()
        for _ in range(repeats):
            fn()
        rounds.append((time.thread_time() - start) / repeats)
    return float(np.median(rounds))


def goal_pairs(spec: TaskSpec, n: int, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    g = rng.normal(scale=0.1, size=(n, spec.goal_dim))
    ag = g + rng.normal(scale=spec.distance_threshold, size=g.shape)
    if spec.goal_dim == 7:
        for x in (g, ag):
            x[:, 3:] /= np.linalg.norm(x[:, 3:], axis=1, keepdims=True)
    return ag, g


def sample_seconds(name: str, batch: int, repeats: int) -> float:
    """One `ReplayTable.draw` of `batch` transitions from 200 stored random episodes."""
    config = apply_overrides(HercsConfig(), [f"task.name={name}", "run.method=her",
                                             f"ddpg.batch_size={batch}"])
    table = ReplayBuilder(config).table(rng=np.random.default_rng(0))
    rng = np.random.default_rng(0)
    for i in range(200):
        table.store_episode(random_episode(config.task.spec, rng, actor_id="bench", seq=i))
    return seconds_per_call(lambda: table.draw(1, batch), repeats)


def measure(quick: bool) -> dict[str, dict[str, float]]:
    repeats = 5 if quick else 200
    rng = np.random.default_rng(1)
    out: dict[str, dict[str, float]] = {}
    for name in TASKS:
        built_in = task_spec(name)
        by_env = dataclasses.replace(built_in, reward_rule="env")
        row: dict[str, float] = {}
        for batch in (256, 1024):
            ag, g = goal_pairs(built_in, batch, rng)
            if built_in.reward_rule != "env":
                np.testing.assert_array_equal(built_in.compute_reward(ag, g),
                                              by_env.compute_reward(ag, g))
            row[f"built_in_us_{batch}"] = 1e6 * seconds_per_call(
                lambda s=built_in, a=ag, b=g: s.compute_reward(a, b), repeats)
            row[f"env_us_{batch}"] = 1e6 * seconds_per_call(
                lambda s=by_env, a=ag, b=g: s.compute_reward(a, b), repeats)
            row[f"sample_us_{batch}"] = 1e6 * sample_seconds(name, batch,
                                                             max(3, repeats // 10))
        out[name] = row
    return out


def report(summary: dict) -> str:  # type: ignore[type-arg]
    lines = ["# Rewards computed by the environment against the built-in rules", "",
             f"`python -m bench.perf.env_reward{' --quick' if summary['quick'] else ''}` — "
             f"{summary['date']}, commit {summary['commit']}, {summary['machine']}. CPU time "
             "of one `compute_reward` over a minibatch of goal pairs (median of 5 rounds), "
             "beside one whole `ReplayTable.draw` of that minibatch (HER, relabelling "
             "included) with the built-in rule.", "",
             "| task | B | built-in (µs) | env's compute_reward (µs) | × built-in | "
             "whole sample (µs) | env's extra, share of a sample |",
             "|---|---|---|---|---|---|---|"]
    for name, row in summary["results"].items():
        for b in (256, 1024):
            built, env, sample = (row[f"{k}_us_{b}"] for k in ("built_in", "env", "sample"))
            lines.append(f"| {name} | {b} | {built:.0f} | {env:.0f} | {env / built:.1f} | "
                         f"{sample:.0f} | {(env - built) / sample:.0%} |")
    lines += ["", "The env rule keeps one environment instance per process (replay, "
              "clusterer), never stepped; its reward equals the built-in one on every pair "
              "(asserted here for the tasks whose batched env rule is right: not the pen, "
              "whose env mishandles batches, hercs.rl.task_registry.hand_success)."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_out_option(parser, "env_reward")
    parser.add_argument("--quick", action="store_true", help="CI: a few repeats")
    args = parser.parse_args(argv)
    summary = {"date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
               "commit": git_commit(), "quick": args.quick,
               "machine": f"{platform.node()} ({os.cpu_count()} cores)",
               "results": measure(args.quick)}
    text = report(summary)
    show_report(args, "env_reward", summary, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
