"""The best policies committed beside their runs' metrics (docs/results/runs/<run>/
checkpoints/best.pt) load through the API and evaluate with `hercs eval` on a fresh clone."""

from __future__ import annotations

import os
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


def _snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*"))}


def test_eval_and_load_policy_write_nothing_into_the_run_directory(tmp_path: Path) -> None:
    """Run from inside the run folder itself, the worst case: `hercs eval` and
    `hercs.load_policy` (best.pt, and a real learner.pt) leave every file as it was and add
    none."""
    import shutil

    from tests.run_dirs import make_run

    run = tmp_path / "copy"
    shutil.copytree(next(p for p in PUBLISHED if "-v1-" not in p.name), run)
    trained = tmp_path / "trained"
    make_run(trained, epochs=3, trained=2, checkpoint=2)
    before = {folder: _snapshot(folder) for folder in (run, trained)}
    done = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "eval", ".", "--episodes",
                           "1"], cwd=run, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(REPO)})
    assert done.returncode == 0, done.stderr
    for folder, checkpoint in ((run, "best"), (trained, "latest")):
        policy = hercs.load_policy(folder, checkpoint)
        spec = policy.config.task.spec
        policy.act({"observation": np.zeros(spec.obs_dim), "desired_goal": np.zeros(
            spec.goal_dim)})
    assert {folder: _snapshot(folder) for folder in (run, trained)} == before


def test_hercs_eval_of_a_zoo_name_reproduces_its_recorded_epoch_and_says_so() -> None:
    """`hercs eval zoo:NAME` evaluates the shipped policy on the goals its evaluator drew for
    best.pt's epoch and says what metrics.csv recorded there, with its interval, and that
    these episodes give the same numbers (to their last digits on another CPU)."""
    done = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "eval",
                           "zoo:push-her-ebp-cs-s1"], cwd=REPO, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    first, said = done.stdout.splitlines()[:2]
    assert "policy of epoch 44 from best.pt: success 1.00 (20/20)" in first, first
    assert said.startswith("hercs eval: metrics.csv recorded 1.00 (20/20, 95 % interval "
                           "0.84-1.00) at epoch 44, the best of its 50 evaluated epochs"), said
    assert re.search(r"the first 20 episodes here are (the evaluator's of that epoch and give "
                     r"the same success and final distance|on the goals its evaluator drew "
                     r"for that epoch and give the same success, the mean final distance)",
                     said), said
