"""TensorBoard scalars beside metrics.csv, read back with TensorBoard's own reader."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("tensorboard", reason="the tensorboard extra is not installed")
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from hercs.learner.tensorboard import TensorBoardScalars


def _scalars(folder: Path) -> dict[str, list[tuple[int, float]]]:
    acc = EventAccumulator(str(folder))
    acc.Reload()
    return {tag: [(e.step, e.value) for e in acc.Scalars(tag)] for tag in acc.Tags()["scalars"]}


def row(epoch: int, success: float) -> dict[str, object]:
    return {"epoch": epoch, "success_rate": success, "critic_loss": 0.5 / epoch,
            "env_steps_per_s": 1000.0, "replay_size": 100 * epoch, "cluster_sizes": "3;4",
            "rejects": "", "q_mean": float("nan")}


def test_each_epoch_once_grouped_by_unit_and_a_resume_purges_what_followed(
        tmp_path: Path) -> None:
    first = TensorBoardScalars(tmp_path)
    for epoch in (1, 2, 3):
        first.write(row(epoch, 0.1 * epoch))
    first.close()
    resumed = TensorBoardScalars(tmp_path, after_epoch=2)  # died after epoch 3's row
    resumed.write(row(3, 0.9))
    resumed.close()
    got = _scalars(tmp_path)
    assert set(got) == {"eval/success_rate", "loss/critic_loss", "throughput/env_steps_per_s",
                        "replay/replay_size"}, "text and non-finite columns are left out"
    assert got["eval/success_rate"] == [(1, pytest.approx(0.1)), (2, pytest.approx(0.2)),
                                        (3, pytest.approx(0.9))]
