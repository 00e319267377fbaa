"""bench/perf/env_reward.py quick mode: every cell computed and positive, for every task (no timing
is asserted: the machine is shared); the two rules agree (the bench asserts it per batch)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]


def test_quick_mode_times_both_rules_on_every_task(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "bench.perf.env_reward", "--quick", "--out",
                           str(tmp_path)], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    results = json.loads((tmp_path / "env_reward.json").read_text())["results"]
    assert sorted(results) == sorted(["push", "HandReach-v3", "HandManipulateBlock-v1"])
    for row in results.values():
        assert len(row) == 6 and all(v > 0 for v in row.values()), row
    assert "| push | 256 |" in (tmp_path / "env_reward.md").read_text()
