"""`hercs sweep`: variants, the manifest, the report's statistics, the Slurm cells, and a killed
sweep resumed."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hercs.apps.sweep import cells as sc
from hercs.apps.sweep import grid as se
from hercs.apps.sweep import report as sr
from hercs.apps.sweep import stats as sweep_stats
from hercs.errors import ConfigError
from hercs.run.rundir import RunDir
from tests.support import REPO
from tests.unit.apps.sweep_runs import finished_run

# ------------------------------------------------------------------ variants and manifest

def test_a_variant_is_an_arm_of_its_own_named_and_launched_with_its_overrides() -> None:
    name, items = sc.parse_variant("lr5e-4:ddpg.lr_actor=5e-4, ddpg.lr_critic=5e-4")
    assert (name, items) == ("lr5e-4", ("ddpg.lr_actor=5e-4", "ddpg.lr_critic=5e-4"))
    cells = sc.plan_grid(["push"], ["her", "her-cs"], [1, 2], variants=[("", ()), (name, items)])
    assert [c.name for c in cells] == [
        "push-her-s1", "push-her-cs-s1", "push-her-lr5e-4-s1", "push-her-cs-lr5e-4-s1",
        "push-her-s2", "push-her-cs-s2", "push-her-lr5e-4-s2", "push-her-cs-lr5e-4-s2"]
    assert cells[2].arm == "push-her-lr5e-4" and sr.arm_key(cells[2]) == "her/lr5e-4"
    cmd = sc.up_command(cells[2], epochs=1, run_root=Path("/r"), port=1, actors=1,
                        overrides=["ddpg.polyak=0.9"])
    sets = [cmd[i + 1] for i, arg in enumerate(cmd) if arg == "--set"]
    assert sets[-3:] == ["ddpg.lr_actor=5e-4", "ddpg.lr_critic=5e-4", "ddpg.polyak=0.9"]
    plain = sc.up_command(cells[0], epochs=1, run_root=Path("/r"), port=1, actors=1,
                          overrides=[])
    assert not any("lr_actor" in a for a in plain)


@pytest.mark.parametrize("text, why", [
    ("lr", "give NAME:FIELD=VALUE"), ("lr:", "give NAME:FIELD=VALUE"),
    ("lr:ddpg.lr_actor", "give NAME:FIELD=VALUE"), ("Big:ddpg.lr_actor=1", "lower-case"),
    ("s2:ddpg.lr_actor=1", "or a seed"),
])
def test_a_malformed_variant_is_refused_with_what_to_write(text: str, why: str) -> None:
    with pytest.raises(ConfigError, match=why):
        sc.parse_variant(text)


def test_bad_variants_stop_the_sweep_before_any_run(capsys: pytest.CaptureFixture[str],
                                                    tmp_path: Path) -> None:
    base = ["--report-only", "--tasks", "push", "--run-dir", str(tmp_path / "r")]
    assert se.main([*base, "--variant", "lr:ddpg.lr_actor=fast"]) == 2
    assert "ddpg.lr_actor: got 'fast', must be a number" in capsys.readouterr().err
    assert se.main([*base, "--variant", "a:ddpg.polyak=0.9", "--variant", "a:ddpg.polyak=0.8"]
                   ) == 2
    assert "two --variant arms have one name" in capsys.readouterr().err
    assert se.main([*base, "--no-plain"]) == 2
    assert not (tmp_path / "r").exists()


def test_the_manifest_says_where_every_cell_stands_and_the_report_reads_it(
        tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    cells = sc.plan_grid(["push"], ["her", "her-cs"], [1, 2])
    for cell, success in zip(cells[:3], ([0.1] * 12, [0.9] * 12, [0.3] * 12), strict=True):
        finished_run(runs, cell, success)
    path = sc.write_manifest(runs, cells, {cells[3]: "running"}, command="hercs sweep x",
                             epochs=12, committed=None)
    manifest = json.loads(path.read_text())
    assert [(c["name"], c["state"]) for c in manifest["cells"]] == [
        ("push-her-s1", "done"), ("push-her-cs-s1", "done"), ("push-her-s2", "done"),
        ("push-her-cs-s2", "running")]
    assert manifest["cells"][0]["commit"] == "abc" and manifest["command"] == "hercs sweep x"
    again, _ = sc.read_manifest(runs)
    assert again == cells
    assert sr.main_report([str(runs), "--out", str(tmp_path / "out"), "--reps", "200",
                           "--compare", "HER-CS", "HER"]) == 0
    text = (tmp_path / "out" / "push.md").read_text()
    # HER-CS's one run (.90) beats both of HER's (.10, .30): P = 1 in every resample
    assert "| HER-CS | 1 | .90 [.90, .90] | .90 [.90, .90] | 1.00 [1.00, 1.00] |" in text
    assert "| HER | 2 | .20 [.10, .30] | .20 [.10, .30] | – |" in text
    assert "- P(HER-CS > HER) = 1.00 [1.00, 1.00]" in text
    assert "- not finished yet: push-her-cs-s2" in text
    with pytest.raises(ConfigError, match="no sweep here"):
        sc.read_manifest(tmp_path)


# ------------------------------------------------------------------------ its statistics

@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 7, 8, 20])
def test_the_iqm_and_probability_of_improvement_equal_rliables(n: int) -> None:
    from rliable import metrics

    rng = np.random.default_rng(n)
    x, y = rng.random(n), np.round(rng.random(n + 2), 1)
    assert sweep_stats.iqm(x) == pytest.approx(metrics.aggregate_iqm(x[:, None]), abs=1e-12)
    assert sweep_stats.probability_of_improvement(x, y) == pytest.approx(
        metrics.probability_of_improvement(x[:, None], y[:, None]), abs=1e-12)


def test_bootstrap_intervals_by_hand() -> None:
    """Four runs 0, 0, 0, 1: resampled means are k/4, P(k >= 3) = 5.1 % and P(k = 4) = .4 %,
    so the 97.5th percentile is .75 and, with P(k = 0) = 32 %, the 2.5th is 0."""
    mean = sweep_stats.bootstrap([0, 0, 0, 1], np.mean, reps=4000)
    assert (mean.value, mean.low, mean.high) == (0.25, 0.0, 0.75)
    apart = sweep_stats.improvement([0.9, 0.8], [0.1, 0.2], reps=500)
    assert (apart.value, apart.low, apart.high) == (1.0, 1.0, 1.0)
    assert sweep_stats.Interval(0.5, 0.25, 1.0).format() == ".50 [.25, 1.00]"


@pytest.mark.parametrize("name", ["cs", "ebp-cs", "v1", "lockstep", "bf16", "ts4", "eps3"])
def test_a_variant_may_not_take_a_name_the_runs_naming_uses(name: str) -> None:
    # `her` + variant `cs` would be named like a her-cs run: push-her-cs-s1
    with pytest.raises(ConfigError, match="one hercs gives runs itself"):
        sc.parse_variant(f"{name}:ddpg.polyak=0.9")


def test_repeated_tasks_and_methods_are_one_arm_each(capsys: pytest.CaptureFixture[str],
                                                     tmp_path: Path) -> None:
    assert se.main(["--report-only", "--tasks", "push", "push", "--methods", "her", "her",
                    "--seeds", "1", "--run-dir", str(tmp_path / "r")]) == 0
    assert "sweep: 1 runs (push × her × 1 arm × seed 1)" in capsys.readouterr().out


def test_manifest_writers_at_once_never_fail_or_leave_half_a_file(tmp_path: Path) -> None:
    """Slurm array tasks write the manifest together: each through a temporary file of its
    own and an atomic rename."""
    import threading

    cells = sc.plan_grid(["push"], ["her", "her-cs"], [1, 2, 3])
    errors: list[BaseException] = []

    def write() -> None:
        try:
            for _ in range(30):
                sc.write_manifest(tmp_path, cells, {}, command="x", epochs=1, committed=None)
                json.loads((tmp_path / sc.MANIFEST).read_text())  # always whole
        except BaseException as exc:  # collected for the assertion
            errors.append(exc)

    threads = [threading.Thread(target=write) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    assert [p.name for p in tmp_path.iterdir()] == [sc.MANIFEST]  # no temporary file left


def test_the_slurm_cells_keep_the_tasks_in_the_order_given() -> None:
    """The array's --cell-index values are the submitter's indices: the task's command must
    plan the same cells in the same order."""
    import argparse

    from hercs.apps.sweep.slurm_array import cell_command

    args = argparse.Namespace(methods=["her"], seeds=1, first_seed=3, schedule="async",
                              precision="fp32",
                              env_version="v4", weld_torquescale=1.0, energy_epsilon=1e-6,
                              actors=1, variants=[], no_plain=False)
    cmd = cell_command(args, ["reach", "push"], run_root=Path("/r"), committed=None, epochs=1,
                       overrides=[])
    assert cmd[cmd.index("--tasks") + 1:cmd.index("--tasks") + 3] == ["reach", "push"]
    assert cmd[cmd.index("--first-seed") + 1] == "3"  # the task plans the submitter's seeds


@pytest.mark.full
@pytest.mark.integration
@pytest.mark.slow
def test_a_killed_sweep_stops_its_runs_in_order_and_the_next_call_resumes_them(
        tmp_path: Path) -> None:
    """SIGTERM to the sweep (its runs are in sessions of their own, out of its reach
    otherwise): each run stops in order, the manifest says so, nothing is left running, and
    the same command continues the run from its checkpoint."""
    import signal
    import time

    cmd = [sys.executable, "-m", "hercs.apps.cli", "sweep", "--quick", "--methods", "her",
           "--seeds", "1", "--epochs", "100", "--run-dir", str(tmp_path / "runs")]
    sweep = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                             text=True)
    metrics = RunDir(tmp_path / "runs" / "reach-her-s1").metrics
    deadline = time.monotonic() + 300
    # the learner's first row: the run is training (a file has no event to await)
    while not (metrics.is_file() and len(metrics.read_text().splitlines()) >= 2):
        assert sweep.poll() is None and time.monotonic() < deadline, sweep.stdout.read()
        time.sleep(0.2)
    sweep.send_signal(signal.SIGTERM)
    out, _ = sweep.communicate(timeout=180)
    assert sweep.returncode == 130, out
    assert "hercs sweep: stopped; the same command resumes it" in out
    manifest = json.loads((tmp_path / "runs" / sc.MANIFEST).read_text())
    assert manifest["cells"][0]["state"] == "stopped (resumed by the next call)"
    log = (tmp_path / "runs" / "_logs" / "reach-her-s1.log").read_text()
    assert "hercs up: got SIGTERM, stopping the run" in log and "stopped; run directory" in log
    kept = len(metrics.read_text().splitlines()) - 1
    assert 1 <= kept < 100
    again = subprocess.run([*cmd[:-4], "--epochs", str(kept + 1), *cmd[-2:]], cwd=REPO,
                           capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stdout + again.stderr
    assert "[resume] reach-her-s1" in again.stdout
    epochs = [int(line.split(",")[0]) for line in metrics.read_text().splitlines()[1:]]
    # the kept epochs, then more to the new end, none twice. The learner may have trained
    # past the last row before the stop (a row waits for its epoch's evaluation, and these
    # epochs take well under a second): the resumed learner then asks for those evaluations
    # again and writes their rows, even past the new --epochs; nothing is trained twice.
    assert epochs == list(range(1, len(epochs) + 1)) and epochs[-1] >= kept + 1
