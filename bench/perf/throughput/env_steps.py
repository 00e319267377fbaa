"""1. Env steps/s: one `hercs actor` against raw FetchPush stepping in this process,
in alternating slices (the package docstring says how)."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from bench.perf.throughput import say
from bench.perf.throughput.harness import Harness
from bench.perf.throughput.plan import ACTOR_ID, SEED
from bench.perf.throughput.throughput_report import Figure, Target
from hercs.rl.envs import make_env
from hercs.rl.seeding import generator, int_seed


def raw_env(bench: Harness) -> Callable[[float], tuple[float, float, float]]:
    """Raw FetchPush stepping with uniform random actions; returns run(seconds) ->
    (env steps, seconds, CPU seconds). Resets every T steps, as an actor's episodes do;
    one untimed episode first. The env lives as long as the process."""
    spec = bench.spec
    env = make_env(spec)
    rng = generator(SEED, "bench", "raw-env")
    env.reset(seed=int_seed(SEED, "bench", "raw-env"))
    T, low, high = spec.episode_steps, -spec.max_action, spec.max_action
    for _ in range(T):
        env.step(rng.uniform(low, high, spec.action_dim).astype(np.float32))

    def run(seconds: float) -> tuple[float, float, float]:
        steps, start, cpu = 0, time.perf_counter(), time.thread_time()
        while time.perf_counter() - start < seconds:
            env.reset()
            for _ in range(T):
                env.step(rng.uniform(low, high, spec.action_dim).astype(np.float32))
            steps += T
        return float(steps), time.perf_counter() - start, time.thread_time() - cpu

    return run


def measure(bench: Harness) -> None:
    p, T = bench.plan, bench.spec.episode_steps
    raw = raw_env(bench)
    actor = bench.start("actor", ACTOR_ID)

    def is_ours(actor_id: str) -> bool:
        # The wire id is `<ident>@<incarnation>` (hercs/actors/actor_shell.py).
        return actor_id.partition("@")[0] == ACTOR_ID

    turns = bench.alternate_warmed(actor, bench.headers, is_ours, p.actor_warmup_episodes,
                                   rounds=p.env_rounds, slice_s=p.env_slice_s, reference=raw)
    arrivals = [t for t, actor_id in bench.headers.snapshot() if is_ours(actor_id)]
    acked = [(t, (i + 1) * T) for i, t in enumerate(arrivals)]  # cumulative env steps
    ours, ours_cpu, reference, reference_cpu = turns.rates(acked)
    say(f"env steps/s: actor {ours:,.0f}, raw {reference:,.0f}; per CPU-second: actor "
        f"{ours_cpu:,.0f}, raw {reference_cpu:,.0f}")
    bench.details["env"] = {
        **turns.details(acked, system="actor_steps", reference="raw_steps"),
        "actor_policy": "initial weights (no learner runs in this phase); the same "
                        "network, so the same inference cost as a trained one",
    }
    slices = f"in {p.env_slice_s:g} s slices alternating with the actor's (paused meanwhile)"
    bench.figures.append(Figure(
        key="env_steps_per_s", name=f"env steps/s, one actor ({p.actor_envs} envs)",
        unit="steps/s", ours=ours, reference=reference,
        ours_what=f"one `hercs actor` process stepping {p.actor_envs} envs "
                  "(`actor.envs_per_process`; batched policy inference, exploration, "
                  "inserts acked over Zenoh), acked episodes × 50 per second at the replay",
        reference_what=f"raw FetchPush-v4 steps with random actions in one process, {slices}",
        target=Target("ratio_at_least", 0.9)))
    bench.figures.append(Figure(
        key="env_steps_per_cpu_s",
        name=f"env steps per CPU-second, one actor ({p.actor_envs} envs)",
        unit="steps/CPU-s", ours=ours_cpu, reference=reference_cpu,
        ours_what="the same acked steps over the CPU time of the actor process (all its "
                  "threads) in its slices: the rate it would reach on a core of its own",
        reference_what="raw steps over the CPU time of the stepping thread",
        target=Target("ratio_at_least", 0.95)))
