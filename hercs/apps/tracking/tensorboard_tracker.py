"""TensorBoard: event files in RUN/tensorboard/, written with torch's `SummaryWriter`, so any
TensorBoard reads them (`tensorboard --logdir runs/`)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from hercs.apps.tracking.rows import flat_hyperparameters
from hercs.apps.tracking.tracker import TrackedRun
from hercs.run.rundir import RunDir

CONFIG_METRIC = "eval/success_rate"
"""The metric TensorBoard's HParams table shows beside each run's parameters."""


class TensorBoardTracker:
    """The epochs as scalars at step = epoch, one panel per unit (hercs.apps.tracking.rows
    `PANELS`), the flat config in the HParams tab, the commit as the text `run/commit`. A
    resumed run continues the same folder: events of epochs after the last one sent, left by
    a run that died, are purged (TensorBoard's `purge_step`), so each epoch appears once.
    TensorBoard stores no files: a video stays where `hercs eval --video` wrote it."""

    name = "tensorboard"
    keeps_files = False

    def __init__(self) -> None:
        self._writer: Any = None

    def start(self, run: TrackedRun, saved: Mapping[str, Any], *,
              attach: bool = False) -> dict[str, Any]:
        from torch.utils.tensorboard import SummaryWriter
        from torch.utils.tensorboard.summary import hparams

        sent = int(saved.get("sent_through", 0))
        self._writer = SummaryWriter(log_dir=str(RunDir(run.folder).tensorboard),
                                     purge_step=sent + 1)
        if not attach:
            flat = flat_hyperparameters(run.config)
            for summary in hparams(flat, {CONFIG_METRIC: float("nan")}):
                self._writer.file_writer.add_summary(summary)
            self._writer.add_text("run/commit", run.commit, global_step=sent)
            self._writer.flush()
        return {}

    def log_epoch(self, epoch: int, scalars: Mapping[str, float]) -> None:
        for name, value in scalars.items():
            self._writer.add_scalar(name, value, epoch)
        self._writer.flush()

    def log_video(self, path: Path) -> None:  # keeps_files is False: never called
        raise NotImplementedError("TensorBoard stores no files")

    def finish(self, *, complete: bool) -> None:
        self._writer.close()

