"""MLflow: one MLflow run per hercs run, continued by its run id after a resume."""

from __future__ import annotations

import time
import urllib.error
import urllib.request
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from hercs.apps.tracking.rows import flat_hyperparameters
from hercs.apps.tracking.tracker import TrackedRun, TrackerError

PROBE_S = 10.0
"""How long a tracking server gets to answer at start. MLflow's own client retries a refused
connection for minutes (MLFLOW_HTTP_REQUEST_MAX_RETRIES): a server that is not there is said
at once instead."""
PARAMS_PER_CALL = 100
"""MLflow's limit of parameters in one `log_batch`."""
COMMIT_TAGS = ("mlflow.source.git.commit", "hercs.commit")
"""The commit, in MLflow's own tag (its UI shows it) and ours."""


class MlflowTracker:
    """The epochs as metrics at step = epoch, the flat config (`section.field`) as
    parameters, the commit and the group as tags, a video as an artifact under `eval/`. The
    experiment is `tracking.group` (a sweep's) or `tracking.project`."""

    name = "mlflow"
    keeps_files = True

    def __init__(self) -> None:
        self._client: Any = None
        self._run_id = ""
        self._attached = False

    def start(self, run: TrackedRun, saved: Mapping[str, Any], *,
              attach: bool = False) -> dict[str, Any]:
        import mlflow
        from mlflow.tracking import MlflowClient

        uri = run.settings.mlflow_uri or mlflow.get_tracking_uri()
        reachable(uri)
        self._client = client = MlflowClient(tracking_uri=uri)
        self._attached = attach
        continuing = saved.get("run_id") if saved.get("tracking_uri") == uri else None
        if continuing:
            self._run_id = str(continuing)
            if not attach:
                client.update_run(self._run_id, status="RUNNING")
        else:
            name = run.group or run.settings.project
            experiment = client.get_experiment_by_name(name)
            experiment_id = (experiment.experiment_id if experiment is not None
                             else client.create_experiment(name))
            self._run_id = client.create_run(experiment_id, run_name=run.name).info.run_id
        if not attach:
            self._log_config(run)
        return {"run_id": self._run_id, "tracking_uri": uri}

    def _log_config(self, run: TrackedRun) -> None:
        """The parameters a resumed run first logs, its commit, its group. MLflow refuses to
        change a parameter: one a resume changed (a longer training.epochs) goes to the
        tag `resumed.<section.field>`."""
        from mlflow.entities import Param, RunTag

        client = self._client
        logged = client.get_run(self._run_id).data.params
        flat = {key: str(value) for key, value in flat_hyperparameters(run.config).items()}
        new = [Param(key, value) for key, value in flat.items() if key not in logged]
        for i in range(0, len(new), PARAMS_PER_CALL):
            client.log_batch(self._run_id, params=new[i:i + PARAMS_PER_CALL])
        tags = [RunTag(tag, run.commit) for tag in COMMIT_TAGS]
        tags.append(RunTag("hercs.group", run.group))
        tags += [RunTag(f"resumed.{key}", value) for key, value in flat.items()
                 if key in logged and logged[key] != value]
        client.log_batch(self._run_id, tags=tags)

    def log_epoch(self, epoch: int, scalars: Mapping[str, float]) -> None:
        from mlflow.entities import Metric

        now = int(time.time() * 1000)
        self._client.log_batch(self._run_id, metrics=[
            Metric(key, value, now, epoch) for key, value in scalars.items()])

    def log_video(self, path: Path) -> None:
        self._client.log_artifact(self._run_id, str(path), artifact_path="eval")

    def finish(self, *, complete: bool) -> None:
        if not self._attached:  # a video added later leaves the run's state as it was
            self._client.set_terminated(self._run_id, "FINISHED" if complete else "KILLED")


def reachable(uri: str) -> None:
    """Raise `TrackerError` when an http(s) tracking URI does not answer within `PROBE_S`
    (any HTTP answer will do); other stores (a folder, sqlite) are opened by MLflow itself."""
    if not uri.startswith(("http://", "https://")):
        return
    try:
        with urllib.request.urlopen(uri.rstrip("/") + "/health", timeout=PROBE_S):
            pass
    except urllib.error.HTTPError:
        return  # a server answered
    except (urllib.error.URLError, OSError) as exc:
        reason = getattr(exc, "reason", exc)
        raise TrackerError(f"cannot reach {uri} ({reason})") from None
