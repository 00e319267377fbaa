"""Learning beyond Fetch: a whole `hercs up` run on a user's own goal environment, named
`module:factory` (tests/goal_envs.py: a point driven to a goal within 0.4 of its start, in
10 steps), must reach 90 % success. Its spec is read from the environment and its rewards come
from the environment's own `compute_reward` (the `env` rule, hercs.rl.goal_env): the path any lab
environment takes."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from hercs.run.rundir import RunDir
from hercs.run.runlog import read_cluster_models, read_episode_messages
from hercs.wire.codec import msg_to_array
from tests.support import free_endpoint

pytestmark = [pytest.mark.integration, pytest.mark.learning, pytest.mark.full]

TASK = "tests.goal_envs:reach_on_a_plane"
EPOCHS = 6
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("runs")
    cmd = [sys.executable, "-m", "hercs.apps.cli", "up", "--task", TASK, "--method", "her-cs",
           "--epochs", str(EPOCHS), "--seed", "1", "--run", "goal-env-learns",
           "--run-dir", str(root), "--listen", free_endpoint(),
           "--set", "training.cycles_per_epoch=10", "--set", "training.eval_episodes=20",
           "--set", "cluster.k=4", "--set", "cluster.fgb_size=40"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=900, cwd=REPO)
    path = root / "goal-env-learns"
    logs = "\n".join(f"== {p.name}\n{p.read_text()[-2000:]}"
                     for p in sorted(RunDir(path).logs.glob("*.log"))) if path.exists() else ""
    assert proc.returncode == 0, (
        f"hercs up failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}\n{logs}")
    return path


def test_a_users_goal_env_reaches_90_percent_success(run_dir: Path) -> None:
    with open(RunDir(run_dir).metrics) as f:
        success = [float(r["success_rate"]) for r in csv.DictReader(f)]
    assert len(success) == EPOCHS
    assert max(success[-3:]) >= 0.9, f"success per epoch: {success}"


def test_the_run_records_the_task_and_logs_its_2d_goals(run_dir: Path) -> None:
    config = yaml.safe_load(RunDir(run_dir).config.read_text())
    assert config["task"]["name"] == TASK
    _, episode = next(iter(read_episode_messages(run_dir)))
    assert episode.task == TASK
    assert msg_to_array(episode.ag).shape == (11, 2)  # T + 1 achieved goals in the plane
    models = list(read_cluster_models(run_dir))
    assert models, "HER-CS fitted its clusters on the failed 2-d goals"
    assert all(msg_to_array(m.centroids).shape == (4, 2) for m in models)
