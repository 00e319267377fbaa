"""An env step's CPU cost with the observation read by name and by ids resolved once, side by side.

    python -m bench.perf.env_step                 # Push and PickAndPlace v4, 6 rounds

Writes docs/results/env_step.{json,md} (or --out). Method and results: docs/PERFORMANCE.md §3,
"Env steps read by id"."""

from __future__ import annotations

import os
import time
from datetime import UTC, datetime
from statistics import median
from typing import Any

import numpy as np

from bench import common
from hercs.rl.envs import make_env
from hercs.rl.task_registry import task_spec

SETTINGS = ("by name", "indexed")


def _episodes(env: Any, spec: Any, seed: int, episodes: int) -> tuple[float, int, bytes]:
    """CPU seconds and steps of `episodes` episodes from reset(seed) with seeded random
    actions, and the last observation's bytes."""
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1.0, 1.0, (episodes, spec.episode_steps, spec.action_dim))
    started = time.thread_time()
    obs, _ = env.reset(seed=seed)
    for episode in range(episodes):
        if episode:
            obs, _ = env.reset()
        for action in actions[episode].astype(np.float32):
            obs = env.step(action)[0]
    spent = time.thread_time() - started
    return spent, episodes * spec.episode_steps, obs["observation"].tobytes()


def measure(task: str, rounds: int, episodes: int) -> dict[str, Any]:
    spec = task_spec(task)
    envs = {"by name": make_env(spec, indexed=False), "indexed": make_env(spec)}
    rates: dict[str, list[float]] = {name: [] for name in SETTINGS}
    identical = True
    try:
        _episodes(envs["by name"], spec, 0, 1)  # warm both before timing
        _episodes(envs["indexed"], spec, 0, 1)
        for round_ in range(rounds):
            order = SETTINGS if round_ % 2 == 0 else SETTINGS[::-1]
            last = {}
            for name in order:
                spent, steps, last[name] = _episodes(envs[name], spec, round_ + 1, episodes)
                rates[name].append(steps / spent)
            identical = identical and last["by name"] == last["indexed"]
    finally:
        for env in envs.values():
            env.close()
    ratios = [new / old for new, old in zip(rates["indexed"], rates["by name"], strict=True)]
    return {"env_id": spec.env_id, "steps_per_cpu_s": rates,
            "median_steps_per_cpu_s": {name: median(v) for name, v in rates.items()},
            "ratio_per_round": ratios, "median_ratio": median(ratios),
            "same_last_observation": identical}


def render(summary: dict[str, Any]) -> str:
    lines = [*common.report_head(
        "bench.perf.env_step", "An env step by name and indexed", summary,
        f"{summary['rounds']} rounds of {summary['episodes']} episodes a setting, the order "
        "alternating; env steps per CPU-second of the thread (median over rounds)"),
        "| env | by name | indexed | indexed ÷ by name (median; rounds' range) | "
        "same last observation |", "|---|---:|---:|---|---|"]
    for found in summary["tasks"].values():
        rate, ratios = found["median_steps_per_cpu_s"], found["ratio_per_round"]
        lines.append(f"| {found['env_id']} | {rate['by name']:.0f} | {rate['indexed']:.0f} | "
                     f"**{found['median_ratio']:.2f}×** ({min(ratios):.2f}–{max(ratios):.2f}) | "
                     f"{'yes' if found['same_last_observation'] else 'NO'} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = common.script_parser("bench.perf.env_step", __doc__)
    parser.add_argument("--tasks", nargs="+", default=["push", "pick"])
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--episodes", type=int, default=20,
                        help="episodes per setting and round")
    parser.add_argument("--quick", action="store_true", help="CI: Reach, 2 rounds of 2")
    common.add_out_option(parser, "env_step")
    args = parser.parse_args(argv)
    if args.quick:
        args.tasks, args.rounds, args.episodes = ["reach"], 2, 2
    if args.rounds < 1 or args.episodes < 1:
        parser.error("--rounds and --episodes must be at least 1")
    summary = {"date": datetime.now(UTC).strftime("%Y-%m-%d"), "commit": common.git_commit(),
               "machine": common.machine_identity(), "cores": os.cpu_count(),
               "rounds": args.rounds, "episodes": args.episodes, "quick": args.quick,
               "tasks": {task: measure(task, args.rounds, args.episodes) for task in args.tasks}}
    common.show_report(args, "env_step", summary, render(summary))
    return 0 if all(found["same_last_observation"] for found in summary["tasks"].values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
