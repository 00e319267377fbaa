"""Helpers shared by tests of different folders: free ports and endpoints, a real Rerun viewer
stand-in, loading the benchmark scripts (which are files, not a package), random learner
minibatches and one update's losses."""

from __future__ import annotations

import importlib
import json
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from hercs.apps.launch.child_process import stop_process
from hercs.apps.launch.router import free_port
from hercs.config import HercsConfig, apply_overrides, save_yaml
from hercs.learner.ddpg import DDPGLearner
from hercs.rl.task_registry import TaskSpec
from hercs.run.rundir import RunDir
from hercs.wire.batch import TransitionBatch

REPO = Path(__file__).resolve().parents[1]


def saved_run_config(run_dir: Path, overrides: list[str]) -> HercsConfig:
    """The config these overrides make, saved as `run_dir`'s config.yaml, as a run writes it."""
    config = apply_overrides(HercsConfig(), overrides)
    save_yaml(config, RunDir(run_dir).config)
    return config


class Clock:
    """A clock the test moves (`clock.now += seconds`), so that timeouts, retries and periods
    come without waiting for them."""

    def __init__(self, now: float = 100.0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


def sigterm_after_line(proc: subprocess.Popen[str], marker: str, timeout_s: float) -> str:
    """Reads `proc`'s stderr to the first line holding `marker`, then stops it with SIGTERM and
    asserts exit 0 within `timeout_s`; it is killed whatever happens. The line ("" where the
    stream ended first), for the test to check what it said."""
    found = ""
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            if marker in line:
                found = line
                break
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=timeout_s) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return found


def free_endpoint() -> str:
    """A Zenoh endpoint on loopback that nothing listens on right now."""
    return f"tcp/127.0.0.1:{free_port()}"


def wait_for_port(port: int, timeout_s: float = 20.0) -> None:
    """Until something accepts connections on 127.0.0.1:port (a server we just started)."""
    deadline = time.monotonic() + timeout_s
    while True:
        with socket.socket() as sock:
            if sock.connect_ex(("127.0.0.1", port)) == 0:
                return
        assert time.monotonic() < deadline, f"nothing listens on port {port}"
        time.sleep(0.1)


def rerun_binary() -> str:
    """The rerun executable itself (`.venv/bin/rerun` is a Python wrapper that forks it, so
    signals sent to the wrapper would not reach the viewer)."""
    import rerun_cli

    return str(Path(rerun_cli.__file__).parent / "rerun")


@contextmanager
def rerun_viewer(port: int, received: Path) -> Iterator[subprocess.Popen[bytes]]:
    """A real Rerun gRPC server on `port` standing in for a viewer, saving what it receives
    to `received`; on exit it is asked to end its file (SIGINT), killed if it hangs."""
    viewer = subprocess.Popen([rerun_binary(), "--bind", "127.0.0.1", "--port", str(port),
                               "--save", str(received)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_for_port(port)
        yield viewer
    finally:
        stop_process(viewer, signal.SIGINT, grace_s=10)


def load_module(name: str) -> ModuleType:
    """A benchmark's or a study's module by its dotted name (`bench.perf.learner`,
    `studies.claims.claims`): neither folder is installed, so tests import them from the
    checkout."""
    return importlib.import_module(name)


def quick_report(module: str, name: str, out: Path) -> tuple[dict[str, Any], str]:
    """Run `python -m module --quick --out out` in the checkout (failing the test with its
    stderr's end if it fails) and return its report: `name`.json's summary and `name`.md."""
    done = subprocess.run([sys.executable, "-m", module, "--quick", "--out", str(out)],
                          cwd=REPO, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads((out / f"{name}.json").read_text()), (out / f"{name}.md").read_text()


def random_transition_batch(spec: TaskSpec, b: int, seed: int) -> TransitionBatch:
    """A minibatch of `b` random transitions of `spec`'s shapes (rewards 0 or −1), from `seed`."""
    rng = np.random.default_rng(seed)
    return TransitionBatch(
        o=rng.normal(size=(b, spec.obs_dim)).astype(np.float32),
        g=rng.normal(size=(b, spec.goal_dim)).astype(np.float32),
        u=rng.uniform(-spec.max_action, spec.max_action,
                      size=(b, spec.action_dim)).astype(np.float32),
        r=-(rng.random(b) < 0.7).astype(np.float32),
        o2=rng.normal(size=(b, spec.obs_dim)).astype(np.float32),
    )


def update_losses(learner: DDPGLearner, batch: TransitionBatch) -> dict[str, float]:
    """One DDPG update as the training loop makes it (`train`) and its losses read back
    (`loss_means`, over that one update)."""
    learner.train(batch)
    return learner.loss_means()


def skip_without_mujoco_py() -> None:
    """Skip, saying why, where the authors' Fetch*-v1 cannot run (no `make mujoco-py`)."""
    import pytest

    from hercs.rl.envs import mujoco_py_problem

    problem = mujoco_py_problem()
    if problem is not None:
        pytest.skip(f"Fetch*-v1 needs mujoco-py and {problem}; `make mujoco-py` installs it")


def reset_and_check_spec(spec, env) -> dict:  # type: ignore[no-untyped-def]
    """Reset `env` (seed 0) and assert it has `spec`'s id, shapes, action size and horizon;
    returns the first observation."""
    assert env.spec is not None and env.spec.id == spec.env_id
    obs, _ = env.reset(seed=0)
    assert obs["observation"].shape == (spec.obs_dim,)
    assert obs["achieved_goal"].shape == obs["desired_goal"].shape == (spec.goal_dim,)
    assert env.action_space.shape == (spec.action_dim,)
    assert env.spec.max_episode_steps == spec.episode_steps
    return obs

