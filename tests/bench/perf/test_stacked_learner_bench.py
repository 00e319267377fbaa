"""bench/perf/stacked_learner.py quick mode: every arm timed for every K, each figure finite and
positive, the speed-ups the table prints computed from the same figures (no timing is
asserted: the machine is shared); the memory of a process holding 1 and 4 stacked cells."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]


def test_quick_mode_times_every_arm_for_every_k(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "bench.perf.stacked_learner", "--quick",
                           "--out", str(tmp_path)], cwd=REPO, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr
    summary = json.loads((tmp_path / "stacked_learner.json").read_text())
    table = summary["ms_per_seed_update"]
    assert sorted(table) == ["1", "2"]
    for row in table.values():
        assert set(row) == {"lone fp32", "stacked fp32", "stacked bf16"}
        assert all(math.isfinite(v) and v > 0 for v in row.values()), row
    text = (tmp_path / "stacked_learner.md").read_text()
    lone, fp32 = table["2"]["lone fp32"], table["2"]["stacked fp32"]
    assert f"| 2 | {lone:.2f} | {fp32:.2f} |" in text
    assert f"{lone / fp32:.2f}×" in text
    assert summary["cpu"] in text
    memory = summary["memory_pss_mib"]
    assert sorted(memory) == ["1", "4"]
    for k, row in memory.items():
        # a process that imported torch holds tens of MiB at least; its cells add to that
        assert row["cells_mib"] > row["imported_mib"] > 20, (k, row)
        assert f"| {k} | {row['imported_mib']:.0f} | {row['cells_mib']:.0f} |" in text
    per_slot = (memory["4"]["cells_mib"] - memory["1"]["cells_mib"]) / 3
    assert f"adds {per_slot:.1f} MiB" in text


def test_a_bad_count_is_a_usage_error() -> None:
    done = subprocess.run([sys.executable, "-m", "bench.perf.stacked_learner", "--rounds", "0"],
                          cwd=REPO, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "--rounds must be >= 1" in done.stderr
