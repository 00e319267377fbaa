"""hercs.rundir: checkpoint names resolve to the files `hercs eval` and `hercs.load_policy`
read (the learner writes them under the same names, which it imports from hercs.rundir)."""

from __future__ import annotations

from pathlib import Path

import pytest

from hercs import rundir


@pytest.mark.parametrize(
    ("checkpoint", "present", "expected"),
    [(None, {"best.pt", "learner.pt"}, "checkpoints/best.pt"),
     (None, {"learner.pt"}, "checkpoints/learner.pt"),
     ("best", set(), "checkpoints/best.pt"), ("latest", set(), "checkpoints/learner.pt"),
     ("epoch-7", set(), "checkpoints/epoch-0007.pt"), ("other/file.pt", set(), "other/file.pt")],
    ids=["default-best", "default-falls-back-to-latest", "best", "latest", "epoch", "path"])
def test_checkpoint_names_resolve(tmp_path: Path, checkpoint: str | None, present: set[str],
                                  expected: str) -> None:
    (tmp_path / "checkpoints").mkdir()
    for name in present:
        (tmp_path / "checkpoints" / name).write_bytes(b"")
    path = rundir.checkpoint_path(tmp_path, checkpoint)
    assert path == (tmp_path / expected if expected.startswith("checkpoints") else Path(expected))


def test_kept_checkpoints_lists_best_latest_then_epochs(tmp_path: Path) -> None:
    (tmp_path / "checkpoints").mkdir()
    for name in ("epoch-0020.pt", "learner.pt", "best.pt", "epoch-0010.pt", "mine.pt"):
        (tmp_path / "checkpoints" / name).write_bytes(b"")
    assert rundir.kept_checkpoints(tmp_path) == {
        "best.pt": "best", "learner.pt": "latest", "epoch-0010.pt": "epoch-10",
        "epoch-0020.pt": "epoch-20", "mine.pt": ""}
