"""bench/perf/learner_cuda.py quick mode: every cell of its tables computed and finite; with a GPU
the TF32 emulation sits nearer the GPU's own TF32 than fp32 does (no timing is asserted)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[3]


@pytest.mark.full
def test_quick_mode_fills_every_cell(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "bench.perf.learner_cuda", "--quick", "--out",
                           str(tmp_path)], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    summary = json.loads((tmp_path / "learner_cuda.json").read_text())
    cpu = summary["cpu_updates_per_s"]
    assert sorted(cpu) == ["bf16", "fp32", "fp32+halves", "fp32+reads", "tf32"]
    assert all(sorted(row) == ["1", "4"] for row in cpu.values()), cpu
    assert all(math.isfinite(v) and v > 0 for row in cpu.values() for v in row.values())
    text = (tmp_path / "learner_cuda.md").read_text()
    assert "| CPU | tf32 |" in text
    if not torch.cuda.is_available():
        print("no CUDA device here: only the CPU rows were measured")
        assert summary["gpu"] is None and "gpu_updates_per_s" not in summary
        return
    gpu, emulation = summary["gpu_updates_per_s"], summary["emulation"]
    assert sorted(gpu) == ["bf16", "bf16+graph", "fp32", "fp32+gpu-tf32", "fp32+graph",
                           "fp32+reads", "tf32"]
    first = emulation["1"]
    assert first["tf32_from_gpu_tf32"] < first["fp32_from_gpu_tf32"]
    products = summary["product_check"]
    assert products["tf32_emulated"] < products["fp32"]


def test_the_report_of_a_gpu_run_renders_every_table() -> None:
    """`report` on a GPU run's summary (the committed H200 one, CPU-only rows included), so that
    a report bug shows here and not on a lent GPU, where it once cost a call."""
    from bench.perf.learner_cuda import report

    summary = json.loads((REPO / "docs" / "results" / "learner_cuda.json").read_text())
    for key in ("gpu_updates_per_s", "cpu_updates_per_s"):  # JSON keys back to worker counts
        summary[key] = {p: {int(n): v for n, v in row.items()} for p, row in summary[key].items()}
    text = report(summary)
    ratios = text.split("GPU over CPU")[1].split("TF32 emulation")[0]
    assert "fp32+halves" in summary["cpu_updates_per_s"] and "| CPU | fp32+halves |" in text
    assert "| fp32 |" in ratios and "fp32+halves" not in ratios  # a CPU-only setting: no ratio
    assert all(f"| GPU | {p} |" in text for p in summary["gpu_updates_per_s"])
    assert "emulated TF32" in text
