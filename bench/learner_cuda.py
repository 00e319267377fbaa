"""The learner on a GPU: update rate against the CPU, and how close the TF32 emulation is.

    python -m bench.learner_cuda           # ~2 min on a CUDA machine
    python -m bench.learner_cuda --quick   # CI: a few updates on whatever device there is

Two questions, measured in one process:

1. **Speed.** Updates per second of `DDPGLearner.update` (FetchPush shapes, the paper's
   network) at B = 256·N (the `--workers N` preset), wall time with the GPU synchronised, for
   each `learner.precision` and for fp32 with the GPU's own TF32 products on (what torch 1.10
   did by default on Ampere); beside the same updates on this machine's CPU with one torch
   thread (the learner's setting on a small box), timed in the same run.
2. **TF32 emulation.** `learner.precision=tf32` (learner/tf32.py) rounds every product's
   operands to TF32 on any device. From the same seed and minibatches, 200 updates on the GPU
   in fp32, in emulated TF32 and with the GPU's TF32: the distance of the emulation's actor
   weights from the GPU TF32 run's, beside fp32's distance from it and beside how far the
   weights moved. Emulation faithful to the arithmetic = its distance far below fp32's.

Writes docs/results/learner_cuda.{json,md} (or --out); not with --quick unless --out is given.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import sys
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import torch

from bench.common import git_commit
from bench.learner import make_batch
from hercs.batch import TransitionBatch
from hercs.config import DDPGConfig
from hercs.networks import to_arrays
from hercs.tasks import task_spec
from learner.ddpg import DDPGLearner

REPO = Path(__file__).resolve().parents[1]
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


def learner(device: str, precision: str, spec, config: DDPGConfig) -> DDPGLearner:  # type: ignore[no-untyped-def]
    return DDPGLearner(spec=spec, config=config, seed=0, device=device,
                       precision="fp32" if precision == GPU_TF32 else precision)


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
                     it: Iterator[int] = it) -> None:
                net.update(batches[next(it) % len(batches)])

            with gpu_tf32(precision == GPU_TF32):
                out[precision][n] = updates_per_s(step, device, updates)
    return out


def _flat(net: DDPGLearner) -> np.ndarray:
    return np.concatenate([a.ravel() for a in to_arrays(net.actor).values()]).astype(np.float64)


def emulation(device: str, updates: int, spec, config: DDPGConfig) -> dict[str, float]:  # type: ignore[no-untyped-def]
    """Distances between actor weights after `updates` identical updates."""
    rng = np.random.default_rng(1)
    batches = [make_batch(spec, config.batch_size, rng) for _ in range(20)]
    finals: dict[str, np.ndarray] = {}
    start = _flat(learner(device, "fp32", spec, config))
    for precision in ("fp32", "tf32", GPU_TF32, "bf16"):
        net = learner(device, precision, spec, config)
        with gpu_tf32(precision == GPU_TF32):
            for i in range(updates):
                net.update(batches[i % len(batches)])
                if i % 40 == 39:
                    net.update_targets()
        finals[precision] = _flat(net)
    ref = finals[GPU_TF32]
    return {"moved": float(np.linalg.norm(ref - start)),
            **{f"{p}_from_gpu_tf32": float(np.linalg.norm(finals[p] - ref))
               for p in ("fp32", "tf32", "bf16")}}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--updates", type=int, default=200, help="timed updates per cell")
    parser.add_argument("--out", type=Path, help="where learner_cuda.{json,md} go "
                        "(default docs/results; not written with --quick unless given)")
    parser.add_argument("--quick", action="store_true",
                        help="CI: a few updates, on the CPU where there is no GPU")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    spec, config = task_spec("push"), DDPGConfig()
    updates = 5 if args.quick else args.updates
    has_cuda = torch.cuda.is_available()
    if not has_cuda and not args.quick:
        print("bench.learner_cuda: torch sees no CUDA device here; --quick runs it on the CPU",
              file=sys.stderr)
        return 2
    workers = [1, 4] if args.quick else [1, 4, 16, 64]
    summary: dict[str, object] = {
        "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"), "commit": git_commit(),
        "machine": f"{platform.node()} ({os.cpu_count()} cores)",
        "cpu": platform.processor() or platform.machine(), "torch": torch.__version__,
        "gpu": torch.cuda.get_device_name(0) if has_cuda else None, "quick": args.quick,
        "batch_size": config.batch_size, "updates": updates}
    gpu_precisions = ["fp32", GPU_TF32, "bf16", "tf32"]
    if has_cuda:
        summary["gpu_updates_per_s"] = speed("cuda", gpu_precisions, workers, updates, spec,
                                             config)
        summary["emulation"] = emulation("cuda", 10 if args.quick else 200, spec, config)
    summary["cpu_updates_per_s"] = speed("cpu", ["fp32", "bf16", "tf32"], workers[:2],
                                         max(3, updates // 4), spec, config)
    text = report(summary)
    print(text)
    out = args.out or (None if args.quick else REPO / "docs" / "results")
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / "learner_cuda.json").write_text(json.dumps(summary, indent=2) + "\n")
        (out / "learner_cuda.md").write_text(text)
        print(f"wrote {out / 'learner_cuda.md'}")
    return 0


def report(s: dict) -> str:  # type: ignore[type-arg]
    lines = ["# The learner on a GPU", "",
             f"`python -m bench.learner_cuda{' --quick' if s['quick'] else ''}` — {s['date']}, "
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
        for precision in cpu:
            lines.append(f"| {precision} | " + " | ".join(
                f"{gpu[precision][n] / cpu[precision][n]:.1f}×" for n in workers
                if n in cpu[precision]) + " |")
        e = s["emulation"]
        lines += ["", "TF32 emulation (`learner.precision=tf32`) against the GPU's own TF32, "
                  "200 identical updates from one seed, distance of the actor weights (L2):", "",
                  "| run | distance from GPU TF32 | ÷ fp32's |", "|---|---|---|"]
        for p in ("fp32", "tf32", "bf16"):
            d = e[f"{p}_from_gpu_tf32"]
            lines.append(f"| {p}{' (emulated TF32)' if p == 'tf32' else ''} | {d:.4g} | "
                         f"{d / e['fp32_from_gpu_tf32']:.2f} |")
        lines += ["", f"The weights moved {e['moved']:.4g} from their start."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
