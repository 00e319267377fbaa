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
from tests.integration.services import WAIT_S, OpenRunSide, RunSide, wait_for

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


def learner_side(run_side: OpenRunSide, endpoint: str) -> tuple[
        HercsConfig, RunSide, queue.Queue[pb.EvalResult], queue.Queue[dict[str, float]]]:
    """The test's side as the learner: the run's config, its side, the eval results heard and
    the evaluator's metrics."""
    config = tiny_config(endpoint)
    run = run_side(config.run.name)
    results: queue.Queue[pb.EvalResult] = queue.Queue()
    run.transport.subscribe(run.keys.eval_result,
                            lambda key, raw: results.put(pb.EvalResult.FromString(raw)))
    return config, run, results, run.metrics("evaluator")


def test_evaluator_answers_every_eval_epoch_and_nothing_else(
    run_side: OpenRunSide, endpoint: str,
) -> None:
    config, run, results, metrics = learner_side(run_side, endpoint)
    learner, keys = run.transport, run.keys
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


def test_a_restarted_evaluator_tests_an_epoch_on_that_epochs_goals(
    run_side: OpenRunSide, endpoint: str,
) -> None:
    """A run resumed at epoch 3 asks a fresh evaluator for epoch 3 first: it tests the policy on
    the goals an unbroken run's evaluator tests epoch 3 on (the seeded stream past 2 epochs'
    episodes), so its result is exactly that of those episodes run here, not epoch 1's."""
    from hercs.actors.builder import ActorBuilder
    from hercs.rl.task_registry import goal_distance

    config, run, results, metrics = learner_side(run_side, endpoint)
    learner, keys = run.transport, run.keys
    policy = Policy(spec=config.task.spec, config=config.ddpg, seed=5)
    evaluator = run.start("evaluator", config, "e0")
    wait_for(metrics, lambda m: True, "the evaluator's first metrics (it has subscribed)")
    # A request past the run's epochs is refused, not skipped to (2^63 resets). One key keeps
    # the two in order, so epoch 3's result comes after the refusal.
    requests = learner.publisher(keys.eval_request, block=True)
    requests.put(weights_msg(policy, version=29, epoch=2**63, evaluate=True))
    requests.put(weights_msg(policy, version=30, epoch=3, evaluate=True))
    got = results.get(timeout=WAIT_S)
    after = wait_for(metrics, lambda m: m["policy_version"] == 30, "epoch 3's metrics")
    assert isinstance(after, dict)
    assert after["weights_rejected"] == 1 and after["evaluations"] == 1
    run.stop_cleanly(evaluator, "evaluator", "e0")

    n = config.training.eval_episodes
    parts = ActorBuilder(config)
    here = parts.evaluator_policy()
    here.load(policy.weights())

    def episodes_of(epoch: int) -> tuple[float, float]:
        worker = parts.evaluator_env()
        worker.skip((epoch - 1) * n)
        runs = [worker.run_episode(lambda o, g: here.act(o, g, explore=False)) for _ in range(n)]
        worker.close()
        return (sum(e.success for e in runs) / n,
                float(np.mean([goal_distance(e.final_ag, e.desired_goal) for e in runs])))

    success, distance = episodes_of(3)
    assert (got.epoch, got.success_rate) == (3, success)
    assert got.mean_final_distance == pytest.approx(distance, rel=1e-6)
    assert got.mean_final_distance != pytest.approx(episodes_of(1)[1], rel=1e-6), \
        "epoch 1's goals give the same distance: the test cannot tell them apart"
