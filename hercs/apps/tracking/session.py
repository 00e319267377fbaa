"""The trackers of one run: each on a thread of its own, fed metrics.csv's rows as the learner
writes them, and dropped with one warning line when it fails.

`hercs up` opens them once its run folder is its own (`open_tracking`), `follow`s metrics.csv
and `close`s them at the end; `hercs eval --video` attaches to them to add a video. No tracker
call happens on a thread of the run, so none can hold it: a tracker that cannot start, or
stops answering, costs its own thread only, and metrics.csv (the learner's) is complete
either way. What each tracker run is and the last epoch it was sent are kept in the run's
tracking.json, so a resumed run continues the same tracker runs with the epochs after it.
"""

from __future__ import annotations

import contextlib
import functools
import importlib.util
import json
import os
import queue
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from hercs.apps.provenance import git_commit
from hercs.apps.tracking.mlflow_tracker import MlflowTracker
from hercs.apps.tracking.rows import complete_rows, epoch_scalars
from hercs.apps.tracking.tensorboard_tracker import TensorBoardTracker
from hercs.apps.tracking.tracker import TrackedRun, Tracker
from hercs.apps.tracking.wandb_tracker import WandbTracker
from hercs.config import HercsConfig, TrackingConfig
from hercs.errors import ConfigError
from hercs.run.metrics import epoch_spans
from hercs.run.rundir import RunDir

TRACKERS: dict[str, tuple[type[Tracker], str]] = {
    "tensorboard": (TensorBoardTracker, "tensorboard"),
    "wandb": (WandbTracker, "wandb"),
    "mlflow": (MlflowTracker, "mlflow"),
}
"""Each tracker's class and the package it needs (the extra of the same name installs it)."""
POLL_S = 1.0
"""How often metrics.csv is read for new rows while the run goes on."""


def check_installed(settings: TrackingConfig) -> None:
    """Raise `ConfigError` naming the extra to install for a tracker whose package is missing:
    said before a run starts, not found out at its first epoch."""
    for name in settings.backends:
        package = TRACKERS[name][1]
        try:
            found = importlib.util.find_spec(package) is not None
        except (ImportError, ValueError):  # a package whose import is blocked or broken
            found = False
        if not found:
            raise ConfigError(f"tracking.backends: {name} needs the {package} package, which "
                              f"is not installed; pip install 'hercs[{name}]'")


class _Worker:
    """One tracker and the thread that makes all its calls, in order."""

    def __init__(self, tracker: Tracker, say: Callable[[str], None]) -> None:
        self.tracker = tracker
        self.say = say
        self.failed = False
        self.sent: list[int] = []
        self.unsent: list[int] = []
        self.calls: queue.Queue[tuple[str, Callable[[], object]] | None] = queue.Queue()
        self.thread = threading.Thread(target=self._serve, name=f"tracking-{tracker.name}",
                                       daemon=True)  # a hung library never holds the exit
        self.thread.start()

    def call(self, what: str, fn: Callable[[], object]) -> None:
        self.calls.put((what, fn))

    def _serve(self) -> None:
        while (item := self.calls.get()) is not None:
            what, fn = item
            if self.failed:
                continue
            try:
                fn()
            except Exception as exc:  # any library error: the run goes on without it
                self.failed = True
                self.say(f"tracking: {self.tracker.name} stopped at {what} ({type(exc).__name__}:"
                         f" {str(exc).strip().splitlines()[0] if str(exc).strip() else '-'});"
                         " the run goes on without it, metrics.csv keeps every epoch")

    def end(self) -> None:
        self.calls.put(None)


