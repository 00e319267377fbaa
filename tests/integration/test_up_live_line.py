"""`hercs up` on a terminal (a real pty) draws a live line of the running epoch: its cycles,
env steps and updates, from the learner's RunProgress; in a log (a pipe) there is none, and the
lines stay one per epoch (test_launcher_services.py's end-to-end run checks that)."""

from __future__ import annotations

import os
import pty
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from hercs.apps.launch.launcher import READY_TIMEOUT_S
from hercs.run.rundir import RunDir

pytestmark = [pytest.mark.integration, pytest.mark.slow,
              pytest.mark.timeout(1800)]  # beyond hercs up's own stall bound: see SILENT_S

REPO = Path(__file__).resolve().parents[2]
SILENT_S = READY_TIMEOUT_S + 60
"""Seconds without a byte on the terminal after which hercs up is taken as hung. The run's
length has no bound here: a slow run is hercs up's own stall watchdog's to judge (no epoch's
end for launch.stall_factor times its slowest epoch, or 10 x the 64 s this config's first
epoch should take at most, exits 5 naming what stood still), and this run took 45 s on a free
core, 140 s beside the training grid and 207 s on 0.15 of a core. What the test watches is
the launcher itself: it redraws the live line every second once the run is running, and its
longest wait without a line is the replay's start (READY_TIMEOUT_S)."""


def service_logs(run_dir: Path, lines: int = 40) -> str:
    """The end of each service's log: CI keeps only the test's output, and a run that failed
    on a slow machine is explained by its services' last words."""
    tails = []
    for log in sorted(RunDir(run_dir).logs.glob("*.log")):
        text = log.read_text(errors="replace").splitlines()[-lines:]
        tails.append(f"--- {log.name} (last {len(text)} lines)\n" + "\n".join(text))
    return "\n".join(tails)


@pytest.mark.full
def test_a_run_on_a_terminal_shows_its_cycles_steps_and_updates(tmp_path: Path) -> None:
    master, slave = pty.openpty()
    stderr_path = tmp_path / "stderr.txt"
    # the router's port is hercs up's to pick (listen's default, tcp/127.0.0.1:0, picked again
    # if another process takes it first), not one picked here that may be taken meanwhile
    with stderr_path.open("wb") as stderr:
        proc = subprocess.Popen(
            [sys.executable, "-m", "hercs.apps.cli", "up", "--task", "reach", "--run", "tty",
             "--run-dir", str(tmp_path / "runs"), "--epochs", "2", "--actors", "1",
             "--set", "training.cycles_per_epoch=4", "--set", "training.eval_episodes=2"],
            cwd=tmp_path, stdout=slave, stderr=stderr, stdin=subprocess.DEVNULL,
            env=dict(os.environ, PYTHONPATH=str(REPO), COLUMNS="200"))
    os.close(slave)
    screen: list[bytes] = []
    last_output = [time.monotonic()]

    def read() -> None:
        while True:
            try:
                chunk = os.read(master, 65536)
            except OSError:  # EIO: every writer has closed the pty
                return
            if not chunk:
                return
            screen.append(chunk)
            last_output[0] = time.monotonic()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    hung = False
    try:
        while proc.poll() is None and not hung:
            try:
                proc.wait(timeout=1.0)
            except subprocess.TimeoutExpired:
                hung = time.monotonic() - last_output[0] > SILENT_S
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    reader.join(30)
    os.close(master)
    text = b"".join(screen).decode(errors="replace")
    said = f"{text}\n{stderr_path.read_text(errors='replace')}\n" + service_logs(
        tmp_path / "runs" / "tty")
    assert not hung, f"hercs up printed nothing for {SILENT_S:g} s:\n{said}"
    assert proc.returncode == 0, f"hercs up exited {proc.returncode}:\n{said}"
    # each epoch's first cycle is always drawn, and the run's last (hercs/apps/launch/supervisor.py)
    for epoch, cycle in ((1, 1), (2, 1), (2, 4)):
        assert re.search(rf"epoch {epoch}/2  cycle {cycle}/4  env \d+ steps  updates \d+",
                         text), text
    for epoch in (1, 2):  # the epoch lines themselves, above the live line, once each
        assert len(re.findall(rf"epoch {epoch}/2  success \d\.\d\d", text)) == 1, text
    assert "hercs up: run tty finished" in text
