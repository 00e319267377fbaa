"""The router dies in the middle of a run and comes back on the same port: every service
reconnects by itself, evaluations lost during the outage are asked for again, and the run
finishes with every epoch recorded once. Real processes: `hercs router` and each service."""

from __future__ import annotations

import csv
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from hercs.run.rundir import RunDir
from tests.integration.services import ServiceProcess, make_test_config
from tests.support import free_endpoint

pytestmark = [pytest.mark.integration, pytest.mark.timeout(400)]

EPOCHS = 4
TIMEOUT_S = 240.0


def router(endpoint: str, log: Path) -> subprocess.Popen[bytes]:
    with log.open("ab") as out:
        return subprocess.Popen([sys.executable, "-m", "hercs.apps.cli", "router", "--listen",
                                 endpoint], stdout=out, stderr=subprocess.STDOUT)


def wait_until(condition: Callable[[], bool], what: str, timeout_s: float = TIMEOUT_S) -> None:
    """Polls `condition` (a file's contents: no event to await across processes)."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(0.2)


def epochs(metrics: Path) -> list[int]:
    if not metrics.exists():
        return []
    with metrics.open(newline="") as f:
        return [int(row["epoch"]) for row in csv.DictReader(f)]


@pytest.mark.full
def test_services_ride_out_a_router_restart(tmp_path: Path) -> None:
    endpoint = free_endpoint()
    config, path = make_test_config(tmp_path, endpoint, [
        "task.name=reach", "run.method=her-cs", f"training.epochs={EPOCHS}",
        "training.cycles_per_epoch=3", "training.eval_episodes=2", "cluster.fgb_size=20",
        "cluster.k=2", "training.eval_resend_s=2"])
    metrics = RunDir(Path(config.run.run_dir) / config.run.name).metrics
    first = router(endpoint, tmp_path / "router.log")
    services = [ServiceProcess(role, path, f"{role}-0", tmp_path)
                for role in ("replay", "clusterer", "learner", "evaluator", "actor")]
    learner = services[2]
    try:
        # epoch 1's row, however many rows have come with it (an evaluator running late
        # delivers two results at once); the router must go down before the run's end
        wait_until(lambda: 1 in epochs(metrics), "epoch 1's row")
        assert learner.proc.poll() is None and max(epochs(metrics)) < EPOCHS, epochs(metrics)
        first.send_signal(signal.SIGKILL)
        first.wait()
        second = router(endpoint, tmp_path / "router.log")
        try:
            assert learner.proc.wait(timeout=TIMEOUT_S) == 0, learner.log_text()[-3000:]
        finally:
            second.terminate()
            second.wait(timeout=30)
    finally:
        for service in services:
            if service.proc.poll() is None:
                service.stop()
    assert epochs(metrics) == list(range(1, EPOCHS + 1)), "every epoch once, none missing"
    for service in services:
        assert "Traceback" not in service.log_text(), service.service
