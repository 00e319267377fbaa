"""Experiment tracking with the real libraries: W&B in offline mode, read back with W&B's own
reader of its files (`wandb leet inspect --json`), and MLflow against a real tracking server
started here on loopback (sqlite store), read back with `MlflowClient`. One real `hercs up`
sends a FetchReach run to both; the resume, the video and the failures are driven through
`RunTracking` on a metrics.csv written by the learner's own writer."""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

from hercs.apps.evaluation.policy_eval import video_to_trackers
from hercs.apps.launch.router import free_port
from hercs.apps.tracking.rows import epoch_scalars, flat_hyperparameters
from hercs.apps.tracking.session import RunTracking, open_tracking
from hercs.config import HercsConfig, RunConfig, TrackingConfig, load_yaml
from hercs.run.metrics import MetricsCsv, read_rows
from hercs.run.rundir import RunDir
from tests.integration.launcher_standins import Launcher
from tests.support import REPO, free_endpoint

pytestmark = pytest.mark.integration

SERVER_START_S = 300.0  # measured 44-51 s to its health endpoint beside a training grid


def _wait(ready, what: str, timeout_s: float) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout_s
    while not ready():
        assert time.monotonic() < deadline, f"{what} not within {timeout_s:g} s"
        time.sleep(0.2)


def _answers(url: str) -> bool:
    try:
        with urllib.request.urlopen(url, timeout=2):
            return True
    except OSError:
        return False


