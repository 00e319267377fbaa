"""TensorBoard event files beside metrics.csv: the same scalars, one step per epoch.

Written with torch's `SummaryWriter`, so any TensorBoard reads them. Scalars are grouped so
each panel holds one unit: `eval/`, `loss/`, `throughput/`, `replay/` and `progress/`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from hercs.errors import ConfigError

GROUPS = {
    "success_rate": "eval", "mean_final_distance": "eval",
    "critic_loss": "loss", "actor_loss": "loss", "q_mean": "loss",
    "env_steps_per_s": "throughput", "updates_per_s": "throughput",
    "batch_wait_s": "throughput",
    "replay_size": "replay", "policy_lag": "replay", "policy_lag_request": "replay",
    "weights_version": "replay",
    "cluster_model_version": "replay", "bad_batches": "replay",
}


class TensorBoardScalars:
    """One writer per learner process. A resumed run continues the same folder: events of
    epochs after `after_epoch` left by a learner that died are purged (TensorBoard's
    `purge_step`), so every epoch appears once, as in metrics.csv."""

    def __init__(self, folder: Path, *, after_epoch: int = 0) -> None:
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError as exc:  # torch's writer needs the tensorboard package
            raise ConfigError("run.tensorboard: the tensorboard package is not installed "
                              f"({exc}); pip install 'hercs[tensorboard]'") from None

        self.writer = SummaryWriter(log_dir=str(folder), purge_step=after_epoch + 1)

    def write(self, row: Mapping[str, Any]) -> None:
        epoch = int(row["epoch"])
        for name, value in row.items():
            if name == "epoch" or isinstance(value, bool) or not isinstance(value, int | float):
                continue  # text columns (cluster sizes, rejects) stay in metrics.csv
            if math.isfinite(value):
                self.writer.add_scalar(f"{GROUPS.get(name, 'progress')}/{name}", value, epoch)
        self.writer.flush()

    def close(self) -> None:
        self.writer.close()
