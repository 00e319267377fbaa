"""bench/perf/workers_e2e.py: a real `hercs up --workers 2` run is measured as the schedule says (N×
the episodes, the same updates per epoch), specs are checked, and the committed device report
is what its metrics files give."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from bench.perf.workers_e2e import Spec, main, ratios, runs_from_dir, summarise
from hercs import read_metrics
from tests.support import REPO

COMMITTED = REPO / "docs" / "results" / "workers_e2e"


@pytest.mark.full
def test_a_two_worker_run_takes_twice_the_episodes_through_the_same_updates(
        tmp_path: Path) -> None:
    # 5 cycles per epoch (--quick): 2 workers × 4 episodes and 40 updates per cycle.
    assert main(["--spec", "2:cpu:1", "--quick", "--timeout", "240", "--out", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "workers_e2e.json").read_text())
    (run,) = result["runs"]
    assert (run["workers"], run["device"], run["epochs"]) == (2, "cpu", 1)
    # The epoch's 200 updates need its 40 episodes; the actors may run ahead of the updates
    # by what the rate limiter tolerates (at most training.max_policy_lag = 3 cycles).
    assert 2 * 4 * 5 <= run["episodes_per_epoch"] <= 2 * 4 * (5 + 3)
    rows = read_metrics(tmp_path / "w2-cpu-metrics.csv").rows
    assert int(rows[-1]["updates"]) == 40 * 5
    assert run["episodes_per_s"] > 0 and run["updates_per_s"] > 0
    assert "| w2-cpu | 2 | cpu | 1 |" in (tmp_path / "workers_e2e.md").read_text()


@pytest.mark.parametrize("text", ["8:cpu", "0:cpu:1", "2:tpu:1", "x:cuda:1", "2:cuda:0"])
def test_a_malformed_spec_is_refused_with_its_text(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match=text):
        Spec.parse(text)


def test_a_spec_may_name_a_cuda_index() -> None:
    assert Spec.parse("4:cuda:1:3") == Spec(4, "cuda:1", 3)


def test_epoch_times_come_from_the_cumulative_wall_clock() -> None:
    rows = [{"wall_s": "30", "episodes": "200", "updates_per_s": "80", "policy_lag_p50": "2",
             "policy_lag_p95": "3"},
            {"wall_s": "40", "episodes": "400", "updates_per_s": "100", "policy_lag_p50": "1",
             "policy_lag_p95": "2"},
            {"wall_s": "52", "episodes": "600", "updates_per_s": "90", "policy_lag_p50": "1",
             "policy_lag_p95": "2"}]
    s = summarise("w1-cpu", 1, "cpu", rows)
    assert (s.epoch_s, s.episodes_per_epoch, s.episodes_per_s) == (12.0, 200, 16.67)
    assert (s.updates_per_s, s.lag_p50, s.lag_p95) == (90.0, 1.0, 2.0)
    with pytest.raises(ValueError, match="no finished epoch"):
        summarise("w1-cpu", 1, "cpu", [])


@pytest.mark.docs_check
def test_the_committed_device_report_is_what_its_metrics_give() -> None:
    committed = json.loads((REPO / "docs" / "results" / "workers_e2e.json").read_text())
    runs = runs_from_dir(COMMITTED)
    assert [r.name for r in runs] == [r["name"] for r in committed["runs"]]
    assert ratios(runs) == committed["ratios"]
    by_name = {r.name: r for r in runs}
    # What the device run showed: 8 workers move ~8x the episodes per epoch, and the GPU
    # learner keeps an 8-worker epoch within 2x a 1-worker one where the CPU's takes ~5x.
    assert by_name["w8-cuda"].episodes_per_epoch == 8 * by_name["w1-cuda"].episodes_per_epoch
    assert by_name["w8-cuda"].epoch_s < 2 * by_name["w1-cuda"].epoch_s
    assert by_name["w8-cpu"].epoch_s > 4 * by_name["w1-cpu"].epoch_s
