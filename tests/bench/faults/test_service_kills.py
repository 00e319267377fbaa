"""bench/faults/service_kills.py: its quick mode end to end (a real `hercs up` whose actor is
SIGKILLed after epoch 1 and restarted) and its report; no timing is asserted."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support import load_module

REPO = Path(__file__).resolve().parents[3]
faults = load_module("bench.faults.service_kills")

pytestmark = [pytest.mark.integration, pytest.mark.timeout(600)]


@pytest.mark.full
def test_quick_mode_kills_an_actor_and_loses_nothing(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "bench.faults.service_kills", "--quick",
                           "--out", str(tmp_path)],
                          cwd=REPO, capture_output=True, text=True, timeout=540)
    assert done.returncode == 0, done.stdout + done.stderr
    (row,) = json.loads((tmp_path / "faults.json").read_text())
    assert row["fault"] == "actor" and row["ok"]
    assert row["epochs_recorded"] == [1, 2, 3, 4, 5, 6]
    assert row["acked_before_kill"] > 0 and row["lost"] == 0
    assert row["restarted_after_s"] > 0 and row["next_epoch_after_s"] > 0
    table = (tmp_path / "faults.md").read_text()
    assert "| actor | 0 |" in table and "| ok |" in table


def test_a_run_that_lost_an_epoch_is_not_ok() -> None:
    result = faults.FaultResult(fault="learner", exit_status=0, epochs_expected=4,
                                epochs_recorded=[1, 2, 2, 4], acked_before_kill=10, lost=0,
                                restarted_after_s=1.0, next_epoch_after_s=5.0,
                                median_epoch_s=4.0, wall_s=60.0)
    assert (result.epochs_lost, result.epochs_twice, result.ok) == (1, 1, False)
