"""bench/learner.py quick mode: every figure computed, finite and consistent (no timing is
asserted: the machine is shared)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_quick_mode_reports_the_roofline_ratio_per_precision(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "bench/learner.py", "--quick", "--out", str(tmp_path)],
                          cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    summary = json.loads((tmp_path / "learner.json").read_text())
    # FetchPush, B = 256: the FLOP count is a property of the networks, not of the machine
    assert 0.7 < summary["gflop_per_update"] < 0.85
    for precision in ("fp32", "bf16"):
        r = summary["results"][precision]
        assert all(math.isfinite(v) and v > 0 for v in r.values()), r
        assert r["ratio_to_limit"] == r["updates_per_cpu_s"] / r["limit_updates_per_cpu_s"]
    assert "| fp32 |" in (tmp_path / "learner.md").read_text()
