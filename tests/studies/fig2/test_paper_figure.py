"""studies/fig2: the command is `hercs plot --figure 2` (a run of the old lag default kept apart
and labelled by its settings), and refuses a folder that is not there."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from hercs.run.rundir import RunDir
from studies.fig2.paper_figure import main
from tests.support import REPO


def _run(root: Path, name: str, seed: int, legacy: bool) -> None:
    run = root / name
    run.mkdir(parents=True)
    config = {"run": {"method": "her-cs", "seed": seed}, "task": {"name": "push"},
              "replay": {"rate_tolerance_updates": 80}}
    if not legacy:
        config["learner"] = {"prefetch_depth": 0}
        config["replay"] = {"rate_tolerance_updates": 40}
        config["actor"] = {"insert_queue": 0}
        config["training"] = {"max_policy_lag": 3}
    RunDir(run).config.write_text(yaml.safe_dump(config))
    rows = ["epoch,success_rate"] + [f"{e},{min(1.0, e / 20)}" for e in range(1, 31)]
    RunDir(run).metrics.write_text("\n".join(rows) + "\n")


@pytest.mark.slow  # draws a 2 x 3 figure
def test_the_figure_and_its_tables_keep_the_legacy_runs_apart(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    _run(runs, "push-her-cs-s1", 1, legacy=True)
    _run(runs, "push-her-cs-s2", 2, legacy=False)
    figure, table = tmp_path / "fig2.png", tmp_path / "fig2.md"
    assert main(["--runs", str(runs), "-o", str(figure), "--table", str(table)]) == 0
    text = table.read_text()
    assert figure.stat().st_size > 10_000
    assert "Drawn by `hercs plot --figure 2`" in text and "lag bound, prefetch, actor queue" in text
    assert ("| HER-CS, no lag bound, prefetch 3, actor queue 2, rate tolerance 80 (ours) | 1 |"
            in text and "| HER-CS (ours) | 1 |" in text)


def test_a_missing_runs_folder_is_refused(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "studies.fig2", "--runs", str(tmp_path / "no")],
                          cwd=REPO, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "not a directory" in done.stderr
