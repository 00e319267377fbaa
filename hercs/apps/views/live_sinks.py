"""Where the live view's recording goes: a spawned or given Rerun viewer and/or an .rrd file,
and how a viewer that cannot be reached or went away is noticed without ever raising."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from hercs.apps.views.rerun_draw import APP_ID, rerun_executable
from hercs.apps.views.rerun_layout import blueprint
from hercs.config import HercsConfig
from hercs.errors import ConfigError

log = logging.getLogger("hercs.live")

SPAWN_PORT = 9876
"""Port of the viewer that `view.viewer: spawn` starts (rerun-sdk's default)."""
FLUSH_TIMEOUT_S = 1.0


def open_recording(rr: Any, config: HercsConfig) -> Any:
    """A `RecordingStream` (id = the run name) with the sinks `config.view` asks for and the
    `hercs view` layout. A viewer that cannot be spawned is logged, not raised: the .rrd file,
    if any, is still written."""
    view = config.view
    if view.viewer == "none" and not view.save:
        raise ConfigError("view.viewer: got 'none' with view.save '', the live view would show "
                          "nothing; give a viewer ('spawn' or a URL) or a file to save")
    rec = rr.RecordingStream(APP_ID, recording_id=config.run.name)
    rec.send_recording_name(f"{config.run.name} ({config.task.name}, {config.run.method}, "
                            "live)")
    sinks = []
    if view.viewer == "spawn":
        try:
            rr.spawn(port=SPAWN_PORT, connect=False, recording=rec,
                     executable_path=rerun_executable())
        except Exception as exc:  # e.g. no rerun executable: keep the file sink going
            log.warning("could not start a Rerun viewer (%s); streaming to port %d anyway, "
                        "connect one with `rerun --port %d`", exc, SPAWN_PORT, SPAWN_PORT)
        sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{SPAWN_PORT}/proxy"))
    elif view.viewer != "none":
        sinks.append(rr.GrpcSink(view.viewer))
    if view.save:
        Path(view.save).parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(view.save))
    rec.set_sinks(*sinks, default_blueprint=blueprint(task=config.task.spec))
    return rec


class ViewerHealth:
    """Notices a viewer that cannot be reached or went away, without ever raising: rerun-sdk
    keeps accepting log calls then (the .rrd file sink keeps being written), only a flush
    reports the broken gRPC sink. Warns once, and again only after the viewer came back."""

    def __init__(self, rec: Any, *, viewer: str, save: str) -> None:
        self.rec = rec
        self.viewer = viewer
        self.save = save
        self.ok = True
        self.errors = 0

    def check(self) -> bool:
        """Flush (at most `FLUSH_TIMEOUT_S`); True if everything buffered went out."""
        try:
            self.rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        except Exception as exc:  # rerun-sdk raises RuntimeError; nothing here may escape
            self.errors += 1
            if self.ok:
                self.ok = False
                log.warning("the Rerun viewer (%s) cannot be reached or went away: %s; the live "
                            "view keeps draining%s, training is not affected", self.viewer, exc,
                            f" and writing {self.save}" if self.save else "")
            return False
        if not self.ok:
            self.ok = True
            log.info("the Rerun viewer (%s) is reachable again", self.viewer)
        return True


def close_recording(rec: Any) -> None:
    """Flush what is buffered (bounded) and close the sinks; the .rrd gets its footer."""
    try:
        rec.flush(timeout_sec=2 * FLUSH_TIMEOUT_S)
    except Exception as exc:  # the viewer is gone; the file sink is still closed below
        log.info("final flush: %s", exc)
    rec.disconnect()
