"""The `tracking` section of the configuration tree (hercs.config re-exports it): which
experiment trackers `hercs up` sends a run to (hercs/apps/tracking/)."""

from __future__ import annotations

from dataclasses import dataclass, field

from hercs.config.checks import _check, _positive

TRACKERS = ("tensorboard", "wandb", "mlflow")
"""The trackers a run can be sent to (`hercs up --track NAME`)."""
WANDB_MODES = ("", "online", "offline")


@dataclass
class TrackingConfig:
    backends: list[str] = field(default_factory=list)
    """Trackers `hercs up` sends the run to, any of tensorboard, wandb, mlflow (`--track
    NAME`, repeatable): per epoch metrics.csv's numbers and the cluster model's sizes, once
    the resolved config and the commit [DESIGN]."""
    project: str = "hercs"
    """The W&B project, and the MLflow experiment unless `group` is set."""
    group: str = ""
    """Runs that belong together (`hercs sweep` sets its folder's name): W&B's group, the
    MLflow experiment and its tag hercs.group; empty: none."""
    wandb_mode: str = ""
    """W&B's mode, online or offline; empty: W&B's own choice (WANDB_MODE, `wandb offline`)."""
    wandb_entity: str = ""
    """The W&B entity (team or user) the run goes to; empty: the logged-in user's default."""
    mlflow_uri: str = ""
    """The MLflow tracking URI (http://HOST:5000, sqlite:///mlflow.db, a folder); empty:
    MLflow's own (MLFLOW_TRACKING_URI, else its default store in the working folder)."""
    finish_wait_s: float = 60.0
    """At a run's end, how long `hercs up` waits for each tracker to send what it holds before
    it says what was not sent and exits."""

    def __post_init__(self) -> None:
        for name in self.backends:
            _check(name in TRACKERS, "tracking.backends", self.backends,
                   f"name trackers of {', '.join(TRACKERS)}")
        _check(len(set(self.backends)) == len(self.backends), "tracking.backends",
               self.backends, "name each tracker once")
        _check(self.wandb_mode in WANDB_MODES, "tracking.wandb_mode", self.wandb_mode,
               "be online, offline or empty (W&B's own choice)")
        _check(bool(self.project.strip()), "tracking.project", self.project, "not be empty")
        _positive("tracking.finish_wait_s", self.finish_wait_s)
