"""The `[sweep]` line: cells done, running and left, and the time left at the pace of the runs
this call finished (hercs/apps/sweep/tally.py)."""

from __future__ import annotations

import pytest

from hercs.apps.sweep.tally import SweepTally


def test_before_any_run_ends_the_line_counts_and_says_when_an_eta_comes() -> None:
    tally = SweepTally(total=12, jobs=2, done=3)  # 3 finished by an earlier call
    assert tally.line(left=7, running_s=[10.0, 5.0]) == (
        "[sweep] 3 of 12 done, 2 running, 7 left; eta once the first run ends")


def test_the_eta_is_the_mean_run_for_each_cell_left_less_what_the_running_did() -> None:
    tally = SweepTally(total=6, jobs=2)
    tally.finished(600.0, resumed=False)
    tally.finished(1200.0, resumed=False)  # mean 900 s
    tally.finished(30.0, resumed=True)  # a resumed run's rest: not the pace of a whole run
    # 2 left: 1800 s; running 300 s and 1000 s in: 600 + 0 more; 2 at a time
    assert tally.eta_s(left=2, running_s=[300.0, 1000.0]) == pytest.approx(1200.0)
    assert tally.line(left=2, running_s=[300.0, 1000.0]) == (
        "[sweep] 3 of 6 done, 2 running, 2 left; eta 20m00s (15m00s a run, 2 at a time)")
    # the last run alone is not sped up by the other job
    assert tally.eta_s(left=0, running_s=[300.0]) == pytest.approx(600.0)


def test_only_resumed_runs_finished_still_give_a_pace_and_failures_are_said() -> None:
    tally = SweepTally(total=3, jobs=1)
    tally.finished(120.0, resumed=True)
    tally.failed = 1
    assert tally.line(left=1, running_s=[]) == (
        "[sweep] 1 of 3 done, 0 running, 1 left (1 failed, resumed by the next call); "
        "eta 2m00s (2m00s a run, 1 at a time)")
    tally.finished(60.0, resumed=False)
    assert tally.line(left=0, running_s=[]) == (
        "[sweep] 2 of 3 done, 0 running, 0 left (1 failed, resumed by the next call)")
