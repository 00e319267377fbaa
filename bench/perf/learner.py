"""The learner's update against its compute limit on this core.

    python -m bench.perf.learner            # ~1 min: FetchPush, B = 256, one torch thread

FLOPs per update, this core's GEMM rate, the update rate per precision and the update's own
GEMMs replayed alone. Writes docs/results/learner.{json,md} (or --out); docs/PERFORMANCE.md §4."""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from dataclasses import dataclass
from datetime import UTC, datetime

import numpy as np
import torch

from bench.common import (
    VECTOR_EXTENSIONS,
    add_out_option,
    cpu_info,
    git_commit,
    show_report,
)
from hercs.config import DDPGConfig
from hercs.learner.ddpg import DDPGLearner
from hercs.rl.task_registry import task_spec
from hercs.wire.batch import TransitionBatch


def make_batch(spec, batch_size: int, rng: np.random.Generator) -> TransitionBatch:  # type: ignore[no-untyped-def]
    return TransitionBatch(
        o=rng.normal(size=(batch_size, spec.obs_dim)).astype(np.float32),
        g=rng.normal(size=(batch_size, spec.goal_dim)).astype(np.float32),
        u=rng.uniform(-1, 1, size=(batch_size, spec.action_dim)).astype(np.float32),
        r=-(rng.uniform(size=batch_size) > 0.3).astype(np.float32),
        o2=rng.normal(size=(batch_size, spec.obs_dim)).astype(np.float32))


def update_flops(learner: DDPGLearner, batch: TransitionBatch) -> int:
    """FLOPs torch counts in one real update (matmuls and convolutions; Adam is not)."""
    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as counter:
        learner.train(batch)
    return int(counter.get_total_flops())


@dataclass(frozen=True)
class GemmCall:
    """One matrix product of the update, as the dispatcher saw it."""

    op: str  # "mm" or "addmm"
    shapes: tuple[tuple[int, ...], ...]
    strides: tuple[tuple[int, ...], ...]
    dtype: torch.dtype

    def operands(self) -> list[torch.Tensor]:
        """Fresh tensors of the recorded shapes and strides (a transposed operand stays one)."""
        return [torch.empty_strided(shape, stride, dtype=self.dtype).normal_()
                for shape, stride in zip(self.shapes, self.strides, strict=True)]


def update_gemms(learner: DDPGLearner, batch: TransitionBatch) -> list[GemmCall]:
    """The matrix products one real update runs, in order."""
    from torch.utils._python_dispatch import TorchDispatchMode

    ops = {torch.ops.aten.mm.default: "mm", torch.ops.aten.addmm.default: "addmm"}
    calls: list[GemmCall] = []

    class Recorder(TorchDispatchMode):
        def __torch_dispatch__(self, func, types, args=(), kwargs=None):  # type: ignore[no-untyped-def]
            if func in ops:
                tensors = [a for a in args if isinstance(a, torch.Tensor)]
                calls.append(GemmCall(ops[func], tuple(tuple(t.shape) for t in tensors),
                                      tuple(t.stride() for t in tensors), tensors[-1].dtype))
            return func(*args, **(kwargs or {}))

    with Recorder():
        learner.train(batch)
    return calls


def gemm_replay_seconds(calls: list[GemmCall], repeats: int) -> float:
    """CPU seconds of the recorded products alone, per update."""
    replay = [(torch.mm if c.op == "mm" else torch.addmm, c.operands()) for c in calls]

    def one() -> None:
        for fn, operands in replay:
            fn(*operands)

    return cpu_seconds(one, repeats)


