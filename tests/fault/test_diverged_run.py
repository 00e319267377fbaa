"""Divergence is an error, not a hang: numbers that cannot train are refused before anything
starts, and a real `hercs up` run whose learner diverges mid-run (a user's reward scale set to
1e30 after epoch 1, `tests.goal_envs:reach_with_a_reward_scale_file`) exits 4 saying where and
what, its last sound checkpoint loadable, no weights the actors would refuse published, nothing
restarted. Every wait is on a launcher line or its exit, with a timeout.
"""

from __future__ import annotations

import csv
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hercs.config import load_yaml
from hercs.learner.checkpoint import load_checkpoint
from hercs.learner.ddpg import DDPGLearner
from hercs.learner.divergence import nonfinite_tensors, state_tensors
from hercs.rl.code_names import TRUST_ENV
from hercs.run.rundir import RunDir
from tests.goal_envs import REWARD_SCALE_FILE
from tests.integration.launcher_standins import REPO, Launcher, process_alive
from tests.support import free_endpoint

pytestmark = pytest.mark.integration

RUN_S = 240.0
REFUSED_S = 60.0
"""A refused `hercs up` only imports hercs and parses its flags (~3 s here): a wide margin."""


@pytest.mark.parametrize("override", ["ddpg.lr_critic=inf", "ddpg.lr_actor=1e300"],
                         ids=["inf", "huge"])
def test_a_learning_rate_that_cannot_train_is_refused_before_anything_starts(
        tmp_path: Path, override: str) -> None:
    runs = tmp_path / "runs"
    started = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "hercs.apps.cli", "up", "--task", "reach", "--epochs", "2",
         "--run", "never", "--run-dir", str(runs), "--set", override],
        cwd=REPO, capture_output=True, text=True, timeout=REFUSED_S)
    took = time.monotonic() - started
    field, _, value = override.partition("=")
    assert done.returncode == 2, done.stderr
    must = "be a finite number" if value == "inf" else "lie in (0, 1]"
    assert f"hercs up: invalid configuration: {field}: got " in done.stderr
    assert f", must {must}" in done.stderr, done.stderr
    assert not runs.exists(), "nothing was started or written"
    assert "started" not in done.stdout
    assert took < REFUSED_S


DIVERGED = re.compile(
    r"training diverged in epoch (?P<epoch>\d+), cycle (?P<cycle>\d+) of 3 \(the run's cycle "
    r"\d+\), update (?P<update>\d+): critic_loss = inf; the last sound checkpoint, "
    r"(?P<path>\S+) of epoch (?P<kept>\d+), is kept: `hercs up --resume (?P<run>\S+)` "
    r"continues from it")


TASK = "tests.goal_envs:reach_with_a_reward_scale_file"


@pytest.mark.full
def test_a_learner_that_diverges_mid_run_stops_the_run_and_keeps_its_last_checkpoint(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    scale = tmp_path / "reward-scale"
    monkeypatch.setenv(REWARD_SCALE_FILE, str(scale))  # every service inherits it
    run_dir = tmp_path / "runs" / "wild"
    launcher = Launcher(
        [sys.executable, "-m", "hercs.apps.cli", "up",
         "--task", TASK, "--method", "her",
         "--epochs", "20", "--actors", "1", "--run", "wild",
         "--run-dir", str(tmp_path / "runs"), "--listen", free_endpoint(),
         "--set", "training.cycles_per_epoch=3", "--set", "training.eval_episodes=2",
         "--set", "ddpg.clip_return=false", "--set", "launch.restart_backoff_s=0.2"],
        cwd=tmp_path)
    try:
        launcher.wait_for_line(r"^epoch 1/20  success", timeout_s=RUN_S)
        scale.write_text("1e30")
        status = launcher.finish(timeout_s=RUN_S)
    finally:
        launcher.kill()
    report = "\n".join(launcher.out + launcher.err)
    assert status == 4, report
    assert ("hercs up: learner learner-0 exited unexpectedly (exit code 4); its training "
            "diverged") in report
    found = DIVERGED.search(report)
    assert found is not None, report
    diverged, kept = int(found["epoch"]), int(found["kept"])
    assert kept == diverged - 1 >= 1, "the checkpoint of the last epoch that ended whole"
    assert int(found["update"]) > 3 * 40 * kept, "an update after that checkpoint"
    assert Path(found["path"]) == RunDir(run_dir).checkpoints / "learner.pt"
    assert Path(found["run"]) == run_dir
    assert "again (restart" not in report, "a diverged learner is not restarted"
    assert not [i for i, pid in launcher.child_pids.items() if process_alive(pid)]

    # the checkpoint left is the sound one of epoch `kept`, and a learner loads it
    state = load_checkpoint(RunDir(run_dir).checkpoints)
    assert state is not None and int(state["loop"]["epoch"]) == kept
    assert nonfinite_tensors(state_tensors(state["learner"], "learner")) == []
    monkeypatch.setenv(TRUST_ENV, TASK)  # named here as the launcher's --task named it
    config = load_yaml(RunDir(run_dir).config)
    learner = DDPGLearner(spec=config.task.spec, config=config.ddpg, seed=0)
    learner.load_state_dict(state["learner"])
    assert learner.updates == 3 * 40 * kept
    with RunDir(run_dir).metrics.open(newline="") as f:
        assert {int(row["epoch"]) for row in csv.DictReader(f)} <= set(range(1, kept + 1))
    # nothing was published that an actor or the evaluator refused
    for ident in ("actor-0", "evaluator-0"):
        assert "ignored a Weights message" not in RunDir(run_dir).log(ident).read_text()
