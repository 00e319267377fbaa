"""`hercs learner-stack` on real runs: two FetchReach runs, each a real `hercs up` with its own
router, replay, clusterer, evaluator and actor but no learner (`launch.learner_elsewhere`),
trained to their end by one stacked learner process over Zenoh. Each run's `hercs up` ends 0
when the stack says its run finished; each metrics.csv holds every epoch once; each
checkpoint is a lone learner's, with the run's own update count. Killed with SIGKILL after the
runs' first epochs, the stack started again resumes each run from its own checkpoint."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hercs.config import load_yaml
from hercs.learner.checkpoint import load_checkpoint
from hercs.learner.ddpg import DDPGLearner
from hercs.run.metrics import recorded_epochs
from hercs.run.rundir import RunDir
from tests.support import free_endpoint

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.full]

EPOCHS, CYCLES, MINIBATCHES = 3, 2, 5
SMALL = ["--set", f"training.cycles_per_epoch={CYCLES}", "--set", "training.eval_episodes=2",
         "--set", f"training.minibatches_per_cycle={MINIBATCHES}",
         "--set", "launch.learner_elsewhere=true"]
RUN_TIMEOUT_S = 420.0


def start_run(root: Path, name: str, seed: int) -> subprocess.Popen[str]:
    cmd = [sys.executable, "-m", "hercs.apps.cli", "up", "--task", "reach", "--method", "her",
           "--seed", str(seed), "--epochs", str(EPOCHS), "--actors", "1", "--run", name,
           "--run-dir", str(root), "--listen", free_endpoint(), *SMALL]
    return subprocess.Popen(cmd, cwd=root, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)


def start_stack(root: Path, names: list[str], log: Path) -> subprocess.Popen[bytes]:
    with log.open("ab") as out:
        return subprocess.Popen([sys.executable, "-m", "hercs.apps.cli", "learner-stack",
                                 *(str(root / n) for n in names)], cwd=root, stdout=out,
                                stderr=subprocess.STDOUT)


def wait_for(what: str, done, timeout_s: float, procs) -> None:  # type: ignore[no-untyped-def]
    """Until `done()`, failing at once if one of `procs` died (the runs' files are written by
    them: there is no event to await but the files)."""
    deadline = time.monotonic() + timeout_s
    while not done():
        for proc in procs:
            if proc.poll() is not None:
                output = proc.stdout.read() if proc.stdout is not None else ""
                pytest.fail(f"{what}: {proc.args[3:6]} exited {proc.returncode}:\n"
                            f"{output[-3000:]}")
        assert time.monotonic() < deadline, f"{what}: not within {timeout_s:g} s"
        time.sleep(0.2)


def finish(runs: dict[str, subprocess.Popen[str]], stack: subprocess.Popen[bytes],
           log: Path) -> None:
    for name, proc in runs.items():
        try:
            output, _ = proc.communicate(timeout=RUN_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            output, _ = proc.communicate()
        assert proc.returncode == 0, (f"{name}: hercs up exited {proc.returncode}:\n"
                                      f"{output[-3000:]}\nstack log:\n"
                                      f"{log.read_text()[-3000:]}")
        assert "remote learner" in output, output[-2000:]  # the stack joined it
    assert stack.wait(timeout=60) == 0, log.read_text()[-3000:]


def check_run(run_dir: Path) -> None:
    files = RunDir(run_dir)
    assert recorded_epochs(files.metrics) == list(range(1, EPOCHS + 1))
    state = load_checkpoint(files.checkpoints)
    assert state is not None and state["loop"]["epoch"] == EPOCHS
    config = load_yaml(files.config)
    lone = DDPGLearner(spec=config.task.spec, config=config.ddpg, seed=0)
    lone.load_state_dict(state["learner"])  # a lone learner reads a stacked cell's checkpoint
    assert lone.updates == EPOCHS * CYCLES * MINIBATCHES


@pytest.fixture
def runs(tmp_path: Path):  # type: ignore[no-untyped-def]
    names = ["stack-a", "stack-b"]
    procs = {name: start_run(tmp_path, name, seed) for seed, name in enumerate(names, 1)}
    try:
        wait_for("the runs' routers", lambda: all(
            (tmp_path / n / "router.json").is_file() for n in names), 120, procs.values())
        yield tmp_path, names, procs
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc in procs.values():
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()


def test_one_stacked_learner_trains_two_runs_to_their_end(runs) -> None:  # type: ignore[no-untyped-def]
    root, names, procs = runs
    log = root / "stack.log"
    stack = start_stack(root, names, log)
    try:
        finish(procs, stack, log)
    finally:
        if stack.poll() is None:
            stack.kill()
    text = log.read_text()
    assert "learner stack of 2 runs (stack-a, stack-b)" in text
    for name in names:
        check_run(root / name)


def test_a_killed_stack_started_again_resumes_each_run_from_its_checkpoint(runs) -> None:  # type: ignore[no-untyped-def]
    root, names, procs = runs
    log = root / "stack.log"
    stack = start_stack(root, names, log)
    try:
        wait_for("both runs' first epoch", lambda: all(
            recorded_epochs(RunDir(root / n).metrics) for n in names), RUN_TIMEOUT_S,
            [stack, *procs.values()])
        os.kill(stack.pid, signal.SIGKILL)
        stack.wait(timeout=30)
        stack = start_stack(root, names, log)
        finish(procs, stack, log)
    finally:
        if stack.poll() is None:
            stack.kill()
    assert log.read_text().count("resumed from the checkpoint of epoch") == 2
    for name in names:
        check_run(root / name)
