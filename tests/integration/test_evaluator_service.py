"""`hercs evaluator` as a real process against a router on loopback.

The test plays the learner: it publishes `Weights` (latest kept, as the learner does) and
listens to `eval/result`. No sleeps stand in for synchronisation: every wait is on a queue
with a timeout or the process exit.
"""

from __future__ import annotations

import queue

import numpy as np
import pytest

from hercs.config import HercsConfig, apply_overrides
from hercs.proto import hercs_pb2 as pb
from hercs.rl.policy import Policy
from hercs.wire.codec import weights_to_msg
from tests.integration.services import WAIT_S, OpenRunSide, wait_for

pytestmark = pytest.mark.integration



# ---- the evaluator


def tiny_config(endpoint: str) -> HercsConfig:
    return apply_overrides(HercsConfig(), [
        "run.name=t-evaluator", "run.method=her", "task.name=reach", "training.eval_episodes=5",
        "ddpg.hidden_size=64", f"transport.connect=[{endpoint}]",
    ])


def weights_msg(policy: Policy, *, version: int, epoch: int, evaluate: bool) -> bytes:
    """A `Weights` message as the learner broadcasts it."""
    w = policy.weights()
    return weights_to_msg(version=version, actor_params=w.actor, o_stats=w.o_stats,
                          g_stats=w.g_stats, epoch=epoch, evaluate=evaluate).SerializeToString()


def test_evaluator_answers_every_eval_epoch_and_nothing_else(
    run_side: OpenRunSide, endpoint: str,
) -> None:
    config = tiny_config(endpoint)
    run = run_side(config.run.name)
    learner, keys = run.transport, run.keys
    results: queue.Queue[pb.EvalResult] = queue.Queue()
    learner.subscribe(keys.eval_result, lambda key, raw: results.put(pb.EvalResult.FromString(raw)))
    metrics = run.metrics("evaluator")
    weights = learner.publisher(keys.weights, latest=True, block=True)  # as the learner
    policy = Policy(spec=config.task.spec, config=config.ddpg, seed=3)

    evaluator = run.start("evaluator", config, "e0")
    wait_for(metrics, lambda m: True, "the evaluator's first metrics (it has subscribed)")

    weights.put(weights_msg(policy, version=1, epoch=0, evaluate=False))
    weights.put(b"\x08\x01 not a Weights message")
    weights.put(weights_msg(policy, version=2, epoch=1, evaluate=True))
    first = results.get(timeout=WAIT_S)
    assert (first.epoch, first.weights_version) == (1, 2)
    assert first.episodes == config.training.eval_episodes
    assert 0.0 <= first.success_rate <= 1.0
    assert first.success_rate * first.episodes == pytest.approx(round(first.success_rate
                                                                      * first.episodes))
    assert np.isfinite(first.mean_final_distance) and first.mean_final_distance >= 0.0

    # Newer non-eval weights arriving during an evaluation must not displace a queued one.
    for version, epoch, evaluate in [(3, 2, True), (4, 2, False), (5, 3, True), (6, 3, False),
                                     (7, 4, True)]:
        weights.put(weights_msg(policy, version=version, epoch=epoch, evaluate=evaluate))
    later = [results.get(timeout=WAIT_S) for _ in range(3)]
    assert [(r.epoch, r.weights_version) for r in later] == [(2, 3), (3, 5), (4, 7)]
    assert all(r.episodes == config.training.eval_episodes for r in later)
    assert results.empty(), "a Weights with evaluate=False produced a result"
    # The same policy on fresh goals from one seeded stream: results are plausible, not equal.
    assert all(0.0 <= r.success_rate <= 1.0 for r in later)

    run.stop_cleanly(evaluator, "evaluator", "e0")
