"""bench/perf/actor_envs.py quick mode: every figure computed, finite and consistent (no timing is
asserted: the machine is shared)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]


def test_quick_mode_reports_actor_against_raw_steps_per_envs_count(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "bench.perf.actor_envs", "--quick", "--envs",
                           "1", "3",
                           "--out", str(tmp_path)],
                          cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    summary = json.loads((tmp_path / "actor_envs.json").read_text())
    assert [r["envs"] for r in summary["rows"]] == [1, 3]
    for r in summary["rows"]:
        assert all(math.isfinite(v) and v > 0 for v in r.values()), r
        # one episode of T = 50 steps per env and side
        assert r["raw_steps"] == r["actor_steps"] == 50 * r["envs"]
        assert r["ratio"] == r["actor_steps_per_cpu_s"] / r["raw_steps_per_cpu_s"]
    table = (tmp_path / "actor_envs.md").read_text()
    assert "| 3 |" in table and "≥ 0.95" in table


def test_a_bad_envs_count_is_refused_with_the_flag_named() -> None:
    done = subprocess.run([sys.executable, "-m", "bench.perf.actor_envs", "--quick", "--envs", "0"],
                          cwd=REPO, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "--envs: every count must be >= 1" in done.stderr
