"""Real run directories for tests of what reads them back (resume, eval): a small FetchReach
learner trained for a few one-cycle epochs, its metrics.csv rows and its learner.pt written as
`hercs learner` writes them (the checkpoint at an epoch's end, the row when its evaluation
comes)."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from bench.synthetic_episodes import random_episode
from hercs.config import HercsConfig, apply_overrides, save_yaml
from hercs.learner.builder import LearnerBuilder
from hercs.learner.ddpg import DDPGLearner
from hercs.learner.evaluations import EvalRequests
from hercs.learner.resume import save_learner_state
from hercs.replay_service.builder import ReplayBuilder
from hercs.run.metrics import MetricsCsv
from hercs.run.rundir import RunDir


def run_config(run_dir: Path, epochs: int) -> HercsConfig:
    return apply_overrides(HercsConfig(), [
        "task.name=reach", "run.method=her", f"training.epochs={epochs}",
        "training.cycles_per_epoch=1", "training.minibatches_per_cycle=1",
        "ddpg.batch_size=8", "ddpg.hidden_size=16", "replay.buffer_transitions=2000",
        f"run.name={run_dir.name}", f"run.run_dir={run_dir.parent}"])


def make_run(run_dir: Path, *, epochs: int, trained: int, checkpoint: int | None,
             unevaluated: Iterable[int] = ()) -> HercsConfig:
    """A run of `epochs` epochs that trained `trained` of them: a metrics.csv row for each
    but `unevaluated`, and `checkpoints/learner.pt` taken at the end of epoch `checkpoint`
    (None: no checkpoint), before that epoch's row was written."""
    config = run_config(run_dir, epochs)
    run_dir.mkdir(parents=True)
    save_yaml(config, RunDir(run_dir).config)
    learner = DDPGLearner(spec=config.task.spec, config=config.ddpg, seed=0)
    table = ReplayBuilder(config).table(rng=np.random.default_rng(0))
    # in-process, each step follows its draw at once: the table's counters now are that moment's
    loop = LearnerBuilder(config).loop(learner, replay_status=lambda _samples: table.status())
    rng = np.random.default_rng(1)
    metrics = MetricsCsv(RunDir(run_dir).metrics) if trained else None
    skip = set(unevaluated)
    for epoch in range(1, trained + 1):
        table.store_episode(random_episode(table.spec, rng, seq=epoch))
        served = table.draw(1, config.ddpg.batch_size)
        loop.step(served)
        if epoch == checkpoint:
            save_learner_state(RunDir(run_dir).checkpoints, learner=learner, loop=loop,
                               eval_requests=EvalRequests(resend_s=60.0),
                               config_record=config.to_dict())
        if epoch not in skip and metrics is not None:
            metrics.write(loop.record_eval(epoch=epoch, success_rate=epoch / 10,
                                           mean_final_distance=0.1) or {})
    if metrics is not None:
        metrics.close()
    return config
