"""The TensorBoard tracker: metrics.csv's numbers per epoch, the config in the HParams tab and
the commit as text, read back with TensorBoard's own reader."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("tensorboard", reason="the tensorboard extra is not installed")
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from tensorboard.plugins.hparams import plugin_data_pb2

from hercs.apps.tracking.tensorboard_tracker import TensorBoardTracker
from hercs.apps.tracking.tracker import TrackedRun
from hercs.config import HercsConfig, TrackingConfig
from hercs.run.rundir import RunDir


def _events(folder: Path) -> EventAccumulator:
    acc = EventAccumulator(str(RunDir(folder).tensorboard))
    acc.Reload()
    return acc


def _run(folder: Path) -> TrackedRun:
    settings = TrackingConfig(backends=["tensorboard"])
    return TrackedRun(name="r", folder=folder, commit="abc1234", settings=settings,
                      config=HercsConfig(tracking=settings).resolved().to_dict())


def test_each_epoch_once_a_resume_purging_what_followed_the_last_epoch_sent(
        tmp_path: Path) -> None:
    first = TensorBoardTracker()
    first.start(_run(tmp_path), {})
    for epoch in (1, 2, 3):
        first.log_epoch(epoch, {"eval/success_rate": 0.1 * epoch, "clusters/size_0": 4.0})
    first.finish(complete=False)
    resumed = TensorBoardTracker()  # epoch 3 was written, but tracking.json says 2 was sent
    resumed.start(_run(tmp_path), {"sent_through": 2})
    resumed.log_epoch(3, {"eval/success_rate": 0.9, "clusters/size_0": 5.0})
    resumed.finish(complete=True)
    acc = _events(tmp_path)
    got = [(e.step, e.value) for e in acc.Scalars("eval/success_rate")]
    assert got == [(1, pytest.approx(0.1)), (2, pytest.approx(0.2)), (3, pytest.approx(0.9))]
    assert [e.value for e in acc.Scalars("clusters/size_0")] == [4.0, 4.0, 5.0]


def test_the_config_is_in_the_hparams_tab_and_the_commit_is_text(tmp_path: Path) -> None:
    tracker = TensorBoardTracker()
    tracker.start(_run(tmp_path), {})
    tracker.finish(complete=True)
    acc = _events(tmp_path)
    texts = acc.Tensors("run/commit/text_summary")
    assert [t.tensor_proto.string_val[0].decode() for t in texts] == ["abc1234"]
    content = acc.SummaryMetadata("_hparams_/session_start_info").plugin_data.content
    start = plugin_data_pb2.HParamsPluginData.FromString(content).session_start_info
    assert start.hparams["ddpg.lr_actor"].number_value == HercsConfig().ddpg.lr_actor
    assert start.hparams["run.method"].string_value == "her-cs"
    assert start.hparams["tracking.backends"].string_value == "[tensorboard]"
