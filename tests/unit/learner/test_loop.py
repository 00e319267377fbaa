"""LearnerLoop: cycle and epoch arithmetic, versions, and the metrics row, driven with batches
from a real ReplayCore (no transport)."""

import numpy as np

from hercs.config import HercsConfig, apply_overrides
from hercs.episode import random_episode
from learner.ddpg import DDPGLearner
from learner.loop import METRICS_COLUMNS, LearnerLoop, MetricsCsv, SampleBatch
from replay_service.core import ReplayCore


def config() -> HercsConfig:
    return apply_overrides(HercsConfig(), [
        "task.name=reach", "run.method=her", "training.cycles_per_epoch=3",
        "training.minibatches_per_cycle=2", "training.epochs=2", "ddpg.batch_size=16",
        "ddpg.hidden_size=32", "replay.buffer_transitions=5000"])


def batches(cfg: HercsConfig, n: int) -> list[SampleBatch]:
    core = ReplayCore(config=cfg, rng=np.random.default_rng(0))
    rng = np.random.default_rng(1)
    out = []
    for i in range(n):
        core.insert(random_episode(core.spec, rng, seq=i))
        result = core.sample(cfg.training.minibatches_per_cycle, cfg.ddpg.batch_size)
        o_state, g_state = core.normalizer_state()
        out.append(SampleBatch(
            minibatches=result.minibatches,
            o_stats=o_state, g_stats=g_state, cluster_draws=result.cluster_draws,
            inserts=core.inserts, env_steps=core.env_steps, policy_lag=1.5))
    return out


def test_epochs_versions_and_rows(tmp_path) -> None:
    cfg = config()
    ticks = iter(range(100))
    loop = LearnerLoop(config=cfg, learner=DDPGLearner(spec=cfg.task.spec, config=cfg.ddpg,
                                                       seed=0), clock=lambda: float(next(ticks)))
    ended = [loop.step(b).epoch_ended for b in batches(cfg, 6)]
    assert ended == [None, None, 1, None, None, 2]
    assert loop.version == 6 and loop.learner.updates == 12 and loop.learner.target_updates == 6
    assert loop.done
    row = loop.record_eval(epoch=1, success_rate=0.25, mean_final_distance=0.1,
                           replay_status={"size_transitions": 150, "cluster_sizes": [],
                                          "rejects": {"non_finite": 2}})
    assert set(row) == set(METRICS_COLUMNS) - {"batch_wait_s"}  # the service adds that one
    assert (row["epoch"], row["env_steps"], row["episodes"], row["updates"]) == (1, 150, 3, 6)
    assert row["weights_version"] == 3 and row["success_rate"] == 0.25
    assert row["rejects"] == "non_finite:2" and row["policy_lag"] == 1.5
    # the clock ticks once at start and once per epoch end: epoch 1 spans 1 s
    assert row["updates_per_s"] == 6.0
    assert loop.record_eval(epoch=1, success_rate=0.3, mean_final_distance=0.1) is None
    csv_file = MetricsCsv(tmp_path / "metrics.csv")
    csv_file.write(row)
    csv_file.close()
    lines = (tmp_path / "metrics.csv").read_text().splitlines()
    assert lines[0].split(",") == METRICS_COLUMNS and len(lines) == 2
