"""The one protocol every tracker module meets, and what it is told about the run."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from hercs.config import TrackingConfig
from hercs.errors import HercsError


class TrackerError(HercsError):
    """A tracker cannot be used (not reachable, refused the run); the message says why."""


@dataclass(frozen=True)
class TrackedRun:
    """One run as the trackers see it."""

    name: str
    folder: Path
    config: Mapping[str, Any]
    """The resolved config (`HercsConfig.resolved().to_dict()`): the hyperparameters."""
    commit: str
    """The hercs commit it runs (hercs.apps.provenance.git_commit)."""
    settings: TrackingConfig

    @property
    def group(self) -> str:
        return self.settings.group


class Tracker(Protocol):
    """A tracker's run, opened by `start` and written by one thread.

    `start(run, saved, attach=False)` opens a new tracker run or, given what an earlier
    `start` returned (`saved`, kept in the run's tracking.json), continues that one; with
    `attach` it only adds to an existing one (a video of a finished run), leaving its state.
    It returns what continuing it needs. Each method raises what the library raises; the
    caller drops the tracker with a warning."""

    name: str
    keeps_files: bool
    """Whether it stores files (a video); TensorBoard's event files hold none."""

    def start(self, run: TrackedRun, saved: Mapping[str, Any], *,
              attach: bool = False) -> dict[str, Any]: ...

    def log_epoch(self, epoch: int, scalars: Mapping[str, float]) -> None: ...

    def log_video(self, path: Path) -> None: ...

    def finish(self, *, complete: bool) -> None: ...
