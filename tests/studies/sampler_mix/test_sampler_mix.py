"""studies/sampler_mix/sampler_draws.py: the effective share by hand, and a real run's log read back
(a 1-epoch `hercs sweep --quick` run of HER-CS), also by studies.authors_peer.acted_episodes."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.support import load_module

REPO = Path(__file__).resolve().parents[3]
sm = load_module("studies.sampler_mix.sampler_draws")


def test_effective_share_is_one_for_an_even_draw_and_small_for_a_repeated_one() -> None:
    size, n = 10, 100
    # every episode drawn equally often: Σc² = n²/size, so (Σc)²/Σc² = size; a uniform
    # random draw expects n²/(n + n(n−1)/size) = 10000/1090 distinct-equivalents
    even = np.repeat(np.arange(size), n // size)
    assert sm.effective_share(even, size) == pytest.approx(size / (10000 / 1090))
    # one episode drawn n times: one distinct-equivalent
    assert sm.effective_share(np.zeros(n, np.int64), size) == pytest.approx(1 / (10000 / 1090))


@pytest.mark.integration
def test_a_real_runs_log_is_read_back_one_row_per_epoch_mark(tmp_path: Path) -> None:
    made = subprocess.run([sys.executable, "-m", "hercs.apps.cli", "sweep", "--quick",
                           "--methods", "her-cs", "--seeds", "1", "--run-dir",
                           str(tmp_path / "runs")], capture_output=True, text=True,
                          timeout=300, cwd=REPO)
    assert made.returncode == 0, made.stdout + made.stderr
    mix = subprocess.run([sys.executable, "-m", "studies.sampler_mix",
                          str(tmp_path / "runs" / "reach-her-cs-s1"), "--every-epochs", "1",
                          "--minibatches", "4"], capture_output=True, text=True, timeout=120,
                         cwd=REPO)
    assert mix.returncode == 0, mix.stderr
    rows = [line for line in mix.stdout.splitlines() if line.startswith("| 1 |")]
    assert len(rows) == 1, mix.stdout
    # no cluster model yet in so short a run: both samplers draw uniformly, spread ≈ 1
    spread = [float(x) for x in rows[0].rstrip(" |").rsplit("|", 1)[1].split("/")]
    assert all(0.9 < x < 1.1 for x in spread), rows[0]
    # the same log, read by studies.authors_peer.acted_episodes: one row per epoch of each kind
    acted = subprocess.run([sys.executable, "-m", "studies.authors_peer.acted_episodes",
                            str(tmp_path / "runs" / "reach-her-cs-s1"), "--block", "1",
                            "--out", str(tmp_path / "acted")], capture_output=True, text=True,
                           timeout=120, cwd=REPO)
    assert acted.returncode == 0, acted.stderr
    blocks = json.loads((tmp_path / "acted" / "acted_episodes.json").read_text())["runs"]
    assert len(blocks["reach-her-cs-s1"]) == 1
    assert all(0.0 <= share <= 1.0 for share in blocks["reach-her-cs-s1"][0].values())
