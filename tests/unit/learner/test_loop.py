"""LearnerLoop: cycle and epoch arithmetic, versions, and the metrics row, driven with batches
from a real ReplayTable (no transport)."""

import dataclasses
import time
from collections.abc import Callable

import numpy as np
import pytest
import torch

from bench.synthetic_episodes import random_episode
from hercs.config import HercsConfig, apply_overrides
from hercs.learner.checkpoint import load_checkpoint, save_checkpoint
from hercs.learner.ddpg import DDPGLearner
from hercs.learner.loop import LearnerLoop
from hercs.replay_service.builder import ReplayBuilder
from hercs.run.checkpoint_file import CheckpointError
from hercs.run.metrics import METRICS_COLUMNS, MetricsCsv, recorded_epochs, truncate_metrics
from hercs.run.rundir import RunDir
from hercs.wire.served import ReplayCounters, ServedBatch


def config() -> HercsConfig:
    return apply_overrides(HercsConfig(), [
        "task.name=reach", "run.method=her", "training.cycles_per_epoch=3",
        "training.minibatches_per_cycle=2", "training.epochs=2", "ddpg.batch_size=16",
        "ddpg.hidden_size=32", "replay.buffer_transitions=5000"])


def batches(cfg: HercsConfig, n: int) -> list[ServedBatch]:
    """Batches as the replay serves them (one episode stored before each), without the
    moved-goal figures; each names its moment at the replay (`samples_served`)."""
    table = ReplayBuilder(cfg).table(rng=np.random.default_rng(0))
    rng = np.random.default_rng(1)
    out = []
    for i in range(n):
        table.store_episode(random_episode(table.spec, rng, seq=i))
        served = table.draw(cfg.training.minibatches_per_cycle, cfg.ddpg.batch_size)
        out.append(ServedBatch(
            minibatches=served.minibatches, o_stats=served.o_stats, g_stats=served.g_stats,
            cluster_draws=served.cluster_draws, samples_served=served.samples_served))
    return out


class FakeReplayStatus:
    """The replay's counters at each batch's moment, as `batches` stored them (one 50-step
    episode per batch), with a lag and a reject count of its own; remembers what it was asked."""

    def __init__(self, cfg: HercsConfig) -> None:
        self.per_batch = cfg.training.minibatches_per_cycle
        self.asked: list[int] = []

    def __call__(self, samples: int) -> ReplayCounters:
        self.asked.append(samples)
        episodes = samples // self.per_batch
        return ReplayCounters(samples=samples, inserts=episodes, env_steps=50 * episodes,
                              size_transitions=50 * episodes, policy_lag=1.5,
                              rejects={"non_finite": 2})


def loop_of(cfg: HercsConfig, clock: Callable[[], float] = time.monotonic,
            replay_status: Callable[[int], ReplayCounters] | None = None) -> LearnerLoop:
    """A fresh loop (and learner) of `cfg`, its arguments unpacked as the builder does."""
    return LearnerLoop(learner=DDPGLearner(spec=cfg.task.spec, config=cfg.ddpg, seed=0),
                       epochs=cfg.training.epochs, cycles_per_epoch=cfg.training.cycles_per_epoch,
                       clusters=cfg.cluster.k, clock=clock,
                       replay_status=replay_status or FakeReplayStatus(cfg))


def test_epochs_versions_and_rows(tmp_path) -> None:
    cfg = config()
    ticks = iter(range(100))
    status = FakeReplayStatus(cfg)
    loop = loop_of(cfg, clock=lambda: float(next(ticks)), replay_status=status)
    served = batches(cfg, 6)
    ended = [loop.step(b).epoch_ended for b in served]
    assert ended == [None, None, 1, None, None, 2]
    # once an epoch, for the moment its last batch was drawn
    assert status.asked == [served[2].samples_served, served[5].samples_served] == [6, 12]
    assert loop.version == 6 and loop.learner.updates == 12 and loop.learner.target_updates == 6
    assert loop.done
    # the replay's counters come from the epoch's last batch
    row = loop.record_eval(epoch=1, success_rate=0.25, mean_final_distance=0.1)
    assert row["replay_size"] == 150 and row["cluster_sizes"] == ""
    # the service adds those two
    assert set(row) == set(METRICS_COLUMNS) - {"batch_wait_s", "bad_batches"}
    assert (row["epoch"], row["env_steps"], row["episodes"], row["updates"]) == (1, 150, 3, 6)
    assert row["weights_version"] == 3 and row["success_rate"] == 0.25
    assert row["rejects"] == "non_finite:2" and row["policy_lag"] == 1.5
    # the clock ticks once at start and once per epoch end: epoch 1 spans 1 s
    assert row["updates_per_s"] == 6.0
    assert loop.record_eval(epoch=1, success_rate=0.3, mean_final_distance=0.1) is None
    csv_file = MetricsCsv(RunDir(tmp_path).metrics)
    csv_file.write(row)
    csv_file.close()
    lines = RunDir(tmp_path).metrics.read_text().splitlines()
    assert lines[0].split(",") == METRICS_COLUMNS and len(lines) == 2


