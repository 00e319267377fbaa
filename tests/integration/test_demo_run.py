"""The committed demo run (docs/demo/push-her-cs, what `make run` makes): its episode log
holds the run's episodes and its cluster models, and `hercs view` draws them on a fresh
clone, so that a new user sees clusters forming before making a run of their own."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import hercs
from hercs.run.rundir import RunDir
from hercs.run.runlog.reader import read_cluster_models

pytestmark = pytest.mark.integration

DEMO = Path(__file__).resolve().parents[2] / "docs" / "demo" / "push-her-cs"


def test_the_demo_log_holds_the_runs_episodes_and_a_cluster_model_per_epoch() -> None:
    assert RunDir(DEMO).episode_log.stat().st_size < 20 * 2**20  # small enough to ship
    config = hercs.load_config(DEMO)
    assert (config.task.name, config.run.method, config.training.epochs) == ("push", "her-cs", 4)
    metrics = hercs.read_metrics(DEMO)
    assert metrics.column("cluster_model_version").tolist() == [1, 2, 3, 4]
    models = list(read_cluster_models(DEMO))
    assert [m.version for m in models] == [1, 2, 3, 4]
    assert all(np.frombuffer(m.centroids.data, np.float32).size == 8 * 3 for m in models)
    episodes = list(hercs.read_episodes(DEMO))
    # the last row counts the episodes stored by the learner's last epoch end; the actors'
    # last cycle's few more were stored before the run stopped
    assert int(metrics.column("episodes")[-1]) == 804 and len(episodes) == 808
    assert sorted(e.id for e in episodes) == list(range(808))


def test_hercs_view_draws_the_demo_with_its_cluster_models(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "view", str(DEMO),
                           "--episodes", "all", "--save", str(tmp_path / "demo.rrd")],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "808 of 808 episodes, 4 cluster models" in done.stderr, done.stderr
    assert (tmp_path / "demo.rrd").stat().st_size > 1_000_000
