"""bench/perf/learner.py quick mode: every figure computed, finite and consistent (no timing is
asserted: the machine is shared)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from tests.support import load_module

REPO = Path(__file__).resolve().parents[3]
bench = load_module("bench.perf.learner")


@pytest.mark.full
def test_quick_mode_reports_the_roofline_ratio_per_precision(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "bench.perf.learner", "--quick", "--out",
                           str(tmp_path)], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    summary = json.loads((tmp_path / "learner.json").read_text())
    # FetchPush, B = 256: the FLOP count is a property of the networks, not of the machine
    assert 0.7 < summary["gflop_per_update"] < 0.85
    for precision in ("fp32", "bf16"):
        r = summary["results"][precision]
        assert all(math.isfinite(v) for v in r.values()), r
        # 'share outside GEMMs' may come out negative on a noisy machine; the rest may not
        assert all(v > 0 for k, v in r.items() if k != "share_outside_gemms"), r
        assert r["ratio_to_limit"] == r["updates_per_cpu_s"] / r["limit_updates_per_cpu_s"]
        # 3 hidden layers: 5 forward passes of 4 layers (μ', Q', Q(s,u), μ, Q(s,μ)), then
        # the backward's 18 products (no input gradient for the batch itself)
        assert r["gemm_calls"] == 38
    assert "| fp32 |" in (tmp_path / "learner.md").read_text()


def test_recorded_gemms_are_the_flops_torch_counts() -> None:
    """The replay times exactly the products the FLOP counter counts: same FLOPs."""
    import numpy as np

    from hercs.config import DDPGConfig
    from hercs.learner.ddpg import DDPGLearner
    from hercs.rl.task_registry import task_spec

    spec = task_spec("push")
    learner = DDPGLearner(spec=spec, config=DDPGConfig(), seed=0)
    batch = bench.make_batch(spec, 64, np.random.default_rng(0))
    calls = bench.update_gemms(learner, batch)
    flops = sum(2 * math.prod(c.shapes[-2]) * c.shapes[-1][-1] for c in calls)
    assert flops == bench.update_flops(learner, batch)
    assert {c.dtype for c in calls} == {torch.float32}
    transposed = [c for c in calls if any(st[0] == 1 and sh[0] > 1
                                          for sh, st in zip(c.shapes, c.strides, strict=True))]
    assert transposed  # the backward's W.T and X.T operands are kept as views, as recorded
