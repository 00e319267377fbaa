"""The learner on a GPU: update rate against the CPU, and how close the TF32 emulation is.

    python -m bench.perf.learner_cuda           # ~2 min on a CUDA machine

Writes docs/results/learner_cuda.{json,md} (or --out; not with --quick unless --out is given).
Method and results: docs/PERFORMANCE.md §10."""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import sys
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime

import numpy as np
import torch

from bench.common import add_out_option, git_commit, show_report
from bench.perf.learner import make_batch
from hercs.config import DDPGConfig
from hercs.learner.ddpg import DDPGLearner
from hercs.learner.tf32 import round_to_tf32
from hercs.rl.networks import to_arrays
from hercs.rl.task_registry import task_spec
from hercs.wire.batch import TransitionBatch

GPU_TF32 = "fp32+gpu-tf32"
"""fp32 learner with the GPU's own TF32 matrix products switched on."""


@contextlib.contextmanager
def gpu_tf32(enabled: bool) -> Iterator[None]:
    """The GPU's TF32 matrix products on (torch <1.12's default) within the block."""
    matmul = torch.backends.cuda.matmul
    before = matmul.allow_tf32
    matmul.allow_tf32 = enabled
    try:
        yield
    finally:
        matmul.allow_tf32 = before


READS, GRAPH, HALVES = "+reads", "+graph", "+halves"
"""Variants of a precision: `train()` with the losses read back after every update
(`loss_means()`, a host read per update, as the old loop's path made), the captured CUDA
graph (`learner.cuda_graph`), the CPU's two halves on two threads (`learner.parallel_halves`).
Without a suffix: `train()`, the loop's path, eager."""


def learner(device: str, precision: str, spec, config: DDPGConfig) -> DDPGLearner:  # type: ignore[no-untyped-def]
    base = "fp32" if precision == GPU_TF32 else precision.split("+")[0]
    return DDPGLearner(spec=spec, config=config, seed=0, device=device, precision=base,
                       cuda_graph=precision.endswith(GRAPH),
                       parallel_halves=precision.endswith(HALVES))


