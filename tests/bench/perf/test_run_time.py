"""bench/perf/run_time quick mode: two real runs timed side by side, the ratio computed from
their own seconds per epoch, and a limit made of this machine's measured rates."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]


@pytest.mark.full
def test_quick_mode_times_both_settings_and_the_limit(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "bench.perf.run_time", "--quick", "--out",
                           str(tmp_path)], cwd=REPO, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    summary = json.loads((tmp_path / "run_time.json").read_text())
    runs = {row["setting"]: row for row in summary["runs"]}
    assert set(runs) == {"old default", "default"}
    assert all(row["s_per_epoch"] > 0 and row["start_up_s"] > 0 for row in runs.values())
    assert summary["ratios"] == [pytest.approx(runs["old default"]["s_per_epoch"]
                                               / runs["default"]["s_per_epoch"])]
    limit = summary["limit"]
    assert limit["gemm_gflops"] > 0 and limit["raw_steps_per_s"] > 0
    assert limit["indexed_steps_per_s"] > 0 and limit["indexed_limit_s_per_epoch"] > 0
    # 5 cycles of 40 updates, 5 × 4 training and 20 evaluation episodes of 50 steps
    assert (limit["updates_per_epoch"], limit["env_steps_per_epoch"]) == (200, 2000)
    text = (tmp_path / "run_time.md").read_text()
    assert "| 1 | default |" in text and "geometric mean" in text
