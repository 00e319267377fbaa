"""Weights & Biases: one W&B run per hercs run, continued by its id after a resume."""

from __future__ import annotations

import os
import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from hercs.apps.tracking.tracker import TrackedRun


class WandbTracker:
    """The epochs as history at step = epoch, the config (and `commit`) as the run's config,
    the sweep's name as its group, a video as an artifact of type `video`. Its files go to
    RUN/wandb/ unless WANDB_DIR says otherwise; in offline mode `wandb sync` uploads them."""

    name = "wandb"
    keeps_files = True

    def __init__(self) -> None:
        self._run: Any = None
        self._name = ""

    def start(self, run: TrackedRun, saved: Mapping[str, Any], *,
              attach: bool = False) -> dict[str, Any]:
        import wandb

        run_id = str(saved.get("id") or uuid.uuid4().hex[:12])  # W&B ids: [a-z0-9]
        settings = run.settings
        self._name = run.name
        self._run = wandb.init(
            project=settings.project, entity=settings.wandb_entity or None,
            group=settings.group or None, name=run.name, id=run_id, resume="allow",
            mode=settings.wandb_mode or None,  # type: ignore[arg-type]
            dir=None if os.environ.get("WANDB_DIR") else str(run.folder),
            # the launcher's own output stays its own: no console capture, no system
            # sampling in a process that supervises the run
            settings=wandb.Settings(console="off", x_disable_stats=True, save_code=False),
        )
        if not attach:  # a resumed run may train on to more epochs: its config says so
            self._run.config.update({**run.config, "commit": run.commit},
                                    allow_val_change=True)
        return {"id": run_id}

    def log_epoch(self, epoch: int, scalars: Mapping[str, float]) -> None:
        self._run.log(dict(scalars), step=epoch)

    def log_video(self, path: Path) -> None:
        import wandb

        artifact = wandb.Artifact(f"{self._name}-eval-video", type="video")
        artifact.add_file(str(path), name=path.name)
        self._run.log_artifact(artifact)

    def finish(self, *, complete: bool) -> None:
        self._run.finish(exit_code=0 if complete else 1)
