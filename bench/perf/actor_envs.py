"""Env steps per CPU-second of the actor's rollout core against raw env stepping.

    python -m bench.perf.actor_envs            # ~4 min: FetchPush, 1/2/4/8/16 envs per process

Does `actor.envs_per_process` pay off? Target ≥ 0.95. Writes docs/results/actor_envs.{json,md}
(or --out); method and results: docs/PERFORMANCE.md §8."""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from collections.abc import Callable
from datetime import UTC, datetime

import numpy as np

from bench.common import REPO, add_out_option, git_commit, report_folder, write_report
from hercs.actors.rollout import VectorRollout
from hercs.config import DDPGConfig
from hercs.net.threads import single_threaded_numerics
from hercs.rl.envs import make_env
from hercs.rl.policy import Policy
from hercs.rl.task_registry import TaskSpec, task_spec
from hercs.wire.codec import episode_to_msg

TARGET = 0.95


def raw_slice(spec: TaskSpec, envs: list, rng: np.random.Generator, episodes: int) -> int:
    """Step `envs` with random actions for `episodes` rounds of T steps; returns env steps."""
    for _ in range(episodes):
        for env in envs:
            env.reset()
        for _ in range(spec.episode_steps):
            for env in envs:
                env.step(rng.uniform(-1.0, 1.0, spec.action_dim).astype(np.float32))
    return episodes * spec.episode_steps * len(envs)


def actor_slice(spec: TaskSpec, rollout: VectorRollout, act: Callable, episodes: int) -> int:
    for _ in range(episodes):
        for episode in rollout.run_episodes(act):
            episode_to_msg(episode, run="bench", task=spec.name).SerializeToString()
    return episodes * spec.episode_steps * rollout.num_envs


def measure(spec: TaskSpec, n: int, *, rounds: int, episodes: int) -> dict[str, float]:
    """Alternating raw and actor slices of `episodes` rounds each over `rounds` rounds."""
    rng = np.random.default_rng(0)
    policy = Policy(spec=spec, config=DDPGConfig(), seed=0)
    raw_envs = [make_env(spec) for _ in range(n)]
    for i, env in enumerate(raw_envs):
        env.reset(seed=100 + i)
    rollout = VectorRollout(spec=spec, envs=[make_env(spec) for _ in range(n)],
                            seeds=list(range(n)))

    def act(o: np.ndarray, g: np.ndarray) -> np.ndarray:
        return policy.act(o, g, explore=True, rng=rng)

    actor_slice(spec, rollout, act, 1)  # warm-up: first resets, torch's first calls
    raw_slice(spec, raw_envs, rng, 1)
    totals = {"raw_steps": 0.0, "raw_cpu_s": 0.0, "actor_steps": 0.0, "actor_cpu_s": 0.0}
    for _ in range(rounds):
        for side, run in (("raw", lambda: raw_slice(spec, raw_envs, rng, episodes)),
                          ("actor", lambda: actor_slice(spec, rollout, act, episodes))):
            start = time.process_time()
            steps = run()
            totals[f"{side}_cpu_s"] += time.process_time() - start
            totals[f"{side}_steps"] += steps
    rollout.close()
    for env in raw_envs:
        env.close()
    raw = totals["raw_steps"] / totals["raw_cpu_s"]
    ours = totals["actor_steps"] / totals["actor_cpu_s"]
    return {"envs": n, "raw_steps_per_cpu_s": raw, "actor_steps_per_cpu_s": ours,
            "ratio": ours / raw, **totals}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--task", default="push")
    parser.add_argument("--envs", type=int, nargs="+", default=[1, 2, 4, 8, 16])
    add_out_option(parser, "actor_envs")
    parser.add_argument("--quick", action="store_true", help="CI: 1 round of 1 episode")
    args = parser.parse_args(argv)
    if any(n < 1 for n in args.envs):
        parser.error("--envs: every count must be >= 1")
    single_threaded_numerics()  # as every service process does
    spec = task_spec(args.task)
    rows = []
    for n in args.envs:
        # about the same env steps per slice whatever n (8 episodes' worth), in many short
        # alternating slices: the load of a shared machine drifts within seconds
        episodes = 1 if args.quick else max(1, 8 // n)
        rows.append(measure(spec, n, rounds=1 if args.quick else 20, episodes=episodes))
        print(f"{n:3d} envs: actor {rows[-1]['actor_steps_per_cpu_s']:7.0f} steps/CPU-s, raw "
              f"{rows[-1]['raw_steps_per_cpu_s']:7.0f}, ratio {rows[-1]['ratio']:.3f}",
              flush=True)
    summary = {"task": args.task, "target_ratio": TARGET, "rows": rows, "commit": git_commit(),
               "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
               "machine": f"{platform.node()} ({os.cpu_count()} cores)", "quick": args.quick,
               "command": "python -m bench.perf.actor_envs " + " ".join(argv or sys.argv[1:])}
    lines = [
        "# Actor: env steps per CPU-second against raw env stepping",
        "",
        f"`{summary['command'].strip()}` — {summary['date']}, commit {summary['commit']}, "
        f"{summary['machine']}, one compute thread, Fetch{args.task.capitalize()}.",
        "",
        "Raw: the envs stepped with random actions and nothing else. Actor: `VectorRollout` "
        "with the exploring policy (one batched call per step) and each episode encoded for "
        f"the wire. Target: actor ≥ {TARGET} of raw.",
        "",
        "| envs per process | actor steps/CPU-s | raw steps/CPU-s | ratio | target |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        met = "met" if r["ratio"] >= TARGET else "not met"
        lines.append(f"| {r['envs']} | {r['actor_steps_per_cpu_s']:.0f} | "
                     f"{r['raw_steps_per_cpu_s']:.0f} | {r['ratio']:.3f} | ≥ {TARGET} ({met}) |")
    out = report_folder(args.out, args.quick, REPO)
    write_report(out, "actor_envs", summary, "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