@pytest.fixture(scope="module")
def mlflow_uri(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """`mlflow server` on a free loopback port with a sqlite store, one worker."""
    folder = tmp_path_factory.mktemp("mlflow")
    port = free_port()
    log = (folder / "server.log").open("w")
    server = subprocess.Popen(
        [str(Path(sys.executable).with_name("mlflow")), "server", "--backend-store-uri",
         f"sqlite:///{folder / 'mlflow.db'}", "--artifacts-destination", str(folder / "art"),
         "--host", "127.0.0.1", "--port", str(port), "--workers", "1"],
        stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
        env=dict(os.environ, MLFLOW_SERVER_ENABLE_JOB_EXECUTION="false"))
    uri = f"http://127.0.0.1:{port}"
    try:
        _wait(lambda: server.poll() is not None or _answers(f"{uri}/health"),
              "the MLflow server's /health", SERVER_START_S)
        assert server.poll() is None, (folder / "server.log").read_text()[-3000:]
        yield uri
    finally:
        os.killpg(server.pid, signal.SIGTERM)  # the server and the uvicorn worker it started
        server.wait(timeout=60)
        log.close()


@pytest.fixture
def wandb_offline(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """W&B offline with its files in tmp_path, for this process and the runs it starts."""
    import wandb

    folder = tmp_path / "wandb-home"
    for name, value in (("WANDB_MODE", "offline"), ("WANDB_SILENT", "true"),
                        ("WANDB_DIR", str(folder)), ("WANDB_CACHE_DIR", str(folder / "cache")),
                        ("WANDB_DATA_DIR", str(folder / "data")),
                        ("WANDB_CONFIG_DIR", str(folder / "config"))):
        monkeypatch.setenv(name, value)
    folder.mkdir()
    yield folder
    wandb.teardown()  # its settings are read once per process: the next test's are others


def wandb_records(folder: Path, run_id: str) -> list[dict]:
    """Every record of run `run_id`'s .wandb files under `folder`, oldest file first, as W&B's
    own inspector prints them. A run continued in the second it stopped (a fast resume, or
    `hercs eval --video` just after training) has W&B name its folder with a suffix:
    offline-run-<second>-<id>-1 beside offline-run-<second>-<id>."""
    named = re.compile(rf"offline-run-\d{{8}}_\d{{6}}-{re.escape(run_id)}(-\d+)?")
    records = []
    for run in sorted(p for p in folder.rglob("offline-run-*") if named.fullmatch(p.name)):
        done = subprocess.run([str(Path(sys.executable).with_name("wandb")), "leet", "inspect",
                               "--json", str(run)], capture_output=True, text=True, timeout=120,
                              check=True)
        records += [json.loads(line) for line in done.stdout.splitlines() if line.strip()]
    return records


def wandb_history(records: list[dict]) -> dict[int, dict[str, float]]:
    return {int(r["history"]["step"]["num"]): {k: v for k, v in r["history"]["item"].items()
                                               if not k.startswith("_")}
            for r in records if r["type"] == "history"}


def mlflow_history(client, run_id: str, keys) -> dict[int, dict[str, float]]:  # type: ignore
    out: dict[int, dict[str, float]] = {}
    for key in keys:
        for m in client.get_metric_history(run_id, key):
            out.setdefault(int(m.step), {})[key] = m.value
    return out


def csv_history(run_dir: Path) -> dict[int, dict[str, float]]:
    return {int(r["epoch"]): epoch_scalars(r) for r in read_rows(RunDir(run_dir).metrics)}


# -- one real run ---------------------------------------------------------------------------

@pytest.mark.full
@pytest.mark.slow
def test_a_hercs_up_run_reaches_wandb_and_mlflow_with_metrics_csvs_numbers(
        tmp_path: Path, wandb_offline: Path, mlflow_uri: str) -> None:
    from mlflow.tracking import MlflowClient

    launcher = Launcher(
        [sys.executable, "-m", "hercs.apps.cli", "up", "--task", "reach", "--run", "tracked",
         "--run-dir", str(tmp_path / "runs"), "--listen", free_endpoint(), "--epochs", "2",
         "--track", "wandb", "--track", "mlflow", "--set", f"tracking.mlflow_uri={mlflow_uri}",
         "--set", "tracking.group=grid1", "--set", "training.cycles_per_epoch=2",
         "--set", "training.eval_episodes=2"], cwd=tmp_path)
    try:
        assert launcher.finish(timeout_s=300) == 0, "\n".join(launcher.out + launcher.err)
    finally:
        launcher.kill()
    run_dir = tmp_path / "runs" / "tracked"
    assert "hercs up: tracking to wandb, mlflow" in launcher.out
    assert not [line for line in launcher.err if "warning" in line], launcher.err
    expected = csv_history(run_dir)
    assert sorted(expected) == [1, 2] and "clusters/share_0" in expected[1]
    saved = json.loads(RunDir(run_dir).tracking.read_text())
    assert saved["wandb"]["sent_through"] == saved["mlflow"]["sent_through"] == 2
    config = load_yaml(RunDir(run_dir).config).resolved().to_dict()

    records = wandb_records(wandb_offline, saved["wandb"]["id"])
    assert wandb_history(records) == expected
    (run,) = [r["run"] for r in records if r["type"] == "run"]
    assert (run["display_name"], run["run_group"], run["project"]) == ("tracked", "grid1",
                                                                        "hercs")
    update = {k: v for r in records if r["type"] == "config"
              for k, v in r["config"]["update"].items()}
    assert update["ddpg"] == config["ddpg"] and is_a_commit_of_this_checkout(update["commit"])

    client = MlflowClient(tracking_uri=mlflow_uri)
    ml_run = client.get_run(saved["mlflow"]["run_id"])
    assert mlflow_history(client, ml_run.info.run_id, expected[1]) == expected
    assert ml_run.data.params == {k: str(v) for k, v in flat_hyperparameters(config).items()}
    assert ml_run.data.tags["mlflow.source.git.commit"] == update["commit"]
    assert ml_run.data.tags["hercs.group"] == "grid1" and ml_run.info.status == "FINISHED"
    assert client.get_experiment(ml_run.info.experiment_id).name == "grid1"

    # no run films itself: `hercs eval --video` adds its video to the run's tracker runs
    video = _video(tmp_path / "eval.mp4")
    assert video_to_trackers(str(run_dir), load_yaml(RunDir(run_dir).config), video) == \
        ["wandb", "mlflow"]
    records = wandb_records(wandb_offline, saved["wandb"]["id"])
    (artifact,) = [r["artifact"] for r in records if r["type"] == "artifact"]
    assert (artifact["type"], artifact["name"]) == ("video", "tracked-eval-video")
    assert [f["size"] for f in artifact["manifest"]["contents"]] == [str(video.stat().st_size)]
    assert [(a.path, a.file_size) for a in client.list_artifacts(ml_run.info.run_id, "eval")] \
        == [("eval/eval.mp4", video.stat().st_size)]
    assert client.get_run(ml_run.info.run_id).info.status == "FINISHED", "left as it was"


def _video(path: Path) -> Path:
    """A real two-second mp4, as hercs eval --video writes them (imageio-ffmpeg)."""
    import imageio_ffmpeg
    import numpy as np

    writer = imageio_ffmpeg.write_frames(str(path), (64, 48), fps=25, macro_block_size=8)
    writer.send(None)
    for i in range(50):
        writer.send(np.full((48, 64, 3), 5 * i, np.uint8))
    writer.close()
    return path


def is_a_commit_of_this_checkout(text: str) -> bool:
    """`git_commit()`'s form ("abc1234", marked when the tree had changes) naming a commit
    here (not necessarily HEAD now: the checkout may have moved on since the run started)."""
    sha = text.removesuffix(" (with uncommitted changes)")
    return subprocess.run(["git", "cat-file", "-e", f"{sha}^{{commit}}"], cwd=REPO,
                          capture_output=True).returncode == 0


# -- driven: resume, video, failures --------------------------------------------------------

def _row(epoch: int) -> dict[str, object]:
    return {"epoch": epoch, "env_steps": 100 * epoch, "success_rate": 0.25 * epoch,
            "critic_loss": 0.5 / epoch, "cluster_sizes": f"{epoch};0;3",
            "cluster_share": "0.5000;0.2500;0.2500", "rejects": ""}


def _tracking(folder: Path, settings: TrackingConfig, said: list[str], *,
              attach: bool = False) -> RunTracking:
    config = HercsConfig(run=RunConfig(name=folder.name), tracking=settings)
    tracking = open_tracking(config, folder, say=said.append, attach=attach)
    assert tracking is not None
    return tracking


def _sent(tracking: RunTracking, name: str, epoch: int) -> None:
    tracking.send_new_rows()
    _wait(lambda: tracking.sent_through(name) >= epoch, f"{name}'s epoch {epoch}", 120)


def test_a_resumed_run_continues_its_tracker_runs_with_the_epochs_after_the_last_sent(
        tmp_path: Path, wandb_offline: Path, mlflow_uri: str,
        monkeypatch: pytest.MonkeyPatch) -> None:
    from mlflow.tracking import MlflowClient
    from wandb.sdk import wandb_settings

    # Both W&B sessions start "in the same second", as they did on a fast CI machine: W&B then
    # names the second offline folder <...>-<id>-1, which the history must still include.
    monkeypatch.setattr(wandb_settings.Settings, "_start_datetime",
                        property(lambda self: "20261202_042239"))

    folder = tmp_path / "resumed"
    folder.mkdir()
    settings = TrackingConfig(backends=["wandb", "mlflow"], mlflow_uri=mlflow_uri)
    metrics, said = MetricsCsv(RunDir(folder).metrics), []
    for epoch in (1, 2):
        metrics.write(_row(epoch))
    first = _tracking(folder, settings, said)
    first.send_new_rows()
    assert first.close(complete=False) == ["wandb", "mlflow"]
    saved = json.loads(RunDir(folder).tracking.read_text())
    metrics.write(_row(3))
    metrics.close()
    second = _tracking(folder, settings, said)
    second.send_new_rows()
    assert second.close(complete=True) == ["wandb", "mlflow"]
    again = json.loads(RunDir(folder).tracking.read_text())
    assert again == {name: {**saved[name], "sent_through": 3} for name in saved}
    assert said == []

    expected = csv_history(folder)
    records = wandb_records(wandb_offline, saved["wandb"]["id"])
    assert len({r["run"]["run_id"] for r in records if r["type"] == "run"}) == 1
    assert wandb_history(records) == expected, "epochs 1, 2 then 3, in one W&B run"
    client = MlflowClient(tracking_uri=mlflow_uri)
    run_id = saved["mlflow"]["run_id"]
    assert mlflow_history(client, run_id, expected[1]) == expected
    assert client.get_run(run_id).info.status == "FINISHED"


def test_an_unreachable_tracker_at_start_is_one_warning_and_the_others_get_every_epoch(
        tmp_path: Path) -> None:
    closed = free_port()  # nothing listens there
    settings = TrackingConfig(backends=["tensorboard", "mlflow"],
                              mlflow_uri=f"http://127.0.0.1:{closed}")
    MetricsCsv(RunDir(tmp_path).metrics).write(_row(1))
    said: list[str] = []
    tracking = _tracking(tmp_path, settings, said)
    _sent(tracking, "tensorboard", 1)
    assert tracking.close(complete=True) == ["tensorboard"]
    assert len(said) == 1 and said[0].startswith(
        f"tracking: mlflow stopped at its start (TrackerError: cannot reach "
        f"http://127.0.0.1:{closed} ("), said
    assert said[0].endswith("the run goes on without it, metrics.csv keeps every epoch")


class _Proxy:
    """A loopback TCP relay in front of a server: `close()` makes its address refuse."""

    def __init__(self, target: int) -> None:
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.target = target
        self.open: list[socket.socket] = []
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self.listener.accept()
            except OSError:
                return
            server = socket.create_connection(("127.0.0.1", self.target))
            self.open += [client, server]
            for a, b in ((client, server), (server, client)):
                threading.Thread(target=self._pump, args=(a, b), daemon=True).start()

    @staticmethod
    def _pump(a: socket.socket, b: socket.socket) -> None:
        try:
            while data := a.recv(65536):
                b.sendall(data)
        except OSError:
            pass
        for s in (a, b):
            s.close()

    def close(self) -> None:
        self.listener.close()
        for s in self.open:
            s.close()


def test_a_tracker_that_stops_answering_mid_run_is_one_warning_and_the_run_goes_on(
        tmp_path: Path, mlflow_uri: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "0")  # MLflow's own: fail at once
    proxy = _Proxy(int(mlflow_uri.rsplit(":", 1)[1]))
    settings = TrackingConfig(backends=["tensorboard", "mlflow"],
                              mlflow_uri=f"http://127.0.0.1:{proxy.port}")
    metrics, said = MetricsCsv(RunDir(tmp_path).metrics), []
    metrics.write(_row(1))
    tracking = _tracking(tmp_path, settings, said)
    _sent(tracking, "mlflow", 1)
    proxy.close()  # the server's address goes away mid-run
    for epoch in (2, 3):
        metrics.write(_row(epoch))
    _sent(tracking, "tensorboard", 3)
    assert tracking.close(complete=True) == ["tensorboard"]
    assert len(said) == 1 and said[0].startswith("tracking: mlflow stopped at epoch 2 ("), said
    assert tracking.sent_through("mlflow") == 1
    assert [int(r["epoch"]) for r in read_rows(RunDir(tmp_path).metrics)] == [1, 2, 3]