def cpu_seconds(fn, repeats: int) -> float:  # type: ignore[no-untyped-def]
    """CPU time of this thread per call (the machine is shared: wall time would count others)."""
    for _ in range(max(3, repeats // 10)):  # warm-up: oneDNN picks and caches its kernels
        fn()
    start = time.thread_time()
    for _ in range(repeats):
        fn()
    return (time.thread_time() - start) / repeats


def gemm_rate(batch_size: int, hidden: int, dtype: torch.dtype, repeats: int) -> float:
    """FLOP/s of (batch_size × hidden) · (hidden × hidden) on this thread."""
    a = torch.randn(batch_size, hidden, dtype=dtype)
    b = torch.randn(hidden, hidden, dtype=dtype)
    per_call = cpu_seconds(lambda: torch.mm(a, b), repeats)
    return 2.0 * batch_size * hidden * hidden / per_call


def update_rate(learner: DDPGLearner, batches: list[TransitionBatch]) -> float:
    """Updates per CPU-second of this thread (in the learner's own `precision`)."""
    it = iter(range(10**9))

    def one() -> None:
        learner.train(batches[next(it) % len(batches)])

    return 1.0 / cpu_seconds(one, len(batches))


def workers_scaling(spec, config: DDPGConfig, workers: tuple[int, ...], *,  # type: ignore[no-untyped-def]
                    updates: int, rounds: int) -> dict[int, float]:
    """CPU ms per update at B = 256·N (the `--workers N` preset), N in `workers`, timed in
    alternating rounds so that every size sees the same background load."""
    rng = np.random.default_rng(1)
    learners = {n: DDPGLearner(spec=spec, config=config, seed=0) for n in workers}
    batches = {n: [make_batch(spec, config.batch_size * n, rng) for _ in range(4)]
               for n in workers}
    times: dict[int, list[float]] = {n: [] for n in workers}
    for _ in range(rounds):
        for n in workers:
            it = iter(range(10**9))
            times[n].append(1e3 * cpu_seconds(
                lambda n=n, it=it: learners[n].train(batches[n][next(it) % 4]), updates))
    return {n: float(np.median(t)) for n, t in times.items()}


def cpu_flags() -> set[str]:
    """The CPU's feature flags (/proc/cpuinfo; empty where there is none)."""
    return set(cpu_info().get("flags", "").split())


def bf16_note(flags: set[str]) -> str:
    """What this CPU's extensions mean for the bf16 mode."""
    if "amx_bf16" in flags:
        return "AMX tiles multiply bf16 matrices natively, several times fp32's rate."
    if "avx512_bf16" in flags:
        return ("avx512_bf16 gives bf16 dot products a native instruction (VDPBF16PS): bf16 "
                "matrix products run faster than fp32 here.")
    return ("Without avx512_bf16 or AMX, bf16 matrix products have no native kernel and run "
            "far below fp32: there bf16 cannot pay.")


def cpu_features() -> str:
    """The CPU model and the vector extensions that decide bf16 speed."""
    model = platform.processor() or "unknown CPU"
    if model in ("unknown CPU", "x86_64"):
        model = cpu_info().get("model name", model)
    flags = cpu_flags()
    have = [f for f in VECTOR_EXTENSIONS if f in flags]
    missing = [f for f in VECTOR_EXTENSIONS if f not in flags]
    return f"{model}; has {', '.join(have) or 'none of'}; lacks {', '.join(missing) or '-'}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--task", default="push")
    parser.add_argument("--batch-size", type=int, default=256)
    parser.add_argument("--updates", type=int, default=400, help="timed updates per precision")
    add_out_option(parser, "learner")
    parser.add_argument("--quick", action="store_true", help="CI: 10 updates, 200 GEMMs")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    updates = 10 if args.quick else args.updates
    gemms = 200 if args.quick else 2000
    spec, config = task_spec(args.task), DDPGConfig()
    rng = np.random.default_rng(0)
    learners = {precision: DDPGLearner(spec=spec, config=config, seed=0, precision=precision)
                for precision in ("fp32", "bf16")}
    batches = [make_batch(spec, args.batch_size, rng) for _ in range(16)]
    flops = update_flops(learners["fp32"], batches[0])
    results: dict[str, dict[str, float]] = {}
    for name, dtype in (("fp32", torch.float32), ("bf16", torch.bfloat16)):
        gemm = gemm_rate(args.batch_size, config.hidden_size, dtype, gemms)
        rate = update_rate(learners[name], batches * max(1, updates // len(batches)))
        calls = update_gemms(learners[name], batches[0])
        gemms_only = 1.0 / gemm_replay_seconds(calls, updates)
        limit = gemm / flops
        results[name] = {"gemm_gflops": gemm / 1e9, "updates_per_cpu_s": rate,
                         "limit_updates_per_cpu_s": limit, "ratio_to_limit": rate / limit,
                         "gemm_calls": len(calls), "gemms_only_updates_per_cpu_s": gemms_only,
                         "gemms_only_ratio_to_limit": gemms_only / limit,
                         "share_outside_gemms": 1.0 - rate / gemms_only}
    scaling = workers_scaling(spec, config, (1, 2, 4, 8), updates=3 if args.quick else 20,
                              rounds=1 if args.quick else 5)
    summary = {"task": args.task, "batch_size": args.batch_size, "gflop_per_update": flops / 1e9,
               "workers_ms_per_update": scaling,
               "threads": 1, "results": results, "commit": git_commit(),
               "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
               "machine": f"{platform.node()} ({os.cpu_count()} cores)",
               "cpu": cpu_features(), "quick": args.quick}
    lines = [
        "# The learner's update against this core's GEMM limit",
        "",
        f"`python -m bench.perf.learner{' --quick' if args.quick else ''}` — {summary['date']}, "
        f"commit {summary['commit']}, {summary['machine']}, one torch thread.",
        "",
        f"CPU: {summary['cpu']}. {bf16_note(cpu_flags())}",
        "",
        f"One {spec.env_id} update at B = {args.batch_size}: "
        f"**{summary['gflop_per_update']:.3f} GFLOP** (torch's FLOP counter, Adam excluded).",
        "",
        "| precision | GEMM rate (GFLOP/s) | limit (updates/CPU-s) | measured (updates/CPU-s) "
        "| ratio | its GEMMs alone (updates/CPU-s) | their ratio | time outside GEMMs |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, r in results.items():
        lines.append(f"| {name} | {r['gemm_gflops']:.1f} | {r['limit_updates_per_cpu_s']:.1f} | "
                     f"{r['updates_per_cpu_s']:.1f} | **{r['ratio_to_limit']:.2f}** | "
                     f"{r['gemms_only_updates_per_cpu_s']:.1f} | "
                     f"{r['gemms_only_ratio_to_limit']:.2f} | "
                     f"{r['share_outside_gemms']:.0%} |")
    lines += [
        "",
        f"'Its GEMMs alone': the {results['fp32']['gemm_calls']:.0f} matrix products of one "
        "update, recorded with their shapes, strides and dtype and replayed with nothing else: "
        "the ratio an update with zero overhead would reach. 'Time outside GEMMs' is the rest of "
        "the update's CPU time (autograd, element-wise ops, Adam, Python).",
    ]
    lines += [
        "",
        "The `--workers N` preset (N× minibatch, what the reference's N MPI workers amount to): "
        "CPU time of one update at B = 256·N on this core, alternating rounds.",
        "",
        "| N | B | ms per update | × N = 1 | per 256 transitions × N = 1 |",
        "|---|---|---|---|---|",
    ]
    for n, ms in scaling.items():
        lines.append(f"| {n} | {config.batch_size * n} | {ms:.1f} | {ms / scaling[1]:.2f} | "
                     f"{ms / scaling[1] / n:.2f} |")
    text = "\n".join(lines) + "\n"
    show_report(args, "learner", summary, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
