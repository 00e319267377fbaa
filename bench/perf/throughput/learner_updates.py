"""2. Learner updates/s: the `hercs learner` process against `LearnerLoop.step` in this
process, in alternating slices; and the update against this core's GEMM limit."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np
import torch

from bench.perf.learner import gemm_rate, make_batch, update_flops, update_rate
from bench.perf.throughput import say
from bench.perf.throughput.harness import Child, Harness
from bench.perf.throughput.plan import EPISODE_POOL, SEED
from bench.perf.throughput.synthetic import fill_table
from bench.perf.throughput.throughput_report import Figure, Target
from hercs.learner.builder import LearnerBuilder
from hercs.learner.ddpg import DDPGLearner
from hercs.replay_service.builder import ReplayBuilder
from hercs.rl.seeding import generator
from hercs.wire.served import ReplayCounters, ServedBatch


def reference_learner(bench: Harness, batches: Sequence[ServedBatch]
                      ) -> Callable[[float], tuple[float, float, float]]:
    """A `LearnerLoop` in this process; returns run(seconds) -> (updates, seconds, CPU
    seconds), whole cycles only. One untimed cycle first."""
    config = bench.configs["her"][0]
    loop = LearnerBuilder(config).loop(
        DDPGLearner(spec=bench.spec, config=config.ddpg, seed=config.run.seed),
        replay_status=lambda samples: ReplayCounters(samples=samples))  # rows are not timed
    loop.step(batches[0])
    turn = 0

    def run(seconds: float) -> tuple[float, float, float]:
        nonlocal turn
        updates, start, cpu = 0, time.perf_counter(), time.thread_time()
        while time.perf_counter() - start < seconds:
            batch = batches[turn % len(batches)]
            loop.step(batch)
            updates += len(batch.minibatches)
            turn += 1
        return float(updates), time.perf_counter() - start, time.thread_time() - cpu

    return run


def local_batches(bench: Harness, count: int) -> list[ServedBatch]:
    """Batches as the learner gets them, sampled here from a local table (untimed)."""
    config = bench.configs["her"][0]
    table = ReplayBuilder(config).table(rng=generator(SEED, "bench", "learner-core"))
    fill_table(table, bench.pool, max(bench.plan.learner_min_episodes, EPISODE_POOL))
    return [table.draw(bench.plan.minibatches_per_cycle, config.ddpg.batch_size)
            for _ in range(count)]


def measure(bench: Harness, replay: Child) -> None:
    p = bench.plan
    torch.set_num_threads(1)  # as hercs.learner.learner_shell does
    bench.top_up(replay, p.learner_min_episodes)
    reference = reference_learner(bench, local_batches(bench, 4))
    bench.weights.clear()
    learner = bench.start("learner", "bench-learner")
    turns = bench.alternate_warmed(learner, bench.weights,
                                   lambda v: v >= p.learner_warmup_cycles, 1,
                                   rounds=p.learner_rounds, slice_s=p.learner_slice_s,
                                   reference=reference)
    progress = [(t, v * p.minibatches_per_cycle) for t, v in bench.weights.snapshot()]
    ours, ours_cpu, reference_rate, reference_cpu = turns.rates(progress)
    say(f"updates/s: learner service {ours:.1f}, in process {reference_rate:.1f}; per "
        f"CPU-second: service {ours_cpu:.1f}, in process {reference_cpu:.1f}")
    bench.details["learner"] = {
        **turns.details(progress, system="service_updates", reference="reference_updates"),
        "minibatches_per_cycle": p.minibatches_per_cycle, "batch_size": 256,
        "torch_threads": 1,
    }
    bench.figures.append(Figure(
        key="learner_updates_per_s", name="learner updates/s", unit="updates/s",
        ours=ours, reference=reference_rate,
        ours_what=f"the `hercs learner` process pulling {p.minibatches_per_cycle}×256 "
                  "batches over Zenoh (prefetch depth 2), weights versions per second × "
                  f"{p.minibatches_per_cycle}",
        reference_what="`LearnerLoop.step` in one process, one torch thread, on batches "
                       "sampled beforehand from a local ReplayTable, in "
                       f"{p.learner_slice_s:g} s slices alternating with the learner's "
                       "(paused meanwhile)",
        target=Target("ratio_at_least", 0.95)))
    bench.figures.append(Figure(
        key="learner_updates_per_cpu_s", name="learner updates per CPU-second",
        unit="updates/CPU-s", ours=ours_cpu, reference=reference_cpu,
        ours_what="the same updates over the CPU time of the learner process (update "
                  "thread, prefetch and decoding, weights broadcast) in its slices",
        reference_what="in-process updates over the CPU time of the updating thread"))


def measure_roofline(bench: Harness) -> None:
    """The update against this core's GEMM limit, per precision (bench/perf/learner.py, where
    the GEMM replay that explains the gap also runs)."""
    p, spec, config = bench.plan, bench.spec, bench.configs["her"][0].ddpg
    rng = np.random.default_rng(SEED)
    batches = [make_batch(spec, config.batch_size, rng) for _ in range(16)]
    repeats = batches * max(1, p.roofline_updates // len(batches))
    flops = 0
    targets = {"fp32": 0.85, "bf16": 0.8}
    for precision, dtype in (("fp32", torch.float32), ("bf16", torch.bfloat16)):
        learner = DDPGLearner(spec=spec, config=config, seed=SEED, precision=precision)
        flops = flops or update_flops(learner, batches[0])
        limit = gemm_rate(config.batch_size, config.hidden_size, dtype,
                          p.roofline_gemms) / flops
        rate = update_rate(learner, repeats)
        say(f"learner {precision}: {rate:.1f} updates/CPU-s against a GEMM limit of "
            f"{limit:.1f} ({rate / limit:.2f})")
        bench.figures.append(Figure(
            key=f"learner_roofline_{precision}",
            name=f"learner update vs its {precision} GEMM limit", unit="updates/CPU-s",
            ours=rate, reference=limit,
            ours_what=f"`DDPGLearner.train` with learner.precision={precision}, "
                      f"B = {config.batch_size}, one torch thread, in process",
            reference_what=f"this core's {config.batch_size}×{config.hidden_size}×"
                           f"{config.hidden_size} {precision} GEMM rate ÷ the update's "
                           f"{flops / 1e9:.3f} GFLOP (torch's FLOP counter), measured "
                           "in the same run",
            target=Target("ratio_at_least", targets[precision])))
