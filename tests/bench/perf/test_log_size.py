"""bench/perf/log_size.py: the measured bytes add up to the files', and the projection follows the
bounded log's rules (a run of 100 episodes, a 20-episode buffer, 5-episode segments)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bench.perf.log_size import measure, project
from bench.synthetic_episodes import random_episode
from hercs.proto import hercs_pb2 as pb
from hercs.proto.schema import SCHEMA_VERSION
from hercs.run.runlog import EpisodeLogWriter, segment_paths
from hercs.wire.codec import episode_to_msg
from tests.support import REPO, saved_run_config


@pytest.fixture
def run_dir(tmp_path: Path) -> Path:
    config = saved_run_config(tmp_path, ["task.name=reach", "run.name=t",
                                         "replay.buffer_transitions=1000",
                                         "training.cycles_per_epoch=5"])
    spec = config.task.spec
    for name, ids in (("episodes.000.mcap", range(0, 12)), ("episodes.mcap", range(12, 30))):
        with EpisodeLogWriter(tmp_path / name, run="t", task="reach") as writer:
            for i in ids:
                ep = random_episode(spec, np.random.default_rng(i), seq=i)
                writer.append_episode(episode_to_msg(ep, run="t", task="reach"), episode_id=i)
            writer.append_eval_result(pb.EvalResult(schema_version=SCHEMA_VERSION, epoch=1))
    return tmp_path


def test_the_measured_parts_add_up_to_the_files(run_dir: Path) -> None:
    measured = measure(run_dir)
    assert measured.episodes == 30 and measured.other_records == 2
    assert measured.segments == 2
    on_disk = sum(p.stat().st_size for p in segment_paths(run_dir))
    assert measured.total == pytest.approx(on_disk, abs=1e-6)
    assert measured.per_episode("/scene", "/scene/points") > measured.per_episode("/episodes")


def test_the_projection_keeps_what_resume_needs() -> None:
    """Unbounded: every episode in one file. Bound 0: after the rotation at the last episode
    (100) the buffer's 20 episodes are left, and the log was largest just before it: 20 kept
    plus the 5 of the full live segment (1.25 buffers)."""
    common = dict(episodes=100, capacity=20, segments_per_buffer=4, episode_bytes=1000.0,
                  segment_bytes=0.0, state_bytes=0.0)
    whole = project(max_bytes=-1, **common)
    assert (whole.end_bytes, whole.peak_bytes, whole.segments_at_end) == (100_000, 100_000, 1)
    minimal = project(max_bytes=0, **common)
    assert (minimal.end_bytes, minimal.peak_bytes) == (20_000, 25_000)
    assert minimal.segments_at_end == 5  # four of 5 episodes and the new, empty live one
    bounded = project(max_bytes=40_000, **common)
    assert bounded.end_bytes == 40_000 and bounded.peak_bytes == 45_000, "bound + a segment"


def test_it_prints_a_row_per_bound_and_refuses_bad_ones(run_dir: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "bench.perf.log_size", str(run_dir), "--epochs",
                           "4", "--bounds=-1,0,150000"], cwd=REPO, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    rows = [line for line in done.stdout.splitlines() if line.startswith("| ")]
    assert [r.split(" | ")[0] for r in rows[1:]] == ["| -1 (keep all)", "| 0 (default)",
                                                     "| 150,000"]
    bad = subprocess.run([sys.executable, "-m", "bench.perf.log_size", str(run_dir),
                          "--bounds=-5"], cwd=REPO, capture_output=True, text=True,
                         timeout=120)
    assert bad.returncode == 2 and "--bounds: got '-5'" in bad.stderr
