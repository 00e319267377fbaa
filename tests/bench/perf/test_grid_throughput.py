"""bench/perf/grid_throughput quick mode: the same real two-run grid with --jobs 1 and 2 and
with one stacked learner in fp32 and bf16, and epochs per hour computed from each grid's own
wall time."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]


@pytest.mark.full
def test_quick_mode_times_a_grid_per_jobs_value(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "bench.perf.grid_throughput", "--quick",
                           "--stacked", "--out", str(tmp_path)], cwd=REPO, capture_output=True,
                          text=True, timeout=900)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    summary = json.loads((tmp_path / "grid_throughput.json").read_text())
    assert summary["jobs"] == [1, 2]
    arms = ("1", "2", "stacked fp32", "stacked bf16")
    assert list(summary["epochs_per_hour"]) == list(arms)
    for arm in arms:
        (wall,) = summary["walls"][arm]
        # two runs of two epochs each: 4 epochs in the grid's wall time
        assert summary["epochs_per_hour"][arm] == pytest.approx(3600 * 4 / wall)
    lone = {j: summary["epochs_per_hour"][j] for j in ("1", "2")}
    assert summary["best_jobs"] == int(max(lone, key=lone.get))
    assert summary["best_arm"] == max(summary["epochs_per_hour"],
                                      key=summary["epochs_per_hour"].get)
    text = (tmp_path / "grid_throughput.md").read_text()
    assert "| 2 |" in text and "| stacked bf16 |" in text
