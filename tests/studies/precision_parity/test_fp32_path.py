"""The parity study's fp32 arm may be the committed FetchPush v1 HER-CS runs, trained at earlier
commits than the bf16 arm: this checks that each of those commits' fp32 learners does the same
arithmetic as this tree's (studies/precision_parity/fp32_path.py)."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import tarfile
from pathlib import Path
from typing import Any

import pytest

from studies.precision_parity.fp32_path import compare, load

ROOT = Path(__file__).resolve().parents[3]
SCRIPT = ROOT / "studies" / "precision_parity" / "fp32_path.py"
ARM = "push-v1-her-cs-s*"
"""The fp32 arm: the Fig. 2 grid's Push v1 HER-CS runs."""


def arm_commits() -> list[str]:
    """The commits the committed fp32-arm runs trained at (a resumed one's first too)."""
    commits = set()
    for done in sorted((ROOT / "docs" / "results" / "runs").glob(f"{ARM}/bench_done.json")):
        record = json.loads(done.read_text())
        if record.get("precision", "fp32") == "fp32":
            commits |= {record[k] for k in ("commit", "started_commit") if record.get(k)}
    return sorted(commits)


def path_of(tree: Path, out: Path) -> dict[str, Any]:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    subprocess.run([sys.executable, str(SCRIPT), "--out", str(out)], cwd=tree, env=env,
                   check=True, timeout=600)
    return load(out)


def git(*args: str) -> subprocess.CompletedProcess[bytes]:
    return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, check=False)


@pytest.mark.docs_check
def test_docs_check_the_fp32_arms_commits_train_as_this_tree_does(tmp_path: Path) -> None:
    commits = arm_commits()
    assert len(commits) >= 4, f"the fp32 arm's commits: {commits}"
    if git("rev-parse", "--git-dir").returncode != 0:
        pytest.skip("SKIPPED: not a git checkout, so the arm's commits cannot be read")
    here = path_of(ROOT, tmp_path / "here.npz")
    for commit in commits:
        tree = tmp_path / commit
        tree.mkdir()
        # The service packages were top-level before they moved under hercs/.
        archive = git("archive", "--format=tar", commit, "hercs", "learner")
        if archive.returncode != 0:
            archive = git("archive", "--format=tar", commit, "hercs")
        assert archive.returncode == 0, f"{commit}: {archive.stderr.decode()}"
        with tarfile.open(fileobj=io.BytesIO(archive.stdout)) as tar:
            tar.extractall(tree, filter="data")
        equal, worst = compare(here, path_of(tree, tmp_path / f"{commit}.npz"))
        assert equal, (f"{commit}'s fp32 learner differs from this tree's after 100 updates "
                       f"(largest difference {worst:.2e} of the largest weight)")