class RunTracking:
    """The trackers of one run folder (`open_tracking`)."""

    def __init__(self, *, run: TrackedRun, trackers: list[Tracker],
                 say: Callable[[str], None], attach: bool = False) -> None:
        self.run = run
        self.files = RunDir(run.folder)
        self._lock = threading.Lock()
        self._state = _read_state(self.files.tracking)
        self._workers = [_Worker(t, say) for t in trackers]
        self._stop = threading.Event()
        self._follower: threading.Thread | None = None
        self.say = say
        for worker in self._workers:
            name = worker.tracker.name
            worker.call("its start", functools.partial(self._start, name, attach))

    def _tracker(self, name: str) -> Tracker:
        return next(w.tracker for w in self._workers if w.tracker.name == name)

    @property
    def names(self) -> list[str]:
        return [w.tracker.name for w in self._workers]

    def _start(self, name: str, attach: bool) -> None:
        saved = dict(self._state.get(name, {}))
        kept = self._tracker(name).start(self.run, saved, attach=attach)
        if not attach:
            self._save(name, {**saved, **kept, "sent_through": saved.get("sent_through", 0)})

    def _save(self, name: str, entry: Mapping[str, Any]) -> None:
        with self._lock:
            self._state[name] = dict(entry)
            tmp = self.files.tracking.with_suffix(".json.tmp")
            tmp.write_text(json.dumps(self._state, indent=1, sort_keys=True) + "\n")
            os.replace(tmp, self.files.tracking)

    def sent_through(self, name: str) -> int:
        with self._lock:
            return int(self._state.get(name, {}).get("sent_through", 0))

    # -- epochs ------------------------------------------------------------------------------
    def send_new_rows(self) -> None:
        """Queue each metrics.csv row past the last epoch each tracker was sent (or queued)."""
        try:
            text = self.files.metrics.read_text()
        except FileNotFoundError:
            return
        for row in complete_rows(text):
            epoch = int(row["epoch"])
            scalars = epoch_scalars(row)
            for worker in self._workers:
                if epoch > max([self.sent_through(worker.tracker.name), *worker.sent]):
                    worker.sent.append(epoch)
                    worker.call(f"epoch {epoch}",
                                functools.partial(self._log_epoch, worker.tracker, epoch, scalars))

    def _log_epoch(self, tracker: Tracker, epoch: int, scalars: Mapping[str, float]) -> None:
        name = tracker.name
        tracker.log_epoch(epoch, scalars)
        with self._lock:
            entry = dict(self._state.get(name, {}))
        self._save(name, {**entry, "sent_through": epoch})

    def follow(self) -> None:
        """Send metrics.csv's new rows every `POLL_S` until `close`."""
        def loop() -> None:
            while not self._stop.wait(POLL_S):
                self.send_new_rows()

        self._follower = threading.Thread(target=loop, name="tracking-follow", daemon=True)
        self._follower.start()

    # -- files -------------------------------------------------------------------------------
    def video(self, path: Path) -> list[str]:
        """Queue `path` as an artifact of each tracker that stores files; their names."""
        keeping = [w for w in self._workers if w.tracker.keeps_files and not w.failed]
        for worker in keeping:
            worker.call("the video", functools.partial(worker.tracker.log_video, path))
        return [w.tracker.name for w in keeping]

    # -- the end -----------------------------------------------------------------------------
    def close(self, *, complete: bool) -> list[str]:
        """Send the last rows, finish each tracker and wait up to `tracking.finish_wait_s` in
        all; says what a tracker left unsent. Returns the trackers that finished."""
        self._stop.set()
        if self._follower is not None:
            self._follower.join()
            self.send_new_rows()
        for worker in self._workers:
            worker.call("its finish", functools.partial(worker.tracker.finish, complete=complete))
            worker.end()
        deadline = time.monotonic() + self.run.settings.finish_wait_s
        finished = []
        for worker in self._workers:
            worker.thread.join(max(0.0, deadline - time.monotonic()))
            name = worker.tracker.name
            if worker.thread.is_alive():
                unsent = [e for e in worker.sent if e > self.sent_through(name)]
                self.say(f"tracking: {name} did not finish within "
                         f"{self.run.settings.finish_wait_s:g} s (tracking.finish_wait_s)"
                         + (f"; epochs {epoch_spans(unsent)} were not sent" if unsent else ""))
            elif not worker.failed:
                finished.append(name)
        return finished


def _read_state(path: Path) -> dict[str, Any]:
    """tracking.json, or nothing where there is none or it is not ours (then the trackers
    start new runs: better than none)."""
    with contextlib.suppress(OSError, ValueError):
        state = json.loads(path.read_text())
        if isinstance(state, dict):
            return {k: v for k, v in state.items() if isinstance(v, dict)}
    return {}


def open_tracking(config: HercsConfig, folder: Path, *, say: Callable[[str], None],
                  attach: bool = False) -> RunTracking | None:
    """The trackers `config.tracking` names for the run in `folder` (None: none named); with
    `attach`, only those that store files and already hold a run of it (tracking.json)."""
    settings = config.tracking
    names = list(settings.backends)
    if attach:
        saved = _read_state(RunDir(folder).tracking)
        names = [n for n in names if n in saved and TRACKERS[n][0].keeps_files]
    if not names:
        return None
    run = TrackedRun(name=config.run.name or folder.name, folder=folder,
                     config=config.resolved().to_dict(), commit=git_commit(),
                     settings=settings)
    return RunTracking(run=run, trackers=[TRACKERS[n][0]() for n in names], say=say,
                       attach=attach)