def updates_per_s(step: Callable[[], None], device: str, updates: int) -> float:
    """Wall-clock updates per second, the device synchronised at both ends."""
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)
    for _ in range(max(3, updates // 10)):
        step()
    sync()
    start = time.perf_counter()
    for _ in range(updates):
        step()
    sync()
    return updates / (time.perf_counter() - start)


def speed(device: str, precisions: list[str], workers: list[int], updates: int,
          spec, config: DDPGConfig) -> dict[str, dict[int, float]]:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(0)
    out: dict[str, dict[int, float]] = {}
    for precision in precisions:
        out[precision] = {}
        for n in workers:
            net = learner(device, precision, spec, config)
            batches = [make_batch(spec, config.batch_size * n, rng) for _ in range(8)]
            it = iter(range(10**9))

            def step(net: DDPGLearner = net, batches: list[TransitionBatch] = batches,
                     it: Iterator[int] = it, reads: bool = precision.endswith(READS)) -> None:
                batch = batches[next(it) % len(batches)]
                net.train(batch)
                if reads:
                    net.loss_means()

            with gpu_tf32(precision == GPU_TF32):
                out[precision][n] = updates_per_s(step, device, updates)
    return out


def _flat(net: DDPGLearner) -> np.ndarray:
    return np.concatenate([a.ravel() for a in to_arrays(net.actor).values()]).astype(np.float64)


CHECKPOINTS = (1, 10, 50, 200)
"""After how many identical updates the emulation's weights are compared."""


def emulation(device: str, updates: int, spec, config: DDPGConfig) -> dict[str, dict[str, float]]:  # type: ignore[no-untyped-def]
    """Distances of the actor weights from the GPU-TF32 run's after k identical updates, for
    each k in CHECKPOINTS up to `updates`. DDPG amplifies any rounding difference over a few
    hundred updates (every run ends up far from every other); the early checkpoints show the
    arithmetic itself."""
    rng = np.random.default_rng(1)
    batches = [make_batch(spec, config.batch_size, rng) for _ in range(20)]
    stops = [k for k in CHECKPOINTS if k <= updates]
    snapshots: dict[str, dict[int, np.ndarray]] = {}
    start = _flat(learner(device, "fp32", spec, config))
    for precision in ("fp32", "tf32", GPU_TF32, "bf16"):
        net = learner(device, precision, spec, config)
        snapshots[precision] = {}
        with gpu_tf32(precision == GPU_TF32):
            for i in range(1, stops[-1] + 1):
                net.train(batches[i % len(batches)])
                if i % 40 == 0:
                    net.update_targets()
                if i in stops:
                    snapshots[precision][i] = _flat(net)
    ref = snapshots[GPU_TF32]
    return {str(k): {"moved": float(np.linalg.norm(ref[k] - start)),
                     **{f"{p}_from_gpu_tf32": float(np.linalg.norm(snapshots[p][k] - ref[k]))
                        for p in ("fp32", "tf32", "bf16")}} for k in stops}


def product_check(size: int = 256) -> dict[str, float]:
    """One (size × size)·(size × size) product of random normals on the GPU: the largest
    difference of fp32 and of the emulation from the GPU's TF32 product, relative to the
    largest entry. A rounding rule equal to the hardware's leaves only summation order."""
    gen = torch.Generator(device="cuda").manual_seed(0)
    a = torch.randn(size, size, device="cuda", generator=gen)
    b = torch.randn(size, size, device="cuda", generator=gen)
    with gpu_tf32(False):
        fp32 = a @ b
        emulated = round_to_tf32(a) @ round_to_tf32(b)
    with gpu_tf32(True):
        tf32 = a @ b
    scale = float(tf32.abs().max())
    return {"fp32": float((fp32 - tf32).abs().max()) / scale,
            "tf32_emulated": float((emulated - tf32).abs().max()) / scale}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--updates", type=int, default=200, help="timed updates per cell")
    add_out_option(parser, "learner_cuda")
    parser.add_argument("--quick", action="store_true",
                        help="CI: a few updates, on the CPU where there is no GPU")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    spec, config = task_spec("push"), DDPGConfig()
    updates = 5 if args.quick else args.updates
    has_cuda = torch.cuda.is_available()
    if not has_cuda and not args.quick:
        print("bench.perf.learner_cuda: torch sees no CUDA device here; --quick runs it on the CPU",
              file=sys.stderr)
        return 2
    workers = [1, 4] if args.quick else [1, 4, 16, 64]
    summary: dict[str, object] = {
        "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"), "commit": git_commit(),
        "machine": f"{platform.node()} ({os.cpu_count()} cores)",
        "cpu": platform.processor() or platform.machine(), "torch": torch.__version__,
        "gpu": torch.cuda.get_device_name(0) if has_cuda else None, "quick": args.quick,
        "batch_size": config.batch_size, "updates": updates}
    gpu_precisions = ["fp32" + READS, "fp32", "fp32" + GRAPH, GPU_TF32, "bf16",
                      "bf16" + GRAPH, "tf32"]
    if has_cuda:
        summary["gpu_updates_per_s"] = speed("cuda", gpu_precisions, workers, updates, spec,
                                             config)
        summary["emulation"] = emulation("cuda", 10 if args.quick else 200, spec, config)
        summary["product_check"] = product_check()
    summary["cpu_updates_per_s"] = speed("cpu", ["fp32" + READS, "fp32", "fp32" + HALVES,
                                                 "bf16", "tf32"], workers[:2],
                                         max(3, updates // 4), spec, config)
    text = report(summary)
    show_report(args, "learner_cuda", summary, text)
    return 0


def report(s: dict) -> str:  # type: ignore[type-arg]
    lines = ["# The learner on a GPU", "",
             f"`python -m bench.perf.learner_cuda{' --quick' if s['quick'] else ''}` — "
             f"{s['date']}, "
             f"commit {s['commit']}, {s['machine']}, torch {s['torch']}, "
             f"GPU: {s['gpu'] or 'none (CPU only)'}. Updates per second of one learner "
             f"(FetchPush-v4 shapes, 3 × 256 hidden units), wall time, device synchronised; "
             f"the CPU with one torch thread, timed in the same run.", ""]
    cpu = s["cpu_updates_per_s"]
    gpu = s.get("gpu_updates_per_s")
    workers = sorted({n for row in (gpu or cpu).values() for n in row})
    lines += ["| device | precision | " + " | ".join(f"B = {s['batch_size'] * n}"
                                                     for n in workers) + " |",
              "|---|---|" + "---|" * len(workers)]
    for device, table in (("GPU", gpu), ("CPU", cpu)):
        for precision, row in (table or {}).items():
            cells = [f"{row[n]:.0f}" if n in row else "–" for n in workers]
            lines.append(f"| {device} | {precision} | " + " | ".join(cells) + " |")
    if gpu:
        lines += ["", "GPU over CPU, same precision, same run:", "",
                  "| precision | " + " | ".join(f"B = {s['batch_size'] * n}"
                                                for n in workers if n in cpu["fp32"]) + " |",
                  "|---|" + "---|" * len([n for n in workers if n in cpu["fp32"]])]
        for precision in (p for p in cpu if p in gpu):  # the halves are a CPU setting only
            lines.append(f"| {precision} | " + " | ".join(
                f"{gpu[precision][n] / cpu[precision][n]:.1f}×" for n in workers
                if n in cpu[precision]) + " |")
        stops = list(s["emulation"])
        lines += ["", "TF32 emulation (`learner.precision=tf32`) against the GPU's own TF32 "
                  "(`fp32+gpu-tf32`): the same seed and minibatches, the L2 distance of the "
                  "actor weights from the GPU-TF32 run's after k updates:", "",
                  "| run | " + " | ".join(f"k = {k}" for k in stops) + " |",
                  "|---|" + "---|" * len(stops)]
        for p in ("fp32", "tf32", "bf16"):
            lines.append(f"| {p}{' (emulated)' if p == 'tf32' else ''} | " + " | ".join(
                f"{s['emulation'][k][f'{p}_from_gpu_tf32']:.3g}" for k in stops) + " |")
        lines.append("| (weights moved from the start) | " + " | ".join(
            f"{s['emulation'][k]['moved']:.3g}" for k in stops) + " |")
        pc = s["product_check"]
        lines += ["", "One 256 × 256 product on the GPU, largest difference from its TF32 "
                  f"product relative to the largest entry: fp32 {pc['fp32']:.2e}, emulated "
                  f"TF32 {pc['tf32_emulated']:.2e}."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
