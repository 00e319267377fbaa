"""bench/perf/inserts.py --quick: every variant acks episodes into a real log."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tests.support import REPO


def test_quick_mode_measures_every_variant(tmp_path: Path) -> None:
    out = tmp_path / "inserts"
    done = subprocess.run([sys.executable, "-m", "bench.perf.inserts", "--quick", "--out",
                           str(out)], cwd=REPO, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    results = json.loads(out.with_suffix(".json").read_text())["results"]
    assert list(results) == ["serial, scene on the ack path", "serial", "group commit",
                             "group commit, scene path before 2026-11-27",
                             "group commit, no scene", "group commit, bounded log"]
    for row in results.values():
        assert row["episodes_per_s"] > 0 and len(row["rounds"]) == 1
        assert 0 < row["with_scenes_per_s"] <= row["episodes_per_s"] * 1.5
    assert results["group commit"]["ratio_to_before_with_scenes"] > 0
    assert results["serial, scene on the ack path"]["ratio"] == 1.0
