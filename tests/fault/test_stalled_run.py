"""A run that stops moving says so and stops, whatever the cause: a real `hercs up` run of
FetchReach whose learner is frozen with SIGSTOP (alive, so never restarted, and silent) ends
with exit 5 within `launch.stall_factor` times its slowest epoch, naming what stalled, since
when, and where the logs are.

Every wait is on a launcher line or its exit, with a timeout sized from what the run measured.
"""

from __future__ import annotations

import os
import re
import signal
import sys
import time
from pathlib import Path

import pytest

from hercs.run.rundir import RunDir
from tests.integration.launcher_standins import Launcher, process_alive
from tests.support import free_endpoint

pytestmark = pytest.mark.integration

RUN_S = 240.0
FACTOR = 2
LAUNCHER_POLL_S = 1.0
"""How often the supervisor's loop looks (hercs.apps.launch.supervisor._POLL_S)."""
LATE_S = LAUNCHER_POLL_S + 4.0
"""How far past its bound a stall may be reported: one poll, and the scheduling of a busy
machine."""
ZENOH_LEASE_S = 10.0
"""A silent client's session, and so its liveliness token, goes after Zenoh's lease."""
STOP_S = 60.0
"""Stopping the services once the stall is reported: each stage may take its 10 s timeout."""

STALLED = re.compile(
    r"hercs up: run stuck stalled: no epoch has ended for (?P<quiet>\d+) s \(since epoch "
    r"(?P<epoch>\d+) ended\); the bound is launch\.stall_factor 2 x the slowest epoch so far, "
    r"(?P<slowest>[\d.]+) s; (?P<episodes>[^.]+)\. (?P<silent>Not seen alive on the router "
    r"\(stopped or hung\): [^.]+\. )?The services' logs are in (?P<logs>\S+); stopping the "
    r"run \(exit 5\)\.")


@pytest.mark.full
def test_a_run_whose_learner_is_frozen_stops_within_its_bound(tmp_path: Path) -> None:
    run_dir = tmp_path / "runs" / "stuck"
    started = time.monotonic()
    launcher = Launcher(
        [sys.executable, "-m", "hercs.apps.cli", "up", "--task", "reach", "--epochs", "20",
         "--actors", "1", "--run", "stuck", "--run-dir", str(tmp_path / "runs"),
         "--listen", free_endpoint(), "--set", "training.cycles_per_epoch=3",
         "--set", "training.eval_episodes=2", "--set", f"launch.stall_factor={FACTOR}"],
        cwd=tmp_path)
    try:
        launcher.wait_for_line(r"^epoch 2/20  success", timeout_s=RUN_S)
        # the slowest epoch is at most the time to here: the bound is at most twice that
        bound_at_most_s = FACTOR * (time.monotonic() - started)
        learner = launcher.child_pids["learner-0"]
        os.kill(learner, signal.SIGSTOP)
        frozen = time.monotonic()
        line = launcher.wait_for_line(r"stalled: ", timeout_s=bound_at_most_s + LATE_S)
        reported_after_s = time.monotonic() - frozen
        status = launcher.finish(timeout_s=STOP_S)
    finally:
        launcher.kill()
        if process_alive(learner):
            os.kill(learner, signal.SIGKILL)
    report = "\n".join(launcher.out + launcher.err)
    assert status == 5, report
    found = STALLED.search(line)
    assert found is not None, line
    bound_s = FACTOR * float(found["slowest"])
    assert int(found["quiet"]) >= int(bound_s), "not before its bound"
    assert reported_after_s <= bound_s + LATE_S, "within its bound of the freeze"
    assert int(found["epoch"]) >= 2
    assert Path(found["logs"]) == RunDir(run_dir).logs
    if reported_after_s > ZENOH_LEASE_S + LATE_S:  # its token had time to go
        assert "learner learner-0" in (found["silent"] or ""), line
    # the frozen learner was woken to handle its SIGTERM: stopped in order, not killed
    assert "learner-0 did not stop within" not in report
    assert not [i for i, pid in launcher.child_pids.items() if process_alive(pid)]
