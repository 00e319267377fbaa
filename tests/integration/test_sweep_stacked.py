"""`hercs sweep --stacked` for real: a quick grid of two FetchReach runs in one wave, their
learners one `hercs learner-stack` process; both runs finish with every epoch recorded and
their done records, the stack's log names both, and the process stops with the wave."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from hercs.run.metrics import recorded_epochs
from hercs.run.rundir import RunDir

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.full]

REPO = Path(__file__).resolve().parents[2]
EPOCHS = 2


def test_a_stacked_sweep_trains_its_wave_with_one_learner_process(tmp_path: Path) -> None:
    root = tmp_path / "grid"
    done = subprocess.run(
        [sys.executable, "-m", "hercs.apps.cli", "sweep", "--quick", "--stacked", "--tasks",
         "reach", "--methods", "her", "her-cs", "--seeds", "1", "--jobs", "2", "--epochs",
         str(EPOCHS), "--run-dir", str(root)],
        cwd=REPO, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-3000:]
    assert done.stdout.count("[stack] learner-stack of 2 runs") == 1, done.stdout[-3000:]
    names = ["reach-her-s1", "reach-her-cs-s1"]
    for name in names:
        run = RunDir(root / name)
        assert recorded_epochs(run.metrics) == list(range(1, EPOCHS + 1)), name
        record = json.loads((root / name / "bench_done.json").read_text())
        assert record["epochs"] == EPOCHS and "launch.learner_elsewhere=true" in record["command"]
        assert not (run.logs / "learner-0.log").exists(), "its hercs up started a learner"
    stack_log = (root / "_logs" / "learner-stack-1.log").read_text()
    assert "learner stack of 2 runs" in stack_log and "ended (0)" in stack_log
