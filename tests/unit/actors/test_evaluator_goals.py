"""The evaluator's episodes depend on the epoch alone (hercs.actors.evaluator.EpochGoals): a
resumed or restarted evaluator, or one asked again for an earlier epoch, evaluates epoch e on
the goals an unbroken one did, which are those `hercs eval` skips to. Real FetchPush envs."""

from __future__ import annotations

import numpy as np

from hercs.actors.evaluator import EpochGoals
from hercs.actors.rollout import RolloutWorker
from hercs.rl.envs import make_env
from hercs.rl.task_registry import task_spec

SPEC = task_spec("push")
PER_EPOCH = 3


def _goals(worker: RolloutWorker, goals: EpochGoals | None = None) -> list[np.ndarray]:
    """The desired goals and initial object positions of PER_EPOCH episodes."""
    out = []
    for _ in range(PER_EPOCH):
        episode = worker.run_episode(lambda o, g: np.zeros(SPEC.action_dim))
        out.append(np.concatenate([episode.g[0], episode.ag[0]]))
        if goals is not None:
            goals.ran(1)
    return out


def test_an_epochs_goals_are_the_same_however_the_evaluator_got_there() -> None:
    unbroken = EpochGoals(spec=SPEC, env=make_env(SPEC), seed=11, per_epoch=PER_EPOCH)
    resumed = EpochGoals(spec=SPEC, env=make_env(SPEC), seed=11, per_epoch=PER_EPOCH)
    by_hercs_eval = RolloutWorker(spec=SPEC, env=make_env(SPEC), seed=11)
    try:
        epochs = {e: _goals(unbroken.position(e), unbroken) for e in (1, 2, 3)}
        assert not np.allclose(epochs[2], epochs[3]), "epochs get other goals"
        # a resumed run's evaluator whose first request is epoch 3
        np.testing.assert_array_equal(_goals(resumed.position(3), resumed), epochs[3])
        # asked again for epoch 2 (a restarted learner), after epoch 3
        np.testing.assert_array_equal(_goals(resumed.position(2), resumed), epochs[2])
        # hercs eval: the stream skipped to epoch 3's first episode
        by_hercs_eval.skip(2 * PER_EPOCH)
        np.testing.assert_array_equal(_goals(by_hercs_eval), epochs[3])
    finally:
        for worker in (unbroken.worker, resumed.worker, by_hercs_eval):
            worker.close()