def test_a_resumed_loop_continues_exactly_where_the_checkpoint_was_taken(tmp_path) -> None:
    """Train 2 epochs straight; or train 1, checkpoint (learner + loop + the checkpoint file),
    build a fresh learner and loop from the file and train epoch 2 on the same batches: the
    weights, versions, counters and pending epochs agree bit for bit."""
    cfg = apply_overrides(config(), ["training.epochs=2"])
    data = batches(cfg, 6)

    def fresh() -> LearnerLoop:
        return loop_of(cfg)

    straight = fresh()
    for b in data:
        straight.step(b)

    first = fresh()
    for b in data[:3]:
        first.step(b)
    assert save_checkpoint(tmp_path, {"learner": first.learner.state_dict(),
                                      "loop": first.state_dict()})
    state = load_checkpoint(tmp_path)
    assert state is not None
    resumed = fresh()
    resumed.learner.load_state_dict(state["learner"])
    resumed.load_state_dict(state["loop"])
    assert (resumed.epoch, resumed.cycle, resumed.version) == (1, 3, 3)
    assert set(resumed.pending) == {1}, "epoch 1 still waits for its evaluation"
    for b in data[3:]:
        resumed.step(b)
    assert (resumed.epoch, resumed.version, resumed.learner.updates) == (2, 6, 12)
    for name, tensor in straight.learner.actor.state_dict().items():
        assert torch.equal(tensor, resumed.learner.actor.state_dict()[name]), name
    for name, tensor in straight.learner.critic_target.state_dict().items():
        assert torch.equal(tensor, resumed.learner.critic_target.state_dict()[name]), name


def test_checkpoint_write_failure_keeps_the_previous_one(tmp_path, monkeypatch) -> None:
    assert save_checkpoint(tmp_path, {"learner": {}, "loop": {"epoch": 1}})

    def full_disk(fd: int) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("hercs.learner.checkpoint.os.fsync", full_disk)
    assert not save_checkpoint(tmp_path, {"learner": {}, "loop": {"epoch": 2}})
    monkeypatch.undo()
    state = load_checkpoint(tmp_path)
    assert state is not None and state["loop"] == {"epoch": 1}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["learner.pt"], "no temp file left"


def test_unreadable_checkpoint_is_refused_not_ignored(tmp_path) -> None:
    (tmp_path / "learner.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match=r"learner\.pt: not a readable learner checkpoint"):
        load_checkpoint(tmp_path)
    assert load_checkpoint(tmp_path / "none") is None


def test_metrics_keep_rows_through_the_checkpoint_epoch_and_the_rest_aside(tmp_path) -> None:
    path = RunDir(tmp_path).metrics
    out = MetricsCsv(path)
    for epoch in (1, 2, 3):
        out.write({"epoch": epoch, "success_rate": epoch / 10})
    out.close()
    aside = RunDir(tmp_path).previous / "t"
    assert truncate_metrics(path, through_epoch=2, aside=aside) == [3]
    assert recorded_epochs(path) == [1, 2]
    assert recorded_epochs(RunDir(aside).metrics) == [1, 2, 3]  # the old file, kept whole
    assert truncate_metrics(path, through_epoch=2, aside=tmp_path / "unused") == []
    assert not (tmp_path / "unused").exists()  # nothing dropped: nothing set aside
    again = MetricsCsv(path)  # reopened for appending: no second header
    again.write({"epoch": 3, "success_rate": 0.9})
    again.close()
    assert recorded_epochs(path) == [1, 2, 3]
    assert path.read_text().count("epoch,") == 1


def test_metrics_of_an_older_run_keep_its_columns(tmp_path) -> None:
    path = RunDir(tmp_path).metrics
    path.write_text("epoch,success_rate\n1,0.5\n")
    out = MetricsCsv(path)
    out.write({"epoch": 2, "success_rate": 0.6, "bad_batches": 0})
    out.close()
    assert path.read_text().splitlines() == ["epoch,success_rate", "1,0.5", "2,0.6"]


def test_the_epoch_row_reports_the_lag_distribution_and_moved_shares() -> None:
    cfg = config()
    loop = loop_of(cfg)
    lags = [[3, 4], [], [4, 4, 5, 12]]           # the episodes stored before each batch
    moved = [(10, 32, 0.25), (0, 32, 0.25), (22, 32, 0.5)]
    for batch, lag, (m, n, share) in zip(batches(cfg, 3), lags, moved, strict=True):
        loop.step(dataclasses.replace(
            batch, policy_lags=np.asarray(lag, np.int64), sampled_moved=m,
            sampled_transitions=n, buffer_moved_share=share))
    row = loop.record_eval(epoch=1, success_rate=0.0, mean_final_distance=0.0)
    every = np.asarray([3, 4, 4, 4, 5, 12])
    assert row["policy_lag_p50"] == np.percentile(every, 50) == 4.0
    assert row["policy_lag_p95"] == pytest.approx(np.percentile(every, 95))
    assert row["policy_lag_max"] == 12
    assert row["sampled_moved_share"] == round(32 / 96, 4)
    assert row["buffer_moved_share"] == round((0.25 + 0.25 + 0.5) / 3, 4)
    for batch in batches(cfg, 3):                # the next epoch starts from nothing
        loop.step(batch)
    row = loop.record_eval(epoch=2, success_rate=0.0, mean_final_distance=0.0)
    assert np.isnan(row["policy_lag_p50"]) and np.isnan(row["policy_lag_max"])
    assert np.isnan(row["sampled_moved_share"]), "batches without these fields: unknown"
