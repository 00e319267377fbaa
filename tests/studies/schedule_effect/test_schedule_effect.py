"""studies/schedule_effect/schedule_pairs.py: the statistics against scipy's t-tests, the pairing of
runs by schedule and precision on run folders written here, and the command line."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy import stats

from hercs.apps.plots.curves import load_run
from hercs.run.rundir import RunDir
from tests.support import load_module

effect = load_module("studies.schedule_effect.schedule_pairs")
REPO = Path(__file__).resolve().parents[3]


def _run(root: Path, name: str, seed: int, success: list[float], *, schedule: str = "async",
         precision: str = "fp32", commit: str = "abc1234") -> None:
    run = root / name
    run.mkdir()
    RunDir(run).config.write_text(yaml.safe_dump({
        "run": {"method": "her-cs", "seed": seed}, "task": {"name": "push"},
        "training": {"schedule": schedule}, "learner": {"precision": precision}}))
    rows = ["epoch,success_rate"] + [f"{e},{s}" for e, s in enumerate(success, start=1)]
    RunDir(run).metrics.write_text("\n".join(rows) + "\n")
    (run / "bench_done.json").write_text(json.dumps(
        {"commit": commit, "finished": "2026-11-25T10:52:07+00:00"}))


@pytest.mark.parametrize("lockstep, asynchronous", [
    ([0.82, 0.80, 0.85], [0.74, 0.96, 0.38, 0.11]),
    ([0.9, 0.7], [0.2, 0.3]),
    ([0.5, 0.52], [0.49, 0.6, 0.41]),
])
def test_welch_interval_excludes_zero_exactly_when_welchs_test_rejects(
        lockstep: list[float], asynchronous: list[float]) -> None:
    d = effect.difference(lockstep, asynchronous)
    p = stats.ttest_ind(lockstep, asynchronous, equal_var=False).pvalue
    assert d.value == pytest.approx(np.mean(lockstep) - np.mean(asynchronous))
    assert d.low < d.value < d.high
    assert d.resolved == (p < 0.05)
    assert d.rule.startswith("Welch")


def test_one_seed_on_a_side_is_the_pooled_t_test() -> None:
    """With one seed on a side the pooled variance is the other side's alone (the single seed
    has no degrees of freedom), so the interval is the classic pooled test's."""
    lockstep, asynchronous = [0.96], [0.89, 0.86, 0.74]
    d = effect.difference(lockstep, asynchronous)
    test = stats.ttest_ind(lockstep, asynchronous, equal_var=True)
    half = (d.high - d.low) / 2
    assert d.stderr == pytest.approx(d.value / test.statistic)
    assert half == pytest.approx(stats.t.ppf(0.975, 2) * d.stderr)
    assert d.resolved == (test.pvalue < 0.05)
    none = effect.difference([0.5], [0.7])
    assert none.stderr is None and none.resolved is None


def test_runs_pair_by_task_method_and_precision_at_their_last_common_epoch(
        tmp_path: Path) -> None:
    climb = [min(1.0, e / 20) for e in range(50)]
    _run(tmp_path, "push-her-cs-lockstep-s1", 1, climb, schedule="lockstep")
    _run(tmp_path, "push-her-cs-lockstep-s2", 2, climb[:45], schedule="lockstep")
    _run(tmp_path, "push-her-cs-s1", 1, [0.0] * 50, commit="def5678")
    _run(tmp_path, "push-her-cs-bf16-s1", 1, climb[:40], precision="bf16")  # no bf16 lockstep
    curves = [load_run(p) for p in sorted(tmp_path.iterdir())]
    [c] = effect.compare_all(curves, max_epoch=50)
    assert (c.task, c.method, c.epoch) == ("FetchPush", "her-cs", 45)
    assert [s.run for s in c.lockstep] == ["push-her-cs-lockstep-s1", "push-her-cs-lockstep-s2"]
    assert [(s.run, s.commit, s.success) for s in c.asynchronous] == [
        ("push-her-cs-s1", "def5678", 0.0)]
    # the trailing mean over epochs 36..45 of e/20 capped at 1 (epoch e holds climb[e - 1])
    expected = float(np.mean([min(1.0, (e - 1) / 20) for e in range(36, 46)]))
    assert c.lockstep[0].success == pytest.approx(expected)
    # the trailing mean at epoch e is (e - 5.5) / 20: past 0.5 first at epoch 16, i.e. 15
    # epochs completed before it (the tables' count)
    assert c.lockstep[0].at_half == 15 and c.asynchronous[0].at_half is None
    assert c.lockstep[0].finished == "2026-11-25 10:52"


def test_command_writes_the_report_and_refuses_a_bad_epoch(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    runs.mkdir()
    _run(runs, "push-her-cs-lockstep-s1", 1, [0.5] * 10, schedule="lockstep")
    _run(runs, "push-her-cs-s1", 1, [0.1] * 10)
    done = subprocess.run([sys.executable, "-m", "studies.schedule_effect", "--runs", str(runs),
                           "--out", str(tmp_path / "out")], capture_output=True, text=True,
                          timeout=60, cwd=REPO)
    assert done.returncode == 0, done.stderr
    text = (tmp_path / "out" / "asynchrony.md").read_text()
    assert "## FetchPush HER-CS: lockstep against asynchronous, epoch 10" in text
    assert "+.40; one seed on each side: no spread to use." in text
    bad = subprocess.run([sys.executable, "-m", "studies.schedule_effect", "--epoch", "0"],
                         capture_output=True, text=True, timeout=60, cwd=REPO)
    assert bad.returncode == 2 and "--epoch must be at least 1, got 0" in bad.stderr
