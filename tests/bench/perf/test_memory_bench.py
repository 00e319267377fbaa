"""bench/perf/memory.py quick mode: a real 2-epoch run sampled from /proc, every service found by
its command line, every sample a positive RSS, and the report's row per role."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]
ROLES = {"up", "replay", "clusterer", "learner", "evaluator", "actor"}


@pytest.mark.full
def test_quick_mode_samples_every_service_of_a_run(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "bench.perf.memory", "--quick", "--out",
                           str(tmp_path)], cwd=REPO, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    rows = list(csv.DictReader((tmp_path / "memory-quick.csv").read_text().splitlines()))
    assert {r["role"] for r in rows} == ROLES
    assert all(float(r["rss_mb"]) > 0 for r in rows)
    # the learner holds torch once it is up: over 100 MB (a process sampled while it starts
    # can be a few MB, so no floor is asserted for the others)
    assert max(float(r["rss_mb"]) for r in rows if r["role"] == "learner") > 100
    assert max(int(r["epoch"]) for r in rows) >= 1
    text = (tmp_path / "memory.md").read_text()
    assert all(f"| memory-quick | {role} |" in text for role in ROLES)
