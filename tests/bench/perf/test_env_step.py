"""bench/perf/env_step.py quick mode: both settings timed in every round on one trajectory,
every rate finite and positive (no speed-up is asserted: the machine is shared)."""

from __future__ import annotations

import math
from pathlib import Path

from tests.support import quick_report


def test_quick_mode_times_both_settings_on_the_same_trajectory(tmp_path: Path) -> None:
    summary, report = quick_report("bench.perf.env_step", "env_step", tmp_path)
    found = summary["tasks"]["reach"]
    assert found["same_last_observation"] is True
    for rates in found["steps_per_cpu_s"].values():
        assert len(rates) == summary["rounds"] == 2
        assert all(math.isfinite(r) and r > 0 for r in rates)
    assert found["median_ratio"] > 0
    assert "| FetchReach-v4 |" in report
