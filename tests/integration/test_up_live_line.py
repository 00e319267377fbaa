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
from pathlib import Path

import pytest

from tests.support import free_endpoint

pytestmark = [pytest.mark.integration, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[2]


def test_a_run_on_a_terminal_shows_its_cycles_steps_and_updates(tmp_path: Path) -> None:
    master, slave = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "hercs.apps.cli", "up", "--task", "reach", "--run", "tty",
         "--run-dir", str(tmp_path / "runs"), "--listen", free_endpoint(), "--epochs", "2",
         "--actors", "1", "--set", "training.cycles_per_epoch=4",
         "--set", "training.eval_episodes=2"],
        cwd=tmp_path, stdout=slave, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL,
        env=dict(os.environ, PYTHONPATH=str(REPO), COLUMNS="200"))
    os.close(slave)
    screen: list[bytes] = []

    def read() -> None:
        while True:
            try:
                chunk = os.read(master, 65536)
            except OSError:  # EIO: every writer has closed the pty
                return
            if not chunk:
                return
            screen.append(chunk)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        _, err = proc.communicate(timeout=240)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    reader.join(30)
    os.close(master)
    text = b"".join(screen).decode(errors="replace")
    assert proc.returncode == 0, text + err.decode()
    # each epoch's first cycle is always drawn, and the run's last (hercs/apps/launch/supervisor.py)
    for epoch, cycle in ((1, 1), (2, 1), (2, 4)):
        assert re.search(rf"epoch {epoch}/2  cycle {cycle}/4  env \d+ steps  updates \d+",
                         text), text
    for epoch in (1, 2):  # the epoch lines themselves, above the live line, once each
        assert len(re.findall(rf"epoch {epoch}/2  success \d\.\d\d", text)) == 1, text
    assert "hercs up: run tty finished" in text
