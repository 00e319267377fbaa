"""bench/perf/fair_share.py --quick: with a real replay on loopback, round-robin admission gives
each normal actor its fair share beside a flooding actor, where arrival order did not."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support import REPO


@pytest.mark.full
def test_quick_mode_normal_actors_get_their_fair_share_beside_a_flooder(
        tmp_path: Path) -> None:
    out = tmp_path / "fair_share"
    done = subprocess.run([sys.executable, "-m", "bench.perf.fair_share", "--quick", "--out",
                           str(out)], cwd=REPO, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    results = json.loads(out.with_suffix(".json").read_text())
    before, after = results["modes"].values()
    assert (before["waiting_inserts_per_actor"], after["waiting_inserts_per_actor"]) == (0, 4)
    shared = after["shared"]["actors"]
    assert len(shared) == 4
    for name, row in shared.items():  # every actor, the flooder too, gets 0.8 of its share
        assert row["share_over_fair"] >= 0.8, (name, row)
    assert before["worst_normal_over_fair"] < after["worst_normal_over_fair"]
    assert after["replay_rejects"].get("actor_queue_full", 0) > 0, "the flooder was held back"
    assert shared["flooder"]["retries"] > 0 and all(
        row["retries"] == 0 for name, row in shared.items() if name != "flooder")
    assert results["alone_ratio"] > 0.8, "a lone actor keeps the capacity"
    assert "| round-robin (after) | normal-0 |" in out.with_suffix(".md").read_text()
