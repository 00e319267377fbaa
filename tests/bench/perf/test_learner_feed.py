"""bench/perf/learner_feed: where a learner counts as fed (pure), and the quick mode's real runs
with one and two actors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from bench.perf.learner_feed import fed_at, parse_args, render, summarise

REPO = Path(__file__).resolve().parents[3]


def test_fed_at_is_the_fewest_actors_within_five_percent_of_the_best() -> None:
    runs = [{"actors": 1, "updates_per_s": 300.0}, {"actors": 2, "updates_per_s": 560.0},
            {"actors": 4, "updates_per_s": 590.0}, {"actors": 8, "updates_per_s": 600.0}]
    assert fed_at(runs) == 4  # 590 ≥ 0.95 × 600; 560 is not
    assert fed_at(runs[:1]) == 1


def test_a_partial_report_says_which_counts_were_run() -> None:
    """The report written after each run (kept if a later run fails) says it is partial."""
    args = parse_args(["--actors", "1", "2", "4"])
    runs = [{"actors": n, "wall_s": 1.0, "updates_per_s": 100.0 * n, "env_steps_per_s": 1.0,
             "batch_wait_s": 0.0} for n in (1, 2)]
    partial = summarise(args, runs)
    assert not partial["complete"] and partial["planned"] == [1, 2, 4]
    assert "Partial: 2 of the actor counts [1, 2, 4] were run." in render(partial)
    whole = summarise(args, [*runs, {**runs[1], "actors": 4}])
    assert whole["complete"] and "Partial" not in render(whole)


@pytest.mark.full
def test_quick_mode_runs_each_actor_count(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "bench.perf.learner_feed", "--quick", "--out",
                           str(tmp_path)], cwd=REPO, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    summary = json.loads((tmp_path / "learner_feed.json").read_text())
    assert [r["actors"] for r in summary["runs"]] == [1, 2]
    assert all(r["updates_per_s"] > 0 and r["env_steps_per_s"] > 0 for r in summary["runs"])
    assert summary["fed_at"] == fed_at(summary["runs"]) and summary["complete"]
    assert "| 2 |" in (tmp_path / "learner_feed.md").read_text()
