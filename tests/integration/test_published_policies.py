"""The best policies committed beside their runs' metrics (docs/results/runs/<run>/
checkpoints/best.pt) load through the API and evaluate with `hercs eval` on a fresh clone."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import hercs
from tests.support import skip_without_mujoco_py

REPO = Path(__file__).resolve().parents[2]
PUBLISHED = sorted(p.parent.parent for p in (REPO / "docs/results/runs").glob(
    "*/checkpoints/best.pt"))


def test_some_runs_publish_their_policy() -> None:
    assert len(PUBLISHED) >= 4, PUBLISHED
    assert all(p.stat().st_size < 2_000_000 for p in
               (REPO / "docs/results/runs").glob("*/checkpoints/best.pt"))


@pytest.mark.parametrize("run", PUBLISHED, ids=lambda p: p.name)
def test_a_published_policy_loads_and_acts(run: Path) -> None:
    policy = hercs.load_policy(run)
    spec = policy.config.task.spec
    rng = np.random.default_rng(0)
    obs = {"observation": rng.normal(size=(3, spec.obs_dim)),
           "desired_goal": rng.normal(size=(3, spec.goal_dim))}
    actions = policy.act(obs)
    assert actions.shape == (3, spec.action_dim)
    assert np.all(np.abs(actions) <= spec.max_action)


def test_hercs_eval_runs_a_published_v4_policy() -> None:
    run = next(p for p in PUBLISHED if "-v1-" not in p.name)
    done = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "eval", str(run), "--episodes",
                           "3"], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert re.search(r"success [01]\.\d\d \([0-3]/3\)", done.stdout), done.stdout


def test_hercs_eval_runs_a_published_v1_policy() -> None:
    skip_without_mujoco_py()
    run = next(p for p in PUBLISHED if "-v1-" in p.name)
    done = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "eval", str(run), "--episodes",
                           "2"], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert re.search(r"success [01]\.\d\d \([0-2]/2\)", done.stdout), done.stdout
