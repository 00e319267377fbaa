"""bench/faults/replay_recovery.py --quick: a real `hercs replay` process recovers each killed run
(the retried insert acked as a duplicate under its logged id, the status counting every
episode written and the buffer holding what it keeps) and the report times every size."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from bench.faults.killed_replay_log import T
from bench.faults.replay_recovery import PHASES, QUICK_BUFFER, QUICK_FGB, QUICK_SIZES
from bench.faults.service_kills import kept_sections
from tests.support import REPO

pytestmark = [pytest.mark.integration, pytest.mark.timeout(300)]


def test_quick_mode_recovers_every_episode_written_and_times_each_size(
        tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "bench.faults.replay_recovery", "--quick", "--out",
                           str(tmp_path)], cwd=REPO, capture_output=True, text=True,
                          timeout=280)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    report = json.loads((tmp_path / "replay_recovery.json").read_text())
    assert (tmp_path / "replay_recovery.md").read_text().count("| yes |") == len(QUICK_SIZES)
    assert report["repeats"] == 2 and report["buffer_transitions"] == QUICK_BUFFER
    capacity = QUICK_BUFFER // T
    rows = report["sizes"]
    assert [row["transitions"] for row in rows] == list(QUICK_SIZES)
    for row in rows:
        episodes = row["transitions"] // T
        assert row["episodes"] == episodes and row["recovered_exactly"]
        models = episodes // QUICK_FGB  # a cluster model logged every cluster.fgb_size
        assert row["expected"] == {"inserted": episodes, "stored": min(episodes, capacity),
                                   "cluster_model_version": models}
        for run in row["process"]["runs"]:  # what the real process answered
            assert run["ack_duplicate"] and run["ack_episode_id"] == episodes - 1
            assert (run["status_inserts"], run["status_size_episodes"],
                    run["status_cluster_model_version"]) == (
                episodes, min(episodes, capacity), models)
            # logged right after the constructor that declares the queryables: about when
            # the ack came (before or after it)
            assert 0 < run["recovered_s"] < run["serving_s"] + 1.0
        for run in row["in_process"]["runs"]:
            assert (run["inserted"], run["stored"], run["cluster_model_version"]) == (
                episodes, min(episodes, capacity), models)
            assert sum(run[f"{name}_s"] for name in PHASES) <= run["total_s"]
        process, in_process = row["process"], row["in_process"]
        assert len(process["runs"]) == len(in_process["runs"]) == 2
        assert 0 < process["serving_s_median"] <= process["serving_s_max"]
        assert 0 < in_process["total_s_median"] <= in_process["total_s_max"]
        assert in_process["dominant"] in PHASES
    # the larger size outgrew the 20-episode buffer: it starts from a saved replay state and
    # needs only the buffer's episodes (from first_held_id on)
    small, large = rows
    assert large["expected"]["cluster_model_version"] >= 2  # the newest of several adopted
    assert small["replay_state"]["first_held_id"] == 0
    assert large["replay_state"]["first_held_id"] > 0
    assert large["replay_state"]["next_episode_id"] - large["replay_state"][
        "first_held_id"] >= capacity


def test_faults_md_keeps_the_recovery_bound_when_bench_faults_rewrites_it(tmp_path: Path) -> None:
    kept = kept_sections(REPO / "docs/results/faults.md")
    assert kept.startswith("\n## Replay recovery time after a kill")
    assert "python -m bench.faults.replay_recovery" in kept and "**The bound.**" in kept
    assert kept_sections(tmp_path / "none.md") == ""
    generated = tmp_path / "faults.md"
    generated.write_text("# Fault injection\n\n| fault |\n|---|\n\n- replay: a note\n")
    assert kept_sections(generated) == ""
