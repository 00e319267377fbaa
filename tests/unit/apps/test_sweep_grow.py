"""`hercs sweep` grown and reported (hercs/apps/sweep/: grid.py, runner.py, cells.py, report.py):
a finished cell trained on to a larger `--epochs` from its checkpoint; one that cannot be
refused; the report reading every arm at one epoch, naming the authors' curves only where
they exist, and refusing a `--compare` of an arm the sweep does not have."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from hercs.apps.sweep import cells as sc
from hercs.apps.sweep import runner as sweep_runner
from hercs.run.rundir import RunDir
from tests.support import REPO
from tests.unit.apps.sweep_runs import finished_run


def _hercs(*args: str, timeout_s: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hercs.apps.cli", *args], capture_output=True,
                          text=True, timeout=timeout_s, cwd=REPO)


@pytest.mark.full
@pytest.mark.integration
@pytest.mark.slow
def test_a_finished_cell_grows_to_a_larger_epochs_from_its_checkpoint(tmp_path: Path) -> None:
    """A real 1-epoch cell, then the same sweep with --epochs 2: the run goes on from its
    checkpoint (epoch 1's row kept as it was), its bench_done.json says 2 epochs, the epochs
    it had, the commit its first life started from, and the committed copy follows."""
    runs, committed = tmp_path / "runs", tmp_path / "committed"
    sweep = ["sweep", "--quick", "--methods", "her-cs", "--seeds", "1", "--run-dir", str(runs),
             "--out", str(tmp_path / "report"), "--committed", str(committed)]
    first = _hercs(*sweep, "--epochs", "1")
    assert first.returncode == 0, first.stdout + first.stderr
    run = runs / "reach-her-cs-s1"
    epoch_1 = RunDir(run).metrics.read_text().splitlines()
    assert len(epoch_1) == 2
    logs = runs / sweep_runner.LOG_DIR
    started = (logs / f"reach-her-cs-s1{sweep_runner.STARTED_SUFFIX}").read_text().strip()

    again = _hercs(*sweep, "--epochs", "1")  # as many epochs: nothing to do
    assert "[skip] reach-her-cs-s1: finished earlier" in again.stdout, again.stdout

    grown = _hercs(*sweep, "--epochs", "2")
    assert grown.returncode == 0, grown.stdout + grown.stderr
    assert ("[grow] reach-her-cs-s1: finished 1 epochs, continued from its checkpoint to 2"
            in grown.stdout), grown.stdout
    rows = RunDir(run).metrics.read_text().splitlines()
    assert rows[:2] == epoch_1, "epoch 1 was kept, not trained again"
    assert [row.split(",")[0] for row in rows[1:]] == ["1", "2"]
    done = json.loads((run / sc.DONE_FILE).read_text())
    assert (done["epochs"], done["grown_from_epochs"], done["resumed"]) == (2, 1, True)
    assert done["started_commit"] == started and "--resume" in done["command"]
    assert json.loads((committed / run.name / sc.DONE_FILE).read_text())["epochs"] == 2
    assert RunDir(committed / run.name).metrics.read_text().splitlines() == rows
    manifest = json.loads((runs / sc.MANIFEST).read_text())
    assert (manifest["epochs"], manifest["cells"][0]["state"]) == (2, "done")
    assert "Every arm is read at epoch 2," in (tmp_path / "report" / "reach.md").read_text()


def test_a_cell_finished_elsewhere_with_fewer_epochs_is_refused_not_passed_over(
        tmp_path: Path) -> None:
    """Its committed copy keeps no learner checkpoint: it cannot be grown here, and skipping
    it would leave the sweep short of what --epochs asks; nothing starts (exit 2)."""
    runs, committed = tmp_path / "runs", tmp_path / "committed"
    finished_run(committed, sc.GridRun("push", "her", 1), [0.1] * 3)
    done = _hercs("sweep", "--tasks", "push", "--methods", "her", "--seeds", "1",
                  "--epochs", "5", "--run-dir", str(runs), "--committed", str(committed))
    assert done.returncode == 2, done.stdout + done.stderr
    assert done.stderr.startswith(
        f"hercs sweep: --epochs 5: push-her-s1 (3 epochs, in {committed / 'push-her-s1'}) "
        "finished fewer epochs and keeps no learner checkpoint here"), done.stderr
    assert done.stderr.rstrip().endswith("or give --epochs 3"), done.stderr
    assert not (runs / "push-her-s1").exists()
    dry = _hercs("sweep", "--tasks", "push", "--methods", "her", "--seeds", "1",
                 "--epochs", "3", "--run-dir", str(runs), "--committed", str(committed),
                 "--dry-run")
    assert dry.returncode == 0 and "[skip] push-her-s1: finished" in dry.stdout, dry.stdout


def test_first_seed_adds_seeds_beside_ones_finished_elsewhere_with_fewer_epochs(
        tmp_path: Path) -> None:
    """A grid's longer second batch: seeds 2..3 start fresh beside a committed seed 1 that
    finished fewer epochs (which --seeds alone would refuse to grow)."""
    runs, committed = tmp_path / "runs", tmp_path / "committed"
    finished_run(committed, sc.GridRun("push", "her", 1), [0.1] * 3)
    dry = _hercs("sweep", "--tasks", "push", "--methods", "her", "--seeds", "2",
                 "--first-seed", "2", "--epochs", "5", "--run-dir", str(runs),
                 "--committed", str(committed), "--dry-run")
    assert dry.returncode == 0, dry.stdout + dry.stderr
    assert "push-her-s1" not in dry.stdout, dry.stdout
    assert "push-her-s2" in dry.stdout and "push-her-s3" in dry.stdout, dry.stdout
    bad = _hercs("sweep", "--tasks", "push", "--first-seed", "0", "--dry-run")
    assert bad.returncode == 2 and "--first-seed 0" in bad.stderr, bad.stderr


def test_a_dry_run_says_which_cells_would_grow(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    cell = sc.GridRun("push", "her", 1)
    finished_run(runs, cell, [0.1] * 3)
    RunDir(runs / cell.name).checkpoints.mkdir()
    RunDir(runs / cell.name).checkpoint("latest").write_bytes(b"a learner checkpoint")
    done = _hercs("sweep", "--tasks", "push", "--methods", "her", "--seeds", "1",
                  "--epochs", "5", "--run-dir", str(runs), "--dry-run")
    assert done.returncode == 0, done.stdout + done.stderr
    assert (f"[grow] push-her-s1: finished 3 epochs; continued from its checkpoint: hercs up "
            f"--resume {runs / cell.name} --epochs 5") in done.stdout, done.stdout


def test_the_report_reads_every_arm_at_one_epoch_and_names_it(tmp_path: Path) -> None:
    """HER ran 12 epochs, HER-CS 8: both are read after epoch 8 (HER's curve is cut there),
    in the milestone table too; the authors' Push curves are cut there as well."""
    runs = tmp_path / "runs"
    her, her_cs = sc.plan_grid(["push"], ["her", "her-cs"], [1])
    finished_run(runs, her, [0.2] * 8 + [1.0] * 4)
    finished_run(runs, her_cs, [0.6] * 8)
    sc.write_manifest(runs, [her, her_cs], {}, command="hercs sweep x", epochs=8,
                      committed=None)
    done = _hercs("sweep", "report", str(runs), "--out", str(tmp_path / "out"), "--reps", "200")
    assert done.returncode == 0, done.stdout + done.stderr
    text = (tmp_path / "out" / "push.md").read_text()
    assert ("Every arm is read at epoch 8, the last epoch every finished run reached; runs "
            "that went further are cut there (push-her-s1).") in text
    assert "against the authors' published per-seed results (dashed" in text
    table = [line for line in text.splitlines() if line.startswith("| HER")]
    assert table[0].startswith("| HER (ours) | 1 | 8 |") and table[0].endswith("| .20 |")
    assert table[1].startswith("| HER (authors) | 5 | 8 |")
    assert "| HER | 1 | .20 [.20, .20] |" in text  # the arms over seeds, after epoch 8


def test_a_task_the_authors_did_not_publish_is_reported_without_their_curves(
        tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    cells = sc.plan_grid(["reach"], ["her", "her-cs"], [1])
    for cell in cells:
        finished_run(runs, cell, [0.9, 1.0])
    sc.write_manifest(runs, cells, {}, command="hercs sweep x", epochs=2, committed=None)
    done = _hercs("sweep", "report", str(runs), "--out", str(tmp_path / "out"), "--reps", "200")
    assert done.returncode == 0, done.stdout + done.stderr
    text = (tmp_path / "out" / "reach.md").read_text()
    assert "authors' published" not in text and "dashed" not in text and "(ours)" not in text
    assert ("(the authors published per-seed results for FetchPickAndPlace, FetchPush, "
            "FetchSlide only: none for FetchReach)") in text
    assert "| HER | 1 | 2 |" in text


def test_compare_of_an_arm_not_in_the_sweep_is_refused_with_the_arms_there(
        tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    cells = sc.plan_grid(["push"], ["her", "her-cs"], [1])
    for cell in cells:
        finished_run(runs, cell, [0.5])
    sc.write_manifest(runs, cells, {}, command="hercs sweep x", epochs=1, committed=None)
    done = _hercs("sweep", "report", str(runs), "--out", str(tmp_path / "out"),
                  "--compare", "HER-EBP", "HER")
    assert done.returncode == 2, done.stdout + done.stderr
    assert done.stderr == (f"hercs sweep: --compare HER-EBP: no such arm in the sweep in {runs}; "
                           "its arms are HER, HER-CS (by key: her, her-cs)\n")
    assert not (tmp_path / "out").exists(), "refused before any report was written"
